"""Roman amp33 from the detector's reference output: against theory, amp33 minus the
science pixels read at the same instants is white noise only, under a strong
correlated 1/f (needs the ``roman`` extra; skipped without it)."""

import numpy as np
import pytest

pytest.importorskip("roman_datamodels")

import roman_datamodels as rdm  # noqa: E402

from noise.clock import detector_from_header  # noqa: E402
from noise.errors import ParameterError  # noqa: E402
from scenesim.io.exposure import Exposure  # noqa: E402
from scenesim.pipelines.roman import AMP33_COLUMNS, l1_model, write_l1  # noqa: E402
from scenesim.run import run_scene  # noqa: E402
from scenesim.scene import load_scene  # noqa: E402

pytestmark = [pytest.mark.filterwarnings("ignore::DeprecationWarning"),
              pytest.mark.filterwarnings("ignore::UserWarning")]

RD, RATIO, C_PINK, GAIN = 8.0, 0.8, 30.0, 1.0      # e- per read, ratio, e-, e-/DN
MA_TABLE = [[0, 1], [1, 2], [3, 3], [6, 4]]        # first read, reads per resultant

SCENE = f"""
seed = 3333
[detector]
preset = "WFI"
ref_output = {{ref_output}}
[detector.subarray]
kind = "stripe"
y0 = 2000
ny = {{ny}}
[noise]
preset = "nirspec"
rd_noise = {RD}
ref_ratio = {RATIO}
c_pink = {C_PINK}
u_pink = 0.0
acn = 0.0
pca0 = 0.0
bias_amp = 0.0
ktc = 0.0
pedestal = 10.0
[readout]
ma_table = {MA_TABLE}
name = "AMP33_TEST"
[effects]
gain = {GAIN}
"""


def _run(tmp_path, *, ref_output=True, ny=16, detector=None):
    path = tmp_path / "amp33.toml"
    path.write_text(SCENE.format(ref_output=str(ref_output).lower(), ny=ny))
    scene = load_scene(str(path))
    if detector is not None:
        scene = scene.replace(detector=detector)
    res = run_scene(scene, output=str(tmp_path / "amp33.fits"), progress=False)
    return Exposure.read(res.exposure)


def _rounding_variance(n):
    """Variance (DN^2) of rounding the mean of ``n`` integer codes to an integer, when
    its fractional part is uniform over k/n: 0 for n = 1, (n^2 - 1) / (12 n^2) for odd
    n, (n^2 + 2) / (12 n^2) for even n (the half-integer rounds by +-1/2)."""
    if n == 1:
        return 0.0
    return (n * n - 1) / (12 * n * n) if n % 2 else (n * n + 2) / (12 * n * n)


@pytest.fixture(scope="module")
def stripe(tmp_path_factory):
    d = tmp_path_factory.mktemp("amp33")
    exp = _run(d)
    return exp, l1_model(exp)


def test_amp33_minus_science_is_white(stripe):
    """Every science output o reads its column at slot c (o even: o*128 + c; odd:
    reversed) when amp33's column c is read.  Their difference, per resultant of n
    reads in DN, holds no correlated 1/f and no pedestal (both common to every output
    at that instant), only the two white noises and the ADC's rounding:

        var = (rd^2 (1 + ref_ratio^2) / g^2 + 2/12) / n + 2 r_n

    (1/12: each read's rounding; r_n: the rounding of each resultant's mean,
    :func:`_rounding_variance`).  Each difference is divided by that sigma; the pooled
    mean of z^2 estimates 1.  The 32 differences at one (resultant, row, slot) share
    amp33's white noise, correlation rho = ref_ratio^2 / (1 + ref_ratio^2), so
    var(mean z^2) = 2 (1 + 31 rho^2) / N (Gaussian: var of a mean of squares =
    2 tr(Sigma^2) / N^2); the tolerance is 5 of its sigma."""
    exp, m = stripe
    det = detector_from_header(exp.header)
    assert det.ref_output and det.n_out_active == 32 and det.ncols_out == AMP33_COLUMNS
    sci = np.asarray(m.data, dtype=np.float64)
    amp = np.asarray(m.amp33, dtype=np.float64)
    nres, ny, nx = sci.shape
    assert amp.shape == (nres, ny, AMP33_COLUMNS)
    c = np.arange(AMP33_COLUMNS)
    z2, n_samples = [], 0
    for r, (_, n) in enumerate(MA_TABLE):
        sigma2 = (RD ** 2 * (1 + RATIO ** 2) / GAIN ** 2 + 2 / 12) / n \
            + 2 * _rounding_variance(n)
        diffs = []
        for o in range(32):
            x = o * AMP33_COLUMNS + (c if o % 2 == 0 else AMP33_COLUMNS - 1 - c)
            keep = (x >= det.ref_border) & (x < nx - det.ref_border)
            diffs.append((sci[r][:, x] - amp[r])[:, keep])
        d = np.concatenate(diffs, axis=1)
        d -= d.mean()
        z2.append((d ** 2).ravel() / sigma2)
        n_samples += d.size
    z2 = np.concatenate(z2)
    rho = RATIO ** 2 / (1 + RATIO ** 2)
    tol = 5 * np.sqrt(2 * (1 + 31 * rho ** 2) / n_samples)
    assert abs(z2.mean() - 1) < tol, (z2.mean(), tol)
    # the test can fail: amp33 alone, or against output 0 at mirrored instants
    # (|127 - 2c| pixel times apart), is far from white (the common 1/f), beyond 5
    # sigma of a sample variance, sqrt(2 / (n - 1)) relative (measured: amp33 alone
    # 21x its white level in resultant 0, mirrored 9.5x the white difference)
    white_amp = (RD * RATIO / GAIN) ** 2 + 1 / 12
    a0 = amp[0]
    assert a0.var() / white_amp - 1 > 5 * np.sqrt(2 / (a0.size - 1))
    mis = (sci[0][:, c[::-1]] - amp[0])[:, c[::-1] >= det.ref_border]
    sigma2_0 = RD ** 2 * (1 + RATIO ** 2) / GAIN ** 2 + 2 / 12
    assert mis.var() / sigma2_0 - 1 > 5 * np.sqrt(2 / (mis.size - 1))


def test_l1_with_reference_output_validates(stripe, tmp_path):
    exp, _ = stripe
    path = write_l1(exp, str(tmp_path / "l1.asdf"))
    with rdm.open(path) as m:
        m.validate()
        amp = np.asarray(m.amp33)
    # amp33 is RAWREF in time order: the reference output's block is mirrored with
    # respect to output 0, which scans left to right
    assert np.array_equal(amp, exp.raw_ref[0][..., ::-1])


def test_reference_output_that_is_not_amp33_is_refused(tmp_path):
    """Refused by ``scenesim run --l1`` before the run, and by ``l1_model``."""
    from noise.clock import preset
    from scenesim.pipelines.command import check_run_products
    det = preset("WFI", naxis1=256, naxis2=16, n_out=4, nfoh=1, ref_output=True)
    msg = "amp33 is one reference output of 128 samples per row.*64"
    path = tmp_path / "amp33.toml"
    path.write_text(SCENE.format(ref_output="true", ny=8))
    scene = load_scene(str(path)).replace(detector=det)
    with pytest.raises(ParameterError, match=msg):
        check_run_products(scene, str(tmp_path / "amp33.fits"), l1=True)
    exp = _run(tmp_path, detector=det)                  # 64 columns per output
    with pytest.raises(ParameterError, match=msg):
        l1_model(exp)


def test_without_reference_output_the_fallback_is_white(tmp_path):
    """No reference output: the fallback amp33 (module notes) is white noise at the
    reference level, rd * ref_ratio, with none of the correlated 1/f."""
    exp = _run(tmp_path, ref_output=False)
    assert exp.raw_ref is None
    m = l1_model(exp)
    amp = np.asarray(m.amp33, dtype=np.float64)[0]     # one read: no mean rounding
    n = amp.size
    white_amp = (RD * RATIO / GAIN) ** 2 + 1 / 12
    # var of a sample variance: 2 sigma^4 / (n - 1); 5 sigma, plus the pedestal drawn
    # once for the frame (a constant: no variance within the frame)
    assert abs(amp.var() / white_amp - 1) < 5 * np.sqrt(2 / (n - 1))
