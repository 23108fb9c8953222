"""End to end: simulate a star field with the full noise model, fit it, compare.

This closes the loop the product exists for (scene -> ramps -> reference correction
-> GLS slopes -> photometry against the injected catalogue), with nothing mocked.
"""

import numpy as np
import pytest

from scenesim.run import run_scene
from scenesim.scene import parse_scene


def test_star_field_photometry_recovers_injected_fluxes(tmp_path):
    pytest.importorskip("photutils")
    rng = np.random.default_rng(2026)
    # 36 stars on a jittered 6 x 6 grid, 36 px apart, away from the 4-px border
    g = np.arange(28, 228, 36.0)
    xs, ys = np.meshgrid(g, g)
    xs = xs.ravel() + rng.uniform(-0.5, 0.5, xs.size)
    ys = ys.ravel() + rng.uniform(-0.5, 0.5, ys.size)
    flux = 10 ** rng.uniform(3, 4, xs.size)                  # 1e3 .. 1e4 e-/s
    scene = parse_scene({
        "seed": 99,
        "detector": {"preset": "H2RG", "naxis1": 256, "naxis2": 256},
        "noise": {"preset": "nirspec"},
        "readout": {"pattern": "RAPID", "ngroups": 10},
        "sources": {"dark_current": 0.01, "background": 0.5,
                    "psf": {"kind": "gaussian", "fwhm": 2.0},
                    "stars": [{"x": float(x), "y": float(y), "flux": float(f)}
                              for x, y, f in zip(xs, ys, flux)]},
        "output": {"path": str(tmp_path / "field.fits"), "truth": True, "fit": "gls",
                   "refpix": "jwst", "compare": True},
    })
    res = run_scene(scene, progress=False)
    p = res.report.photometry
    assert p["n"] == xs.size
    # Acceptance: median measured/injected = 1 within its error.  The reported error
    # is the standard error of the median (1.2533 s / sqrt(n)); 5 of them bound a
    # chance deviation.  Measured per-star scatter is ~2 % (median error ~0.4 % over
    # 36 stars: shot noise of 1e4-1e5 e-, background, residual 1/f and read noise in
    # the aperture), so a bias of ~2 % anywhere in the chain (PSF rendering, fit,
    # aperture correction) would fail.
    assert abs(p["median_ratio"] - 1) < 5 * p["median_ratio_err"], p
    assert p["median_ratio_err"] < 0.01


@pytest.mark.parametrize("fit, products, behind", [
    (None, (), True),            # nothing reads the exposure back
    ("ols", (), False),          # the fit reads it
    (None, ("uncal",), False),   # the uncal product is made from it afterwards
])
def test_exposure_is_written_behind_only_when_nothing_reads_it_back(
        tmp_path, monkeypatch, fit, products, behind):
    import scenesim.run as run_module
    seen = []
    real = run_module.write_exposure

    def spy(*args, **kwargs):
        seen.append(kwargs.get("write_behind"))
        return real(*args, **kwargs)

    monkeypatch.setattr(run_module, "write_exposure", spy)
    scene = parse_scene({
        "seed": 3, "detector": {"preset": "H2RG", "naxis1": 64, "naxis2": 64},
        "readout": {"pattern": "RAPID", "ngroups": 3},
        "sources": {"background": 1.0},
        "output": {"path": str(tmp_path / "e.fits"), "fit": fit or ""},
    })
    run_scene(scene, progress=False, products=products)
    assert seen == [behind]
    assert (tmp_path / "e.fits").exists()


@pytest.mark.parametrize("kwargs, match", [(dict(output=123), "'output' must be a path"),
                                           (dict(plots=123), "'plots' must be a direct")])
def test_run_scene_names_a_path_argument_of_the_wrong_type(kwargs, match, tmp_path):
    # before: a bare TypeError from os.fspath
    from noise.errors import ParameterTypeError
    from scenesim.scene import parse_scene
    scene = parse_scene({"seed": 1, "detector": {"naxis1": 16, "naxis2": 16,
                                                 "ref_border": 2},
                         "readout": {"pattern": "RAPID", "ngroups": 2},
                         "output": {"path": str(tmp_path / "x.fits")}})
    with pytest.raises(ParameterTypeError, match=match):
        run_scene(scene, progress=False, **kwargs)
    assert list(tmp_path.iterdir()) == []


def test_the_commands_help_and_quiet_flags_are_in_step(tmp_path):
    # `noise --help` named 4 of the 8 presets it accepts; `fit` refused -q, which
    # `run` and `noise` take.
    import subprocess
    import sys
    from noise.clock import PRESETS

    def cli(*args):
        return subprocess.run([sys.executable, "-m", "scenesim.cli", *args],
                              cwd=tmp_path, capture_output=True, text=True, timeout=300)
    helptext = " ".join(cli("noise", "--help").stdout.split())
    for name in PRESETS:
        assert name in helptext, name
    (tmp_path / "s.toml").write_text(
        'seed = 1\n[detector]\nnaxis1 = 32\nnaxis2 = 32\n[noise]\npreset = "none"\n'
        '[readout]\npattern = "RAPID"\nngroups = 3\n[sources]\ndark_current = 1.0\n'
        '[output]\npath = "e.fits"\n')
    res = cli("run", "s.toml", "-q")
    assert res.returncode == 0, res.stderr
    res = cli("fit", "e.fits", "--fitter", "ols", "--refpix", "none", "-q")
    assert res.returncode == 0 and res.stdout == "", (res.stdout, res.stderr)
    assert (tmp_path / "e_ols.fits").exists()
