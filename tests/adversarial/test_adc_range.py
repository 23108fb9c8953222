"""Noise that the ADC would clip, refused by every way in.

The ADC clips below code 0 and above its top code, ``gain * (2**bits - 1)`` e-.  The
reset level of a pixel without charge is ``bias_offset`` plus the fixed bias pattern
(``bias_amp`` times the template, deterministic, between ``b_lo`` and ``b_hi``) plus
the other components, of rms spread ``s`` (root sum of squares of the amplitudes that
reach every pixel, each 1/f one at its process's whole rms), so ``bias_offset + b_lo``
must lie 5 spreads above 0, ``bias_offset + b_hi`` 5 spreads below the top, and
``10 s + b_hi - b_lo`` must fit in the range (:meth:`noise.NoiseParams.check_adc`).
Before issue 12 ``c_pink = 1e300`` was accepted with only an overflow RuntimeWarning,
``c_pink = 1e7`` (or ``scenesim noise --unit DN --gain 1e-5``, whose 5000 e- bias is
5e8 DN) wrote a ramp of clipped pixels without a word, and so did ``preset = "none"``
with ``rd_noise = 5`` (bias 0: half of every dark pixel's reads at code 0).  Until
2026-11-27 the check took the bias pattern for a Gaussian of rms ``bias_amp`` and the
1/f amplitudes (defined within one frame) for the rms of their processes: a 256 x 256
H2RG with ``bias_offset = 62000`` passed and then read 9.7 % of its reads at code
65535 (the template reaches 13.7 there), and ``c_pink = 200`` with ``f_min = 1e-6`` at
``bias_offset = 5 s`` put 22 % of one exposure's reads at code 0
(:func:`test_accepted_noise_is_not_clipped`).

Every amplitude of :class:`noise.NoiseParams` (its dataclass fields, less the options
of ``noise.params._OPTIONS`` and ``rtn_amp``, which reaches only the RTN pixels) is
set just above its limit, and (class ``float32``) far beyond the float32 frames, and
given to each way in: a scene mapping (:func:`parse_scene`), a scene file
(:func:`load_scene`), ``Scene.replace`` in the library, :func:`noise.write_noise_fits`
with ``unit='DN'``, and the commands ``scenesim run`` and ``scenesim noise``.  Each
must refuse it before any work in one line naming the key (and its table, for a
scene), and accept the value just inside the limit.  The limits are derived here from
the preset's amplitudes, the template and the synthesised PSD, not from the check
under test.
"""

import dataclasses
import hashlib
import os
import subprocess
import sys

import numpy as np
import pytest

import noise
from noise.errors import ParameterError
from noise.params import _OPTIONS
from scenesim.scene import load_scene, parse_scene

#: The amplitudes check_adc bounds (the ones that reach every pixel).
AMPLITUDES = [f.name for f in dataclasses.fields(noise.NoiseParams)
              if f.name not in _OPTIONS and f.name != "rtn_amp"]
GAIN, BITS = 2.0, 12
ADC_RANGE = GAIN * (2 ** BITS - 1)              # 8190 e-
MID = ADC_RANGE / 2                             # a bias with room on both sides
#: value classes: far above any ADC limit, and beyond the float32 frames (1e30)
VALUES = {"adc": 1e6, "float32": 1e300}


#: The scenes' detector ({"naxis1": 16, "naxis2": 16, "ref_border": 2}, H2RG clock).
DET = noise.preset("H2RG", naxis1=16, naxis2=16, ref_border=2)


def _wander(rate, n, f_min=noise.NIRSPEC_DEFAULTS.f_min):
    """Whole rms of a 1/f process over its rms within ``n`` samples (the amplitude's
    definition): the realised PSD integrated over all frequencies, by a fine log grid
    here, against :func:`noise.unit_frame_variance`."""
    f = np.geomspace(f_min * 1e-4, rate / 2, 400001)
    psd = noise.realised_psd(f, rate, f_min)
    total = np.trapezoid(psd, f) + psd[0] * f[0]     # the PSD is flat below f_min
    return float(np.sqrt(total / noise.unit_frame_variance(rate, n, f_min)))


def _template(det=DET):
    t = noise.template_for(det)
    return float(t.min()), float(t.max())


def _scales(det=DET):
    """Per 1/f amplitude, the factor to its process's whole rms on ``det`` (picture
    frame: also the template's largest |value|, which it multiplies)."""
    pink = _wander(1 / det.dt, det.frame_samples)
    tlo, thi = _template(det)
    return {"c_pink": pink, "u_pink": pink,
            "acn": _wander(0.5 / det.dt, det.frame_samples // 2),
            "pca0": _wander(1 / det.row_time, det.ny + det.nfoh) * max(-tlo, thi)}


def _terms(p, det=DET):
    """The spread's terms (e-) of NoiseParams ``p``: every amplitude that reaches every
    pixel (largest per-output value), the white noise at the larger of the regular and
    reference-pixel levels, the 1/f ones at their processes' whole rms; the bias
    itself, its pattern and RTN left out."""
    out, scale = {}, _scales(det)
    for name in AMPLITUDES:
        if name in ("bias_offset", "bias_amp"):
            continue
        v = getattr(p, name)
        v = max(v) if isinstance(v, tuple) else v
        v = v * max(1.0, p.ref_ratio) if name == "rd_noise" else v
        out[name] = v * scale.get(name, 1.0)
    return out


def _spread(p, det=DET):
    return sum(v * v for v in _terms(p, det).values()) ** 0.5


def _pattern(p, det=DET):
    """(b_lo, b_hi), e-: the bias pattern's extremes."""
    tlo, thi = _template(det)
    return p.bias_amp * tlo, p.bias_amp * thi


def _centre(p, det=DET, adc_range=ADC_RANGE):
    """The bias with equal room at both ends: bias + b_lo = range - bias - b_hi."""
    b_lo, b_hi = _pattern(p, det)
    return (adc_range - b_lo - b_hi) / 2


def _limit(key, adc_range=ADC_RANGE):
    """Largest value of amplitude ``key`` (the nirspec preset otherwise): 10 s plus
    the pattern's span must fit in the range (with the bias at the centre, that is
    also where a bias end is reached)."""
    p = noise.NIRSPEC_DEFAULTS
    if key == "bias_amp":
        tlo, thi = _template()
        return (adc_range - 10 * _spread(p)) / (thi - tlo)
    b_lo, b_hi = _pattern(p)
    rest = {k: v for k, v in _terms(p).items() if k != key}
    room = ((adc_range - (b_hi - b_lo)) / 10) ** 2 - sum(v * v for v in rest.values())
    return room ** 0.5 / _scales().get(key, 1.0) / (
        max(1.0, p.ref_ratio) if key == "rd_noise" else 1.0)


def _mapping(key, value):
    """A scene with amplitude ``key`` at ``value`` and the bias at the centre of what
    the nirspec preset so changed leaves (``MID`` with no pattern)."""
    try:
        bias = value if key == "bias_offset" else _centre(
            noise.NIRSPEC_DEFAULTS.replace(**{key: value}))
    except ParameterError:           # beyond the float32 frames: refused anyway
        bias = MID
    table = {"preset": "nirspec", "bias_offset": bias, key: value}
    return {"seed": 1, "detector": {"naxis1": 16, "naxis2": 16, "ref_border": 2},
            "noise": table,
            "readout": {"pattern": "RAPID", "ngroups": 2},
            "effects": {"gain": GAIN, "adc_bits": BITS},
            "output": {"path": "out.fits"}}


def _toml(key, value):
    bias = "" if key == "bias_offset" else f"bias_offset = {MID!r}\n"
    return (f'seed = 1\n[detector]\nnaxis1 = 16\nnaxis2 = 16\nref_border = 2\n'
            f'[noise]\npreset = "nirspec"\n{bias}{key} = {value!r}\n'
            f'[readout]\npattern = "RAPID"\nngroups = 2\n'
            f'[effects]\ngain = {GAIN!r}\nadc_bits = {BITS}\n[output]\npath = "out.fits"\n')


def _check(msg, key):
    assert "\n" not in msg, msg
    assert f"'{key}'" in msg, msg


def test_the_amplitudes_are_enumerated():
    assert set(AMPLITUDES) == {"rd_noise", "c_pink", "u_pink", "acn", "pca0", "pedestal",
                               "ktc", "bias_offset", "bias_amp"}


@pytest.mark.parametrize("key", AMPLITUDES)
@pytest.mark.parametrize("cls", list(VALUES))
def test_scene_mapping_and_file_refuse_it(key, cls, tmp_path):
    with pytest.raises(ParameterError) as info:
        parse_scene(_mapping(key, VALUES[cls]))
    _check(str(info.value), key)
    assert str(info.value).startswith("[noise] ")
    if cls == "adc":
        assert "'gain' 2 e-/DN" in str(info.value) and "'adc_bits' 12" in str(info.value)
    (tmp_path / "s.toml").write_text(_toml(key, VALUES[cls]))
    with pytest.raises(ParameterError) as info:
        load_scene(tmp_path / "s.toml")
    _check(str(info.value), key)
    assert str(tmp_path / "s.toml") in str(info.value)


@pytest.mark.parametrize("key", [k for k in AMPLITUDES if k != "bias_offset"])
def test_each_amplitude_is_refused_just_above_its_limit_and_accepted_below(key):
    # s <= range / 10 with the bias at mid-range: 1e-6 relative on either side
    lim = _limit(key)
    inside, outside = lim * (1 - 1e-6), lim * (1 + 1e-6)
    assert getattr(parse_scene(_mapping(key, inside)).noise, key) == inside
    with pytest.raises(ParameterError) as info:
        parse_scene(_mapping(key, outside))
    _check(str(info.value), key)
    assert "too large for the ADC" in str(info.value)


@pytest.mark.parametrize("preset, amps", [("nirspec", {}),
                                          ("none", {"rd_noise": 5.0}),
                                          ("none", {"c_pink": 30.0, "ktc": 40.0})])
@pytest.mark.parametrize("side", ["top", "bottom"])
def test_a_bias_within_5_spreads_of_either_end_is_refused(side, preset, amps):
    # The ADC clips a dark pixel's reads once the bias lies less than 5 rms spreads s
    # inside the range [0, gain (2**bits - 1)] e- (2.9e-7 of a Gaussian beyond 5 s).
    # Before, only a bias 5 s *beyond* the range was refused: `preset = "none"` with
    # `rd_noise = 5` (bias 0) put half of every dark pixel's reads at code 0
    # silently.  Just inside is accepted, just outside refused, in one line naming
    # the key and the fraction clipped.
    p = (noise.NIRSPEC_DEFAULTS if preset == "nirspec" else noise.ZERO_NOISE).replace(
        **amps)
    s = _spread(p)
    b_lo, b_hi = _pattern(p)
    edge = ADC_RANGE - 5 * s - b_hi if side == "top" else 5 * s - b_lo
    step = 1e-5 * s                  # z = 5 - 1e-5: Q(z) still rounds to 2.87e-7
    inside = edge - step if side == "top" else edge + step
    outside = edge + step if side == "top" else edge - step

    def mapping(bias):
        m = _mapping("bias_offset", bias)
        m["noise"] = {"preset": preset, "bias_offset": bias, **amps}
        return m

    assert parse_scene(mapping(inside)).noise.bias_offset == inside
    with pytest.raises(ParameterError) as info:
        parse_scene(mapping(outside))
    _check(str(info.value), "bias_offset")
    assert ("above the ADC's top code" if side == "top" else "below code 0") in \
        str(info.value)
    # 5 s inside: a fraction Q(5) = 2.87e-7 of the reads clip
    assert "2.87e-05 %" in str(info.value)


def test_bias_zero_with_noise_is_refused_naming_half_the_reads():
    m = _mapping("bias_offset", 0.0)
    m["noise"] = {"preset": "none", "rd_noise": 5.0}
    with pytest.raises(ParameterError) as info:
        parse_scene(m)
    _check(str(info.value), "bias_offset")
    assert "50 % of the reads" in str(info.value)
    assert "in [25, 8165] e-" in str(info.value)       # 5 x 5 e- inside [0, 8190]
    # without noise the bias may sit anywhere in the range, ends included
    for bias in (0.0, ADC_RANGE):
        m["noise"] = {"preset": "none", "bias_offset": bias}
        assert parse_scene(m).noise.bias_offset == bias


@pytest.mark.parametrize("key", AMPLITUDES)
def test_library_scene_replace_refuses_it(key):
    scene = parse_scene(_mapping(key, MID if key == "bias_offset" else 1.0))
    with pytest.raises(ParameterError) as info:
        scene.replace(noise=scene.noise.replace(**{key: VALUES["adc"]}))
    _check(str(info.value), key)
    # a smaller ADC range under the same amplitudes: the gain named too (the bias at
    # the old mid-range is the new top code; an amplitude at its old limit is about
    # twice the new one)
    # (for the bias, 10 e- of bias structure: the preset's 500 e- alone would no
    # longer fit 10 times in the halved range, and that is what would be named)
    start = MID if key == "bias_offset" else _limit(key) * (1 - 1e-6)
    m = _mapping(key, start)
    if key == "bias_offset":
        m["noise"]["bias_amp"] = 10.0
    scene = parse_scene(m)
    with pytest.raises(ParameterError) as info:
        scene.replace(effects=dataclasses.replace(scene.effects, gain=GAIN / 2))
    _check(str(info.value), key)
    assert "'gain' 1 e-/DN" in str(info.value)


@pytest.mark.parametrize("key", AMPLITUDES)
def test_write_noise_fits_in_dn_refuses_it(key, tmp_path):
    det = DET
    range16 = GAIN * 65535                           # the file's ADC: 16 bits
    params = noise.ZERO_NOISE.replace(**{key: 1.01 * range16})
    gen = noise.NoiseGenerator(det, params, rng=1, threads=1)
    with pytest.raises(ParameterError) as info:
        noise.write_noise_fits(tmp_path / "n.fits", gen, 2, unit="DN", gain=GAIN)
    _check(str(info.value), key)
    assert "unit='DN'" in str(info.value)
    assert os.listdir(tmp_path) == []
    # in electrons (float32) nothing clips; inside the limit the DN file is written:
    # the bias alone at the top code, an amplitude with s = range / 10 at mid-range,
    # the bias pattern spanning the range less 1e-6 with the bias centred
    noise.write_noise_fits(tmp_path / "e.fits", gen, 2, unit="e")
    tlo, thi = _template()
    if key == "bias_offset":
        inside = {"bias_offset": range16}
    elif key == "bias_amp":
        amp = range16 / (thi - tlo) * (1 - 1e-6)
        inside = {key: amp, "bias_offset": (range16 - amp * (tlo + thi)) / 2}
    else:
        inside = {key: range16 / 10 / _scales().get(key, 1.0) * (1 - 1e-6),
                  "bias_offset": range16 / 2}
    at_limit = noise.NoiseGenerator(det, noise.ZERO_NOISE.replace(**inside),
                                    rng=1, threads=1)
    noise.write_noise_fits(tmp_path / "dn.fits", at_limit, 2, unit="DN", gain=GAIN)
    assert sorted(os.listdir(tmp_path)) == ["dn.fits", "e.fits"]


def _snapshot(directory):
    return {n: hashlib.sha256((directory / n).read_bytes()).hexdigest()
            for n in sorted(os.listdir(directory))}


def _cli(args, cwd):
    return subprocess.run([sys.executable, "-m", "scenesim.cli", *args], cwd=cwd,
                          capture_output=True, text=True, timeout=120)


def _one_line(stderr, *words):
    lines = [ln for ln in stderr.splitlines() if ln.strip()]
    assert len(lines) == 1, stderr
    assert "Traceback" not in stderr
    for w in words:
        assert w in lines[0], (w, lines[0])


@pytest.mark.parametrize("key, cls", [("c_pink", "float32"), ("rd_noise", "float32"),
                                      ("bias_offset", "adc"), ("c_pink", "adc")])
def test_run_command_refuses_it_in_one_line(key, cls, tmp_path):
    (tmp_path / "s.toml").write_text(_toml(key, VALUES[cls]))
    before = _snapshot(tmp_path)
    res = _cli(["run", "s.toml", "-q"], tmp_path)
    assert res.returncode == 2, res.stderr
    _one_line(res.stderr, "s.toml", "[noise]", f"'{key}'")
    assert _snapshot(tmp_path) == before


def test_noise_command_refuses_a_gain_that_clips_every_pixel(tmp_path):
    # the 16-bit range at 1e-5 e-/DN is 0.655 e-: the paper's 500 e- of bias
    # structure (the largest amplitude) alone is 760 times it.  The command says
    # it by its own options: the least --gain (since 2026-11-28; it had named
    # 'bias_amp', which it does not set)
    res = _cli(["noise", "--naxis", "64", "--frames", "2", "--unit", "DN", "--gain",
                "1e-5", "-q", "-o", "n.fits"], tmp_path)
    assert res.returncode == 2, res.stderr
    _one_line(res.stderr, "'--gain' 1e-05 e-/DN is too small for '--noise nirspec' "
              "at the 16-bit ADC", "more than 65535 x 1e-05 = 0.65535 e-",
              "'--gain' must be >= 0.1728 e-/DN")
    assert os.listdir(tmp_path) == []


@pytest.mark.parametrize("preset, amps", [("nirspec", {}),
                                          ("none", {"bias_offset": 100.0}),
                                          ("none", {"rd_noise": 5.0, "bias_offset": 40.0})])
def test_an_adc_step_above_the_dark_reads_is_refused(preset, amps, tmp_path):
    """Half an ADC step above bias_offset + 5 s rounds every read of a pixel without
    charge to code 0 (before, 'gain' = 1e30 wrote an all-zero ramp and slopes
    without a word; and a whole step was asked, which refused bias 0.7 e- at 1
    e-/DN, whose reads all round to code 1).  Just below is accepted, just above
    refused, by the scene, the library's DN writer and both commands, naming 'gain'
    (a scene: in [effects]).  A noise-free detector without bias has nothing to
    resolve and takes any gain."""
    p = (noise.NIRSPEC_DEFAULTS if preset == "nirspec" else noise.ZERO_NOISE).replace(
        **amps)
    top = 2 * (p.bias_offset + _pattern(p)[1] + 5 * _spread(p))
    inside, outside = top * (1 - 1e-6), top * (1 + 1e-6)

    def mapping(gain):
        m = _mapping("bias_offset", p.bias_offset)
        m["noise"] = {"preset": preset, **amps}
        m["effects"] = {"gain": gain, "adc_bits": 16}
        return m

    assert parse_scene(mapping(inside)).effects.gain == inside
    for gain in (outside, 1e30):
        with pytest.raises(ParameterError) as info:
            parse_scene(mapping(gain))
        _check(str(info.value), "gain")
        assert str(info.value).startswith("[effects] 'gain'")
        assert "code 0" in str(info.value)
    gen = noise.NoiseGenerator(DET, p, rng=1)
    with pytest.raises(ParameterError) as info:
        noise.write_noise_fits(tmp_path / "n.fits", gen, 2, unit="DN", gain=outside)
    _check(str(info.value), "gain")
    assert os.listdir(tmp_path) == []
    m = mapping(1e30)
    m["noise"] = {"preset": "none"}                  # nothing to resolve
    assert parse_scene(m).effects.gain == 1e30


def test_the_commands_refuse_a_gain_coarser_than_the_dark_reads(tmp_path):
    (tmp_path / "s.toml").write_text(_toml("bias_offset", MID).replace(
        f"gain = {GAIN!r}\nadc_bits = {BITS}", "gain = 1e30\nadc_bits = 16"))
    for args in (["run", "s.toml", "-q"],
                 ["noise", "--preset", "H2RG", "--naxis", "16", "--frames", "2",
                  "--unit", "DN", "--gain", "1e30", "-o", "n.fits"]):
        res = subprocess.run([sys.executable, "-m", "scenesim.cli", *args],
                             cwd=tmp_path, capture_output=True, text=True)
        assert res.returncode == 2, res.stderr
        lines = res.stderr.strip().splitlines()
        assert len(lines) == 1 and "'gain' = 1e+30" in lines[0], res.stderr
    assert sorted(os.listdir(tmp_path)) == ["s.toml"]


def test_the_rtn_pixels_high_state_must_stay_inside_the_adc():
    """RTN reaches only its pixels, so it is not in the spread s; but their high state,
    bias_offset + rtn_amp, must lie 5 s below the top code too (before, rtn_amp = 1e9
    with rtn_fraction 0.5 clipped half the pixels at 65535 without a word).  Without
    RTN pixels the amplitude is not bounded."""
    p = noise.NIRSPEC_DEFAULTS.replace(bias_offset=MID, rtn_fraction=0.01)
    edge = ADC_RANGE - MID - _pattern(p)[1] - 5 * _spread(p)
    inside, outside = edge * (1 - 1e-6), edge * (1 + 1e-6)

    def mapping(amp, fraction=0.01):
        m = _mapping("bias_offset", MID)
        m["noise"].update(rtn_fraction=fraction, rtn_amp=amp)
        return m

    assert parse_scene(mapping(inside)).noise.rtn_amp == inside
    with pytest.raises(ParameterError) as info:
        parse_scene(mapping(outside))
    _check(str(info.value), "rtn_amp")
    assert "top code" in str(info.value)
    assert parse_scene(mapping(1e9, fraction=0.0)).noise.rtn_amp == 1e9


def test_accepted_noise_is_not_clipped(tmp_path):
    """What the check accepts, the ADC does not clip (the two cases of the module
    notes, which it accepted before and which then clipped 9.7 % and 22 % of reads)."""
    # (1) the bias pattern: a 256 x 256 H2RG with the paper's amplitudes.  62000 e-
    # is refused; the highest bias accepted puts the top of the pattern 5 s below
    # the top code, where Q(5) = 2.9e-7 of that one pixel's reads clip: over 2 reads
    # of 65536 pixels, 0 expected, so none may read 65535 (a pixel of the old case
    # read it on every read).
    det = noise.preset("H2RG", naxis1=256, naxis2=256)
    p = noise.NIRSPEC_DEFAULTS
    with pytest.raises(ParameterError) as info:
        p.replace(bias_offset=62000.0).check_adc(1.0, 16, det)
    _check(str(info.value), "bias_offset")
    assert "top code" in str(info.value)
    top = 65535 - _pattern(p, det)[1] - 5 * _spread(p, det)
    gen = noise.NoiseGenerator(det, p.replace(bias_offset=top - 1e-3), rng=3)
    noise.write_noise_fits(tmp_path / "b.fits", gen, 2, unit="DN", gain=1.0)
    from astropy.io import fits
    assert np.count_nonzero(fits.getdata(tmp_path / "b.fits") == 65535) == 0
    # (2) 1/f wander below one frame: c_pink = 200 e- at f_min = 1e-6 Hz on 18 ms
    # frames wanders 1.9 x 200 e- (the amplitude is defined within one frame).  The
    # old check accepted a bias of 5 x 200 e-, where 14 of 40 exposures of 20
    # frames clipped; the lowest bias accepted now is 5 whole rms above 0, where no
    # sample of 40 such exposures may fall below code 0 (each sample 2.9e-7; the
    # 1/f process is so correlated that an exposure is a few independent draws).
    det = noise.preset("H2RG").window(500, 500, 64, 64)
    p = noise.ZERO_NOISE.replace(c_pink=200.0, f_min=1e-6)
    with pytest.raises(ParameterError):
        p.replace(bias_offset=1000.0).check_adc(1.0, 16, det)
    low = 5 * 200.0 * _wander(1 / det.dt, det.frame_samples, 1e-6)
    p = p.replace(bias_offset=low * (1 + 1e-6))
    p.check_adc(1.0, 16, det)
    for seed in range(40):
        x = noise.NoiseGenerator(det, p, rng=seed, threads=1).timeline(
            "pink", 0, 0, 20 * det.frame_samples)
        assert np.all(x + p.bias_offset >= -0.5), seed


def test_a_bias_that_rounds_to_code_1_is_accepted():
    # bias 0.7 e- at 1 e-/DN (noise 0.01 e-): every read rounds to code 1, nothing
    # clips; it was refused as "every such read is code 0"
    p = noise.ZERO_NOISE.replace(bias_offset=0.7, rd_noise=0.01)
    p.check_adc(1.0, 16, DET)
    with pytest.raises(ParameterError, match="half an ADC step"):
        p.check_adc(2 * (0.7 + 5 * 0.01) * 1.001, 16, DET)
