"""The library's public functions against wrong argument types, case by class.

Every public callable of :mod:`noise` and :mod:`scenesim` (the packages' ``__all__``;
:func:`test_every_public_callable_is_covered` keeps the list complete), the
``Readout`` builders and the methods a user calls (``NoiseGenerator.frames``,
``ChargeEngine.simulate``, ``Nonlinearity.apply``, ...) and a few subpackage entry
points (``undo_ipc``, ``apply_saturation``, ``linearize_resultants``,
``draw_cosmic_rays``, ...) is called with one argument at a time replaced by a value
of each class of :data:`BAD`, the others valid.  The call must either work (the value
is allowed there: ``None`` for an optional argument, a negative bias, ...) or raise
one of the project's errors (:class:`noise.errors.ScenesimError`: ``ParameterError``
or its ``ParameterTypeError``, ``FileFormatError``) with a one-line message naming
the argument -- never an ``AttributeError``, ``IndexError``, ``KeyError``, a bare
``TypeError``/``ValueError`` or a numpy error from deep inside, and never a
RuntimeWarning (warnings are errors in this suite).

Before these checks (issue 12) 262 of the cases failed, e.g.
``ChargeEngine("abc", readout)`` (AttributeError), ``Detector(subarray=[1])``
(AttributeError), ``NoiseGenerator(threads="abc")`` (ValueError),
``apply_ipc(image, {"a": 1})`` (TypeError), ``parse_scene(m, base_dir=None)``
(TypeError), ``unit_frame_variance(None, ...)`` (TypeError), and every message
quoting an array ran over several lines.

Each case runs in a fresh empty working directory, so a string taken as a path
creates nothing in the checkout.
"""

import inspect
import math

import numpy as np
import pytest

import noise
import scenesim
from noise.errors import ScenesimError
from scenesim.budget import check_budget, check_noise_budget
from scenesim.calib import (SaturationOptions, common_mode, measure_read_noise,
                            reference_layout, saturation_flags)
from scenesim.detector import (FullWell, apply_flat, apply_saturation, ipc_noise_gain,
                               linearize_resultants, undo_ipc)
from scenesim.engine import CosmicRayHits, VariableSource
from scenesim.rampfit import RampCovariance, check_read_times, ols_variance
from scenesim.sky import (CosmicRayModel, draw_cosmic_rays, draw_hot_pixels, load_map,
                          read_catalogue)

#: One value of each class.
BAD = {
    "none": None,
    "string": "abc",
    "dict": {"a": 1},
    "list_of_strings": ["a", "b"],
    "negative": -3,
    "nan": math.nan,
    "wrong_shape": np.zeros((3, 5)),
}

NY = NX = 16
DET = noise.Detector(naxis1=32, naxis2=32, n_out=4).window(0, 0, NX, NY)
RO = scenesim.Readout.named("RAPID", 3)
T_FRAME = DET.frame_time
READ_TIMES = RO.read_times(T_FRAME)
TBAR = RO.mean_times(T_FRAME)
RNG = np.random.default_rng(1)
RESULTANTS = (np.arange(3, dtype=np.float64)[:, None, None] * 10.0
              + RNG.normal(0.0, 5.0, (3, NY, NX)))
IMAGE = RNG.uniform(0.0, 100.0, (NY, NX))
KERNEL = scenesim.ipc_kernel(0.01)
GROUPS = np.repeat(np.arange(4), NX // 4)[None, :].repeat(NY, axis=0)   # 4 outputs
PSF = scenesim.GaussianPSF(2.0)
NL = scenesim.Nonlinearity((-1e-6,))
CURVE = scenesim.LightCurve.step(1.0, after=2.0)
SCENE_MAP = {
    "seed": 3,
    "detector": {"naxis1": 16, "naxis2": 16, "ref_border": 2},
    "noise": {"preset": "none", "rd_noise": 5.0, "bias_offset": 100.0},
    "readout": {"pattern": "RAPID", "ngroups": 3},
    "sources": {"background": 1.0},
    "output": {"path": "out.fits"},
}
SCENE = scenesim.parse_scene(SCENE_MAP)
ENGINE_DET = SCENE.detector

#: Files made once per session by :func:`_files` (exposure, truth, fit, catalogue).
FILES = {}


class Lazy:
    """A valid value made when the case runs (files, fresh generators)."""

    def __init__(self, make):
        self.make = make


def _engine(**kw):
    return scenesim.ChargeEngine(DET, RO, **kw)


def _gen(**kw):
    return noise.NoiseGenerator(DET, noise.NoiseParams(), rng=1, threads=1, **kw)


def _first(iterable):
    return next(iter(iterable))


def _file(name):
    return Lazy(lambda: FILES[name])


#: name -> (function, [(argument, valid value, positional?)]); called as
#: ``fn(*positional, **keywords)``.
CALLS = {
    # ------------------------------------------------------------------ noise
    "Detector": (noise.Detector, [("naxis1", 32, False), ("n_out", 4, False),
                                  ("dt", 1e-5, False), ("pixel_pitch", 18.0, False),
                                  ("name", "H2RG", False), ("reverse_scan", False, False),
                                  ("subarray", None, False)]),
    "Subarray": (noise.Subarray, [("kind", "window", True), ("x0", 0, True),
                                  ("y0", 0, True), ("nx", 8, True), ("ny", 8, True)]),
    "Detector.window": (DET.full_frame().window, [("x0", 0, True), ("y0", 0, True),
                                                   ("nx", 8, True), ("ny", 8, True)]),
    "preset": (noise.preset, [("name", "H2RG", True)]),
    "NoiseParams": (noise.NoiseParams, [("rd_noise", 5.0, False), ("c_pink", 1.0, False),
                                        ("bias_offset", 10.0, False),
                                        ("pink_spectrum", None, False),
                                        ("pca0_file", None, False)]),
    "NoiseGenerator": (noise.NoiseGenerator,
                       [("detector", DET, True), ("params", noise.NoiseParams(), True),
                        ("rng", 1, False), ("threads", 1, False), ("layout", None, False)]),
    "NoiseGenerator.frames": (lambda *a, **k: _first(_gen().frames(*a, **k)),
                              [("nreads", 2, True), ("reads", None, True),
                               ("nints", 1, False), ("integrations", None, False),
                               ("dn_gain", None, False), ("reuse", False, False)]),
    "NoiseGenerator.cube": (lambda *a, **k: _gen().cube(*a, **k),
                            [("nframes", 2, True), ("nints", 1, False)]),
    "write_noise_fits": (noise.write_noise_fits,
                         [("path", "n.fits", True), ("generator", Lazy(_gen), True),
                          ("nframes", 2, True), ("nints", 1, False), ("unit", "DN", False),
                          ("gain", 2.0, False), ("overwrite", False, False),
                          ("progress", None, False), ("extra_cards", (), False)]),
    "Layout": (noise.Layout, [("pool_min_pixels", 1 << 16, False),
                              ("band_rows", 512, False)]),
    "root_seed": (noise.root_seed, [("rng", 1, True)]),
    "ADC": (noise.ADC, [("gain", 1.5, True), ("bits", 16, True), ("shape", None, False)]),
    "to_dn": (noise.to_dn, [("electrons", IMAGE, True), ("gain", 1.5, True),
                            ("bits", 16, False)]),
    "from_dn": (noise.from_dn, [("dn", IMAGE.astype(np.uint16), True), ("gain", 1.5, True)]),
    "synthetic_template": (noise.synthetic_template, [("naxis2", 16, True),
                                                      ("naxis1", 16, True)]),
    "template_for": (noise.template_for, [("detector", DET, True), ("path", None, True)]),
    "pink_psd_shape": (noise.pink_psd_shape, [("f", np.array([1.0, 10.0]), True),
                                              ("f_min", 1e-4, True),
                                              ("spectrum", None, True)]),
    "realised_psd": (noise.realised_psd, [("f", np.array([1.0, 10.0]), True),
                                          ("rate", 1e5, True), ("f_min", 1e-4, True),
                                          ("spectrum", None, True)]),
    "unit_frame_variance": (noise.unit_frame_variance,
                            [("rate", 1e5, True), ("n", 1000, True), ("f_min", 1e-4, True),
                             ("spectrum", None, True)]),
    # ---------------------------------------------------------------- readout
    "Readout": (scenesim.Readout, [("resultants", ((0,), (1,)), True), ("nints", 1, False),
                                   ("reset_mode", "rolling", False), ("name", "X", False)]),
    "Readout.named": (scenesim.Readout.named, [("pattern", "RAPID", True),
                                               ("ngroups", 3, True), ("nints", 1, False),
                                               ("reset_mode", "rolling", False)]),
    "Readout.multiaccum": (scenesim.Readout.multiaccum,
                           [("nframes", 2, True), ("ngroups", 3, True),
                            ("groupgap", 0, False), ("nskip", 0, False)]),
    "Readout.from_ma_table": (scenesim.Readout.from_ma_table,
                              [("table", [[0, 1], [1, 2]], True), ("nints", 1, False),
                               ("name", "T", False)]),
    "Readout.from_reads": (scenesim.Readout.from_reads, [("read_lists", [[0], [2, 3]], True),
                                                         ("name", "R", False)]),
    "Readout.read_times": (RO.read_times, [("t_frame", T_FRAME, True),
                                           ("pixel_time", 0.0, True)]),
    "Readout.mean_times": (RO.mean_times, [("t_frame", T_FRAME, True),
                                           ("pixel_time", 0.0, True)]),
    "Readout.tau": (RO.tau, [("t_frame", T_FRAME, True), ("pixel_time", 0.0, True)]),
    "Readout.read_table": (RO.read_table, [("t_frame", T_FRAME, True)]),
    # -------------------------------------------------------------------- sky
    "GaussianPSF": (scenesim.GaussianPSF, [("fwhm", 2.0, True)]),
    "AiryPSF": (scenesim.AiryPSF, [("radius", 2.0, True)]),
    "ImagePSF": (scenesim.ImagePSF, [("data", np.full((5, 5), 0.04), True),
                                     ("oversample", 1, True), ("normalize", True, True)]),
    "render_point_sources": (scenesim.render_point_sources,
                             [("shape", (NY, NX), True), ("x", [3.0, 8.0], True),
                              ("y", [4.0, 9.0], True), ("flux", [10.0, 20.0], True),
                              ("psf", PSF, True), ("stamp_radius", None, False),
                              ("min_rate", 0.0, False), ("max_stamp_radius", 64, False)]),
    "encircled_energy": (scenesim.encircled_energy, [("psf", PSF, True), ("radius", 3.0, True)]),
    "LightCurve": (scenesim.LightCurve, [("time", np.array([0.0, 1.0]), True),
                                         ("flux", np.array([1.0, 2.0]), True)]),
    "LightCurve.step": (scenesim.LightCurve.step, [("t_on", 1.0, True),
                                                   ("before", 1.0, False),
                                                   ("after", 2.0, False)]),
    "LightCurve.transit": (scenesim.LightCurve.transit,
                           [("t0", 5.0, True), ("duration", 2.0, True), ("depth", 0.1, True),
                            ("ingress", 0.2, True)]),
    "LightCurve.flare": (scenesim.LightCurve.flare,
                         [("t0", 5.0, True), ("amplitude", 1.0, True), ("rise", 0.5, True),
                          ("decay", 2.0, True)]),
    "LightCurve.integral": (CURVE.integral, [("t1", np.array([0.0]), True),
                                             ("t2", np.array([2.0]), True)]),
    "LightCurve.__call__": (CURVE, [("t", np.array([0.0, 2.0]), True)]),
    "CosmicRayModel": (CosmicRayModel, [("rate", 5.0, False), ("charge_mean", 100.0, False),
                                        ("charge_sigma", 10.0, False)]),
    "draw_cosmic_rays": (draw_cosmic_rays,
                         [("model", CosmicRayModel(), True), ("shape", (NY, NX), True),
                          ("pixel_pitch_um", 18.0, True), ("t_start", 0.0, True),
                          ("t_stop", 10.0, True), ("rng", 1, False),
                          ("refmask", None, False)]),
    "draw_hot_pixels": (draw_hot_pixels, [("shape", (NY, NX), True), ("fraction", 0.1, True),
                                          ("rate", 5.0, False), ("rng", 1, False),
                                          ("refmask", None, False)]),
    "load_map": (load_map, [("value", 1.0, True), ("detector", DET, True),
                            ("name", "dark_current", False)]),
    "read_catalogue": (read_catalogue, [("path_or_table", _file("catalogue"), True)]),
    # ----------------------------------------------------------------- engine
    "ChargeEngine": (scenesim.ChargeEngine,
                     [("detector", DET, True), ("readout", RO, True),
                      ("noise_params", None, False), ("rate", 1.0, False),
                      ("variable_sources", (), False), ("cosmic_rays", None, False),
                      ("full_well", None, False), ("nonlinearity", None, False),
                      ("ipc_kernel", None, False), ("gain", 1.0, False),
                      ("adc_bits", 16, False), ("rng", 1, False),
                      ("options", scenesim.EngineOptions(), False)]),
    "ChargeEngine.simulate": (lambda **k: _first(_engine(rate=1.0, rng=1).simulate(**k)),
                              [("save_charge", False, False), ("save_noise", False, False),
                               ("progress", None, False)]),
    "EngineOptions": (scenesim.EngineOptions, [("gauss_above", None, False),
                                               ("shot_noise", True, False),
                                               ("arrivals", "time", False),
                                               ("threads", None, False)]),
    "VariableSource in ChargeEngine": (
        lambda *a: _engine(variable_sources=[VariableSource(*a)], rng=1),
        [("index", np.array([0, 1]), True), ("weight", np.array([1.0, 2.0]), True),
         ("light_curve", CURVE, True)]),
    "CosmicRayHits in ChargeEngine": (
        lambda *a: _engine(cosmic_rays=CosmicRayHits(*a), rng=1),
        [("time", np.array([0.1]), True), ("index", np.array([17]), True),
         ("charge", np.array([100.0]), True)]),
    "check_budget": (check_budget, [("scene", SCENE, True), ("force", False, False)]),
    "check_noise_budget": (check_noise_budget,
                           [("detector", DET, True), ("params", noise.NoiseParams(), True),
                            ("nframes", 2, True), ("nints", 1, False), ("unit", "e", False),
                            ("path", "n.fits", False), ("force", False, False)]),
    # -------------------------------------------------------------- detector
    "Nonlinearity": (scenesim.Nonlinearity, [("coeffs", (-1e-6,), True)]),
    "Nonlinearity.apply": (NL.apply, [("charge", IMAGE, True)]),
    "linearize_resultants": (linearize_resultants,
                             [("e", RESULTANTS[None].astype(np.float32), True),
                              ("nl", NL, True), ("tbar", TBAR, True)]),
    "ipc_kernel": (scenesim.ipc_kernel, [("alpha", 0.01, True), ("alpha_diag", 0.0, True)]),
    "apply_ipc": (scenesim.apply_ipc, [("image", IMAGE, True), ("kernel", KERNEL, True)]),
    "undo_ipc": (undo_ipc, [("image", IMAGE, True), ("kernel", KERNEL, True),
                            ("tolerance", 1e-3, False), ("threads", 1, False),
                            ("out", None, False)]),
    "ipc_noise_gain": (ipc_noise_gain, [("kernel", KERNEL, True)]),
    "apply_saturation": (apply_saturation, [("charge", IMAGE, True), ("full_well", 50.0, True)]),
    "FullWell": (FullWell, [("full_well", 50.0, True), ("shape", (NY, NX), True)]),
    "apply_flat": (apply_flat, [("rate", IMAGE, True), ("flat", 0.9, True)]),
    # --------------------------------------------------------- calib, rampfit
    "correct_reference": (scenesim.correct_reference,
                          [("cube", RESULTANTS, True), ("detector", DET, True),
                           ("scheme", "median", False), ("side_window", 11, False),
                           ("sigma", 3.0, False)]),
    "reference_layout": (reference_layout, [("detector", DET, True)]),
    "SaturationOptions": (SaturationOptions, [("full_well", 1e5, True),
                                              ("adc_ceiling_e", 6e4, True)]),
    "saturation_flags": (saturation_flags,
                         [("e", RESULTANTS[None].astype(np.float32), True),
                          ("tbar", TBAR, True),
                          ("options", SaturationOptions(1e5, 6e4), True)]),
    "common_mode": (common_mode, [("resultants", RESULTANTS[None], True),
                                  ("read_times", READ_TIMES, True), ("read_noise", 5.0, False),
                                  ("groups", GROUPS, False)]),
    "measure_read_noise": (measure_read_noise,
                           [("resultants", RESULTANTS[None], True),
                            ("read_times", READ_TIMES, True), ("read_noise", 5.0, False),
                            ("groups", GROUPS, False)]),
    "fit_ramps": (scenesim.fit_ramps,
                  [("resultants", RESULTANTS, True), ("read_times", READ_TIMES, True),
                   ("read_noise", 5.0, False), ("gain", 1.0, False), ("fitter", "gls", False),
                   ("saturated", None, False), ("jump_threshold", None, False),
                   ("n_iter", 2, False), ("refmask", None, False), ("zero_point", None, False),
                   ("threads", 1, False), ("variance_rate", "local", False)]),
    "optimal_variance": (scenesim.optimal_variance,
                         [("rate", IMAGE, True), ("read_times", READ_TIMES, True),
                          ("read_noise", 5.0, True)]),
    "ols_variance": (ols_variance, [("rate", IMAGE, True), ("read_times", READ_TIMES, True),
                                    ("read_noise", 5.0, True)]),
    "model_chi2": (scenesim.model_chi2,
                   [("resultants", RESULTANTS, True), ("read_times", READ_TIMES, True),
                    ("rate", IMAGE, True), ("read_noise", 5.0, True), ("valid", None, False),
                    ("ddof", 1, False)]),
    "RampCovariance": (RampCovariance, [("read_times", READ_TIMES, True)]),
    "check_read_times": (check_read_times, [("read_times", READ_TIMES, True),
                                            ("nres", 3, True)]),
    "PrepareOptions": (scenesim.PrepareOptions, [("refpix", "jwst", False),
                                                 ("read_noise", None, False),
                                                 ("threads", None, False)]),
    "prepare_exposure": (scenesim.prepare_exposure,
                         [("exposure", _file("exposure"), True),
                          ("options", scenesim.PrepareOptions(), False)]),
    "fit_exposure_file": (scenesim.fit_exposure_file,
                          [("exposure", _file("exposure"), True), ("output", "fit.fits", True),
                           ("fitter", "ols", False), ("jump_threshold", 5.0, False),
                           ("options", scenesim.PrepareOptions(), False)]),
    # ---------------------------------------------------------------- files
    "read_exposure": (scenesim.read_exposure, [("path", _file("exposure"), True)]),
    "read_truth": (scenesim.read_truth, [("path", _file("truth"), True)]),
    "read_fit": (scenesim.read_fit, [("path", _file("fit"), True)]),
    "write_fit": (scenesim.write_fit, [("path", "slopes.fits", True),
                                       ("result", Lazy(lambda: scenesim.read_fit(
                                           FILES["fit"])), True)]),
    # ---------------------------------------------------------- validation
    "compare": (scenesim.compare, [("fit", Lazy(lambda: scenesim.read_fit(FILES["fit"])), True),
                                   ("truth", Lazy(lambda: scenesim.read_truth(FILES["truth"])),
                                    True), ("radius", 4.0, False), ("plots", None, False),
                                   ("nints", None, False)]),
    "compare_files": (scenesim.compare_files, [("fit_path", _file("fit"), True),
                                               ("truth_path", _file("truth"), True),
                                               ("exposure", None, False)]),
    "white_noise_added": (scenesim.white_noise_added,
                          [("detector", DET, True), ("params", noise.NoiseParams(), True),
                           ("scheme", "jwst", False)]),
    # ---------------------------------------------------------------- scenes
    "parse_scene": (scenesim.parse_scene, [("mapping", SCENE_MAP, True),
                                           ("base_dir", ".", False)]),
    "load_scene": (scenesim.load_scene, [("path", _file("scene"), True)]),
    "Scene.replace": (SCENE.replace, [("seed", 5, False), ("detector", DET, False),
                                      ("noise", noise.ZERO_NOISE, False)]),
}

#: Public callables of ``noise.__all__`` / ``scenesim.__all__`` not called above, and
#: why.
NOT_CALLED = {
    "package_version": "takes no argument",
    "atomic_path": "a context manager of files (tests/adversarial/test_files.py)",
    "PinkSeries": "an internal building block of NoiseGenerator (its arguments come "
                  "from a validated NoiseParams and Detector)",
    "measure_psd_error": "a benchmark of the 1/f synthesis (seconds per call)",
    "measure_reference_correction": "a study harness taking seconds per call; its "
                                    "arguments are those of white_noise_added",
    "Scene": "built by parse_scene/load_scene; Scene.replace is called",
    "VariableSource": "a record checked by ChargeEngine (called with it)",
    "CosmicRayHits": "a record checked by ChargeEngine (called with it)",
    "FitResult": "a record made by fit_ramps/read_fit (write_fit is called with it)",
    "PreparedExposure": "a record made by prepare_exposure",
    "Exposure": "a record made by read_exposure / write_exposure",
    "Report": "a record made by compare",
    "write_exposure": "argument checks pending in scenesim/run.py (the lead's)",
    "build_engine": "argument checks pending in scenesim/run.py (the lead's)",
    "run_scene": "argument checks pending in scenesim/run.py (the lead's); "
                 "check_budget, which it calls first, is covered",
    "ScenesimError": "an exception class",
    "ParameterError": "an exception class",
    "ParameterTypeError": "an exception class",
    "FileFormatError": "an exception class",
}

#: Arguments that messages name by the scene key or table they come from.
ALIASES = {
    ("preset", "name"): ("preset",),
    ("Nonlinearity", "coeffs"): ("nonlinearity",),
    ("template_for", "path"): ("pca0_file",),
    ("parse_scene", "mapping"): ("",),
    ("load_scene", "path"): ("scene file", "path"),
    ("Subarray", "kind"): ("kind",),
    ("ipc_kernel", "alpha"): ("ipc_alpha",),
    ("ipc_kernel", "alpha_diag"): ("ipc_alpha_diag",),
    ("load_map", "value"): ("dark_current",),
    ("read_catalogue", "path_or_table"): ("catalogue", "path_or_table"),
    ("compare_files", "fit_path"): ("slope file", "fit_path"),
    ("compare_files", "truth_path"): ("truth file", "truth_path"),
    ("read_exposure", "path"): ("exposure", "path"),
    ("read_truth", "path"): ("truth", "path"),
    ("read_fit", "path"): ("fit file", "path"),
}


@pytest.fixture(scope="module", autouse=True)
def _files(tmp_path_factory):
    """An exposure, its truth and fit files, a catalogue and a scene file."""
    d = tmp_path_factory.mktemp("library_types")
    res = scenesim.run_scene(SCENE, output=str(d / "exp.fits"), progress=False,
                             fit="ols")
    FILES.update(exposure=res.exposure, truth=res.truth, fit=res.fit)
    cat = d / "cat.ecsv"
    cat.write_text("# %ECSV 1.0\n# ---\n# datatype:\n# - {name: x, datatype: float64}\n"
                   "# - {name: y, datatype: float64}\n# - {name: flux, datatype: float64}\n"
                   "x y flux\n3.0 4.0 10.0\n")
    FILES["catalogue"] = str(cat)
    scene = d / "scene.toml"
    scene.write_text('seed = 1\n[detector]\nnaxis1 = 16\nnaxis2 = 16\nref_border = 2\n'
                     '[readout]\npattern = "RAPID"\nngroups = 2\n')
    FILES["scene"] = str(scene)
    yield


def _cases():
    for name, (_, params) in CALLS.items():
        for arg, *_ in params:
            for cls in BAD:
                yield pytest.param(name, arg, cls, id=f"{name}-{arg}-{cls}")


def _call(name, arg, value):
    fn, params = CALLS[name]
    pos, kw = [], {}
    for a, valid, positional in params:
        v = value if a == arg else valid
        if isinstance(v, Lazy):
            v = v.make()
        if positional:
            pos.append(v)
        else:
            kw[a] = v
    return fn(*pos, **kw)


def test_every_public_callable_is_covered():
    """A public callable added to a package ``__all__`` needs a case here (or a
    reason in NOT_CALLED)."""
    called = {n.split(".")[0] for n in CALLS} | set(NOT_CALLED)
    missing = []
    for pkg in (noise, scenesim):
        for name in pkg.__all__:
            obj = getattr(pkg, name)
            if callable(obj) and not (inspect.isclass(obj) and issubclass(obj, BaseException)
                                      and name in NOT_CALLED) and name not in called:
                missing.append(f"{pkg.__name__}.{name}")
    assert not missing, missing


@pytest.mark.parametrize("name", list(CALLS))
def test_valid_call_works(name, tmp_path, monkeypatch):
    """The template of every case is itself a valid call."""
    monkeypatch.chdir(tmp_path)
    _call(name, None, None)


@pytest.mark.parametrize("name, arg, cls", list(_cases()))
def test_wrong_type_is_the_projects_error(name, arg, cls, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    try:
        _call(name, arg, BAD[cls])
    except ScenesimError as exc:
        msg = str(exc)
        assert "\n" not in msg, msg
        names = ALIASES.get((name.split(" ")[0], arg), (arg,))
        assert any(n in msg for n in names), msg


# -------------------------------------------------- issue 12, one test per defect
def test_the_type_error_is_a_parameter_error_and_a_type_error():
    from noise.errors import ParameterError, ParameterTypeError
    with pytest.raises(ParameterTypeError) as info:
        scenesim.ChargeEngine("abc", RO)       # before: AttributeError 'shape'
    assert isinstance(info.value, (ParameterError, ValueError, TypeError))
    assert str(info.value) == ("'detector' must be a noise.Detector, got str 'abc'")


def test_messages_quote_arrays_on_one_line():
    from noise.errors import ParameterError
    from noise.validate import describe
    # before: "'nints' must be an integer, got array([[0., 0., ...\n ...])"
    assert describe(np.zeros((3, 5))) == "array of shape (3, 5), float64"
    assert describe(np.arange(3)) == "array([0, 1, 2])"
    assert describe("x" * 200).endswith("...") and len(describe("x" * 200)) == 80
    with pytest.raises(ParameterError, match=r"^'nints' must be an integer, got array "
                                             r"of shape \(3, 5\), float64$"):
        scenesim.Readout(((0,),), nints=np.zeros((3, 5)))


def test_render_point_sources_refuses_x_and_y_of_different_lengths():
    from noise.errors import ParameterError
    # before: y of length 1 was broadcast against x of length 2 without a word
    with pytest.raises(ParameterError, match=r"'x' of length 2, 'y' of length 1"):
        scenesim.render_point_sources((NY, NX), [3.0, 8.0], [4.0], [10.0, 20.0], PSF)
    with pytest.raises(ParameterError, match=r"'y' of length 3, 'flux' of length 2"):
        scenesim.render_point_sources((NY, NX), [3.0, 8.0], [4.0, 1.0, 2.0], [1.0, 2.0],
                                      PSF)
    # scalars still broadcast
    img, info = scenesim.render_point_sources((NY, NX), 8.0, 8.0, [10.0, 20.0], PSF)
    assert len(info) == 2


def test_noise_amplitudes_beyond_float32_frames_are_refused():
    from noise.errors import ParameterError
    # before: accepted; the generator overflowed to inf ("overflow encountered in
    # cast") and the frames were inf/NaN
    with pytest.raises(ParameterError, match=r"'c_pink' = 1e\+300 e- .*float32"):
        noise.NoiseParams(c_pink=1e300)
    with pytest.raises(ParameterError, match=r"'ref_ratio' x 'rd_noise'"):
        noise.NoiseParams(ref_ratio=1e300)
    with pytest.raises(ParameterError, match=r"'pink_spectrum' PSD values must lie in"):
        noise.NoiseParams(pink_spectrum=[[1.0, 1e-300], [10.0, 1e-300]])
    # the largest amplitude still gives finite frames
    p = noise.ZERO_NOISE.replace(rd_noise=1e30, c_pink=1e30, bias_offset=-1e30)
    frame = noise.NoiseGenerator(DET, p, rng=1, threads=1).cube(1)
    assert np.all(np.isfinite(frame))


def test_f_min_must_be_below_the_nyquist_frequency():
    from noise.errors import ParameterError
    # before: "RuntimeWarning: invalid value encountered in sqrt"
    with pytest.raises(ParameterError, match=r"'f_min' = 1000000.0 Hz must be below"):
        noise.NoiseGenerator(DET, noise.NoiseParams(f_min=1e6), rng=1)


def test_a_frame_beyond_the_int32_clock_is_refused():
    from noise.errors import ParameterError
    # before: the int32 sample index overflowed (wrong read times, silently)
    det = noise.Detector(naxis1=16, naxis2=16, n_out=4, nroh=2 ** 31)
    with pytest.raises(ParameterError, match=r"int32 sample index"):
        det.pixel_time()


def test_cosmic_ray_counts_beyond_memory_are_refused():
    from noise.errors import ParameterError
    # before: numpy's "lam value too large" (ValueError), or OverflowError for a huge
    # pixel pitch
    with pytest.raises(ParameterError, match=r"'rate' = 1e\+300 .*at most 1e\+10"):
        draw_cosmic_rays(CosmicRayModel(rate=1e300), (NY, NX), 18.0, 0.0, 10.0, rng=1)
    with pytest.raises(ParameterError, match=r"expected hits"):
        draw_cosmic_rays(CosmicRayModel(rate=5.0), (NY, NX), 1e300, 0.0, 10.0, rng=1)
