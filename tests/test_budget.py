"""Tests of scenesim.budget: the memory and disk a run needs, checked before any work.

The estimates are compared with the formula of the module notes worked out by hand
for small scenes; the refusals with the two cases of issue 12 (``naxis = 400000`` and
``cosmic_ray_rate = 1e12``, which used to end in a MemoryError traceback after the
work had started and are now refused in milliseconds); the formula with the peak
memory of a real run (``slow``).
"""

import dataclasses
import os
import subprocess
import sys
import textwrap
import time

import pytest

from noise.errors import ParameterError, ParameterTypeError
import noise
import scenesim.budget as budget_module
from scenesim.budget import (MEMORY_FRACTION, WARN_FRACTION, Budget, BudgetWarning,
                             available_memory, check_budget, check_noise_budget,
                             estimate_budget, free_disk, one_line_warnings)
from scenesim.run import run_scene
from scenesim.scene import load_scene, parse_scene

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
MB = 2.0 ** 20
HEADERS = 64 * 1024          # headers and small tables per output file


def _scene(**tables):
    """A 16 x 16 window (one output) of a 32 x 32 H2RG, RAPID x 3, 2 integrations,
    background only, no noise; ``tables`` update the scene's tables (a key given None
    is removed)."""
    m = {"seed": 1,
         "detector": {"naxis1": 32, "naxis2": 32, "ref_border": 2,
                      "subarray": {"kind": "window", "nx": 16, "ny": 16}},
         "noise": {"preset": "none"},
         "readout": {"pattern": "RAPID", "ngroups": 3, "nints": 2},
         "sources": {"background": 1.0},
         "output": {"path": "out.fits"}}
    for name, values in tables.items():
        m.setdefault(name, {}).update(values)
        m[name] = {k: v for k, v in m[name].items() if v is not None}   # None: remove
    return parse_scene(m)


def test_noise_free_window_by_hand():
    b = estimate_budget(_scene())
    P, nints, N = 16 * 16, 2, 2 * 3 * 16 * 16
    # rate and pixel maps 33 P, charge frames 18 P, saturation maps 6 nints P
    assert b.memory == 33 * P + 18 * P + 6 * nints * P == 16128
    # exposure 2 N; truth: RATE and RATE_IPC (float32) 8 P, SATREAD and SATGROUP
    # (int16) 4 nints P; each file 64 kB of headers and tables
    assert b.output == (2 * N + HEADERS) + (8 * P + 4 * nints * P + HEADERS) == 138240
    assert [label.split(" ")[1] for label, _ in b.output_parts] == ["exposure", "truth"]
    assert b.cosmic_ray_events == 0


def test_noise_on_a_one_output_window_by_hand():
    b = estimate_budget(_scene(noise={"preset": "nirspec"}))
    P = 256
    sim = 16128
    # frame, reset level (ktc, bias_amp), template (pca0, bias_amp): 12 P; the 1/f line
    # buffers: 2 sets x 2 jobs (the merged c_pink + u_pink of one output, ACN) x 16
    # rows x (16 columns + 12 overhead) x 4 bytes
    frames = 12 * P + 2 * 2 * 16 * 28 * 4
    # 1/f synthesis: 36 MB once, 12 MB for each of 3 sample rates (pixel rate, ACN's
    # half rate, pca0's row rate), 3 MB for each of 4 series (pink, 2 ACN, pca0)
    pink = 36 * MB + 3 * 12 * MB + 4 * 3 * MB
    template = 48 * (32 + 32)            # synthetic: profiles of the full array
    assert b.memory == sim + frames + pink + template == 88109824


def test_slopes_only_fit_with_cosmic_rays_by_hand():
    b = estimate_budget(_scene(effects={"cosmic_ray_rate": 5.0},
                               output={"ramp": False, "fit": "ols"}))
    P, nints, N = 256, 2, 1536
    # exposure time: 2 integrations x (1 reset + 3 reads) frames of (16 + 1) rows x
    # (16 + 12) pixel times x 10 us; area 256 x (18 um)^2
    t_total = 8 * (17 * 28 * 1e-5)
    events = 5.0 * 256 * (18e-4) ** 2 * t_total
    assert b.cosmic_ray_events == pytest.approx(events, rel=1e-12)
    # the fit's peak (larger than the simulation's): the engine's maps 33 P, the
    # resultants kept in memory 2 N, the fit 44 MB + 72 P + 8 N + 4 nints P, and its
    # chunks in flight, 36 bytes a value (a 256-pixel array: every value at once)
    fit = 33 * P + 2 * N + 44 * MB + 72 * P + 8 * N + 4 * nints * P + 36 * N
    assert b.memory == fit == 46181632 + 36 * N
    # no exposure; the truth with its CRS table (9 deposits of 33 bytes per hit); the
    # fit file: eight maps 32 P and two per-integration cubes 8 nints P
    truth = 8 * P + 4 * nints * P + 33 * 9 * events + HEADERS
    assert b.output == pytest.approx(truth + 32 * P + 8 * nints * P + HEADERS, rel=1e-12)
    assert [label.split(" ")[1] for label, _ in b.output_parts] == ["truth", "fit"]


def test_saved_cubes_and_ipc_by_hand():
    plain = estimate_budget(_scene())
    b = estimate_budget(_scene(effects={"ipc_alpha": 0.01},
                               output={"save_charge": True, "save_noise": True}))
    P, N = 256, 1536
    # IPC 16 P, two saved cubes 28 P each; each cube 4 N in the truth file and 4 N in
    # its temporary raw file
    assert b.memory - plain.memory == 16 * P + 2 * 28 * P
    assert b.output - plain.output == 2 * 8 * N


def test_naxis_400000_is_refused_in_milliseconds():
    # before: a MemoryError traceback after the work had started
    scene = load_scene(os.path.join(ROOT, "scenes", "quick.toml"))
    big = scene.replace(detector=dataclasses.replace(scene.detector, naxis1=400000,
                                                     naxis2=400000))
    t0 = time.perf_counter()
    with pytest.raises(ParameterError) as info:
        check_budget(big)
    assert time.perf_counter() - t0 < 0.05
    msg = str(info.value)
    assert "\n" not in msg
    assert "memory" in msg and "--force" in msg and "naxis1" in msg
    assert f"{MEMORY_FRACTION:.0%}" in msg


def test_cosmic_ray_rate_1e12_is_refused_in_milliseconds():
    # before: a MemoryError traceback (or numpy's "lam value too large")
    scene = load_scene(os.path.join(ROOT, "scenes", "quick.toml"))
    storm = scene.replace(effects=dataclasses.replace(scene.effects,
                                                      cosmic_ray_rate=1e12))
    t0 = time.perf_counter()
    with pytest.raises(ParameterError, match=r"cosmic_ray_rate = 1e\+12 .*--force"):
        check_budget(storm)
    assert time.perf_counter() - t0 < 0.05
    assert estimate_budget(storm).cosmic_ray_events > 1e11


def test_noise_ramp_by_hand(tmp_path):
    det = noise.preset("H2RG", naxis1=64, naxis2=64)
    b = check_noise_budget(det, noise.ZERO_NOISE.replace(rd_noise=5.0), 5, nints=2,
                           unit="DN", path=tmp_path / "n.fits")
    P = 64 * 64
    # the writer's frames 16 P; white noise only: the noise frame 4 P and no 1/f
    # line (njobs = 0)
    assert b.memory == 16 * P + 4 * P
    assert b.output == 2 * 5 * P * 2 + HEADERS          # uint16 DN


def test_large_frames_count_the_forked_helpers_third_line_set(tmp_path):
    from noise.generator import Layout
    assert budget_module.LARGE_FRAME_PIXELS == Layout().pool_min_pixels
    det = noise.preset("H2RG", naxis1=256, naxis2=256)       # 4 outputs of 64 columns
    b = check_noise_budget(det, noise.ZERO_NOISE.replace(c_pink=3.0), 5,
                           unit="DN", path=tmp_path / "n.fits")
    P = 256 * 256
    # the writer's frames 16 P, the noise frame 4 P; 65536 pixels make a large frame:
    # 3 sets (forked helpers' result slots) x 1 job (c_pink) x 256 rows x (64 columns
    # + 12 overhead) x 4 bytes; the synthesis 36 MB + 12 MB (one rate) + 3 MB (one
    # series)
    assert b.memory == 16 * P + 4 * P + 3 * 1 * 256 * 76 * 4 + 36 * MB + 12 * MB + 3 * MB


def test_noise_naxis_400000_is_refused_in_milliseconds(tmp_path):
    # before: `scenesim noise --naxis 400000` ended in a MemoryError traceback
    det = noise.preset("H2RG", naxis1=400000, naxis2=400000)
    t0 = time.perf_counter()
    with pytest.raises(ParameterError, match=r"memory .*--naxis.*--force"):
        check_noise_budget(det, noise.NoiseParams(), 5, path=tmp_path / "n.fits")
    assert time.perf_counter() - t0 < 0.05


def test_force_returns_the_budget_with_a_warning():
    scene = load_scene(os.path.join(ROOT, "scenes", "quick.toml"))
    storm = scene.replace(effects=dataclasses.replace(scene.effects,
                                                      cosmic_ray_rate=1e12))
    b = check_budget(storm, force=True)
    assert isinstance(b, Budget)
    assert b.warning().startswith("forced: ")


def test_the_example_scene_fits_without_a_warning():
    b = check_budget(load_scene(os.path.join(ROOT, "scenes", "quick.toml")))
    assert b.problems() == [] and b.warning() is None
    assert "memory ~" in b.summary()


def test_limits_and_warning_thresholds():
    b = estimate_budget(_scene())
    ok = dataclasses.replace(b, available_memory=b.memory / (WARN_FRACTION / 2),
                             free_disk=b.output * 10)
    assert ok.problems() == [] and ok.warning() is None
    ok.check()
    warm = dataclasses.replace(ok, available_memory=b.memory / 0.6)
    assert warm.problems() == []
    assert "memory" in warm.warning() and "60%" in warm.warning()
    hot = dataclasses.replace(ok, available_memory=b.memory / 0.9)
    with pytest.raises(ParameterError, match="more than the limit of 80%"):
        hot.check()
    full = dataclasses.replace(ok, free_disk=b.output / 2)
    with pytest.raises(ParameterError, match="free in"):
        full.check()
    unknown = dataclasses.replace(b, available_memory=None, free_disk=None)
    unknown.check()
    assert unknown.warning() is None


def test_machine_numbers(tmp_path):
    assert available_memory() > 0
    assert free_disk(tmp_path / "x.fits") > 0
    assert free_disk(tmp_path / "no" / "such" / "dir" / "x.fits") > 0


def test_wrong_arguments():
    with pytest.raises(ParameterTypeError, match="'scene'"):
        check_budget({"seed": 1})
    with pytest.raises(ParameterError, match="'force'"):
        check_budget(_scene(), force="yes")


#: Opening of the peak-memory scripts: ``status(key)`` reads /proc/self/status (bytes).
_PEAK_HEAD = textwrap.dedent("""\
    import gc, sys
    def status(key):
        for line in open("/proc/self/status"):
            if line.startswith(key):
                return int(line.split()[1]) * 1024
    """)
#: Reset the peak (VmHWM) to the current RSS ``base``, then load the scene of
#: argv[1]: loading counts (its checks design the 1/f filters that the run then
#: takes from their cache: 52 MB of a 512^2 scene since the ADC check uses them;
#: measured after the load, the run's peak fell by that and the estimate, which
#: counts them, read 1.64 x the peak).
_PEAK_RESET = textwrap.dedent("""\
    gc.collect()
    base = status("VmRSS")
    with open("/proc/self/clear_refs", "w") as f:
        f.write("5")                  # reset the peak (VmHWM) to the current RSS
    scene = load_scene(sys.argv[1])
    """)

MEASURE = _PEAK_HEAD + textwrap.dedent("""\
    import photutils.psf, scenesim.run, scenesim.calib.prepare, scenesim.validate.compare
    from scenesim.budget import estimate_budget
    from scenesim.engine import EngineOptions
    from scenesim.scene import load_scene
    """) + _PEAK_RESET + textwrap.dedent("""\
    scenesim.run.run_scene(scene, progress=False, options=EngineOptions(threads=2))
    print(status("VmHWM") - base, estimate_budget(scene).memory)
    """)


@pytest.mark.slow
@pytest.mark.skipif(not os.path.exists("/proc/self/clear_refs"), reason="Linux only")
@pytest.mark.parametrize("naxis, ngroups, fitter", [(512, 10, "gls"), (256, 200, "gls"),
                                                   (256, 200, "ols")])
def test_estimate_bounds_a_measured_run(tmp_path, naxis, ngroups, fitter):
    """The estimate of a run with the paper's noise and a fit is at or a little above
    its measured peak memory (the module notes' coefficients).  The long ramps: the
    fit's chunks in flight (before, 256^2 x 200 was estimated at 268 MB and peaked at
    504-594 MB above the interpreter's start)."""
    (tmp_path / "s.toml").write_text(textwrap.dedent(f"""\
        seed = 3
        [detector]
        naxis1 = {naxis}
        naxis2 = {naxis}
        [readout]
        pattern = "RAPID"
        ngroups = {ngroups}
        [sources]
        background = 1.0
        [output]
        path = "s.fits"
        fit = "{fitter}"
        """))
    (tmp_path / "m.py").write_text(MEASURE)
    res = subprocess.run([sys.executable, "m.py", "s.toml"], cwd=tmp_path,
                         capture_output=True, text=True, timeout=600)
    assert res.returncode == 0, res.stderr
    measured, estimate = (float(v) for v in res.stdout.split())
    assert 0.9 * measured <= estimate <= 1.6 * measured, (measured / MB, estimate / MB)


# ------------------------------------------------- run_scene checks the budget first
def _tiny_scene(path, naxis=16, **effects):
    return parse_scene({"seed": 2, "detector": {"naxis1": naxis, "naxis2": naxis,
                                                "ref_border": 2},
                        "noise": {"preset": "none"},
                        "readout": {"pattern": "RAPID", "ngroups": 2},
                        "sources": {"background": 1.0}, "effects": effects,
                        "output": {"path": str(path)}})


@pytest.mark.parametrize("change", ["naxis", "cosmic_ray_rate"])
def test_run_scene_refuses_before_any_work(change, tmp_path):
    # before: a MemoryError traceback after the work had started
    # 64 x 64 pixels, RAPID x 2: 7e8 hits at 1e12 /cm^2/s, about 1 TB (on 16 x 16
    # pixels, 7e6 hits and 11 GB, which a large machine holds)
    scene = _tiny_scene(tmp_path / "x.fits", naxis=64)
    if change == "naxis":
        scene = scene.replace(detector=dataclasses.replace(
            scene.detector, naxis1=400000, naxis2=400000))
    else:
        scene = scene.replace(effects=dataclasses.replace(scene.effects,
                                                          cosmic_ray_rate=1e12))
    t0 = time.perf_counter()
    with pytest.raises(ParameterError, match=rf"{'naxis1' if change == 'naxis' else change}"
                                             r".*--force"):
        run_scene(scene, progress=False)
    # arithmetic only (~1 ms); 0.5 s is far below building a 1e11-pixel array
    assert time.perf_counter() - t0 < 0.5
    assert os.listdir(tmp_path) == []


def test_run_scene_force_runs_past_the_limit_with_a_warning(tmp_path, monkeypatch):
    monkeypatch.setattr(budget_module, "available_memory", lambda: 1e3)
    scene = _tiny_scene(tmp_path / "x.fits")
    with pytest.raises(ParameterError, match=r"1000 B available.*--force"):
        run_scene(scene, progress=False)
    assert os.listdir(tmp_path) == []
    with pytest.warns(BudgetWarning, match=r"^forced: the run needs .*1000 B available"):
        res = run_scene(scene, progress=False, force=True)
    assert sorted(os.listdir(tmp_path)) == ["x.fits", "x_truth.fits"]
    assert res.exposure == str(tmp_path / "x.fits")


def test_run_scene_warns_above_the_threshold(tmp_path, monkeypatch):
    monkeypatch.setattr(budget_module, "WARN_FRACTION", 0.0)
    with pytest.warns(BudgetWarning, match=r"^the run needs about .*% of the") as rec:
        run_scene(_tiny_scene(tmp_path / "x.fits"), progress=False)
    assert len(rec) == 1 and rec[0].filename == __file__     # points at the caller
    assert "forced" not in str(rec[0].message)


def test_run_scene_force_must_be_a_bool(tmp_path):
    with pytest.raises(ParameterError, match="'force'"):
        run_scene(_tiny_scene(tmp_path / "x.fits"), progress=False, force="yes")
    assert os.listdir(tmp_path) == []


def test_one_line_warnings_prints_budget_warnings_as_one_line(capsys):
    import warnings
    with one_line_warnings("scenesim run"):
        warnings.simplefilter("always")
        warnings.warn("the run needs a lot", BudgetWarning)
    assert capsys.readouterr().err == "scenesim run: warning: the run needs a lot\n"


def test_pipeline_products_are_counted_by_hand():
    # The products `scenesim run --uncal --l1 --reffiles` writes after the run (issue
    # 12: the size check ignored them).  16 x 16 pixels, RAPID x 3, 2 integrations;
    # linear, so no linearity files; --l1 adds the Roman references to the JWST ones.
    scene = _scene()
    base = estimate_budget(scene)
    b = estimate_budget(scene, products=("uncal", "l1", "reffiles"))
    P, nints, ngroups, ny = 16 * 16, 2, 3, 16
    N = nints * ngroups * P
    # uncal: SCI uint16 2 N, GROUPDQ uint8 N, PIXELDQ uint32 4 P, ZEROFRAME 2 nints P
    uncal = 3 * N + 4 * P + 2 * nints * P + HEADERS
    # L1: 2 N and the amp33 channel, 128 columns of uint16 per row and resultant
    l1 = 2 * N + 2 * 128 * ny * ngroups * nints + HEADERS
    # JWST references (float32 or uint32 planes): gain, readnoise, mask 3 P;
    # saturation + dq 2 P; superbias + err + dq 3 P; linearity 7 planes + dq 8 P;
    # dark: ngroups planes of data and of err, + dq
    jwst = 4 * P * (3 + 2 + 3 + 8) + 4 * P * (2 * ngroups + 1)
    # Roman (linear: no linearity pair): gain, readnoise, mask, saturation + dq, dark
    # + error + dq: 8 planes
    roman = 4 * P * 8
    refs = jwst + roman + 10 * HEADERS
    assert b.output == base.output + uncal + l1 + refs
    assert [label.split(" ")[1] for label, _ in b.output_parts][-3:] == \
        ["JWST", "Roman", "reference"]
    # written after the run, which keeps its maps (33 P): the reference arrays (36 P)
    # and the largest model, the dark (20 ngroups P + 4 P), and 32 MB of fixed cost
    assert b.memory == 33 * P + 32 * MB + 36 * P + 20 * ngroups * P + 4 * P
    assert b.memory_parts[-1][0].startswith("writing the pipeline products")
    assert b.peak == "writing the pipeline products (uncal, l1, reffiles)"
    assert base.peak == "simulating"
    with pytest.raises(ParameterError, match="'products'"):
        estimate_budget(scene, products=("fits",))


def test_nonlinear_roman_references_by_hand():
    # A readout that is no MULTIACCUM pattern gets the Roman references only; with
    # c2, c3 the linearity (7 planes) and inverse-linearity (4: 0, 1, c2 g, c3 g^2)
    # cubes are written and held at once (issue 12: 3.1 GB on the full WFI frame)
    scene = _scene(readout={"pattern": None, "ma_table": [[0, 1], [1, 2]], "name": "X",
                            "ngroups": None, "nints": None},
                   effects={"full_well": 1e5, "nonlinearity": [-8e-7, -2e-12]})
    b = estimate_budget(scene, products=("reffiles",))
    P = 256
    out = 4 * P * 8 + 4 * P * (7 + 1 + 4 + 1) + 10 * HEADERS
    assert b.output_parts[-1][1] == out
    # the arrays 28 P, the cubes 4 (4 + 7) P, the Horner steps from the float64
    # bias 32 P; the reference 36 P; the run's maps 33 P
    assert b.memory == 33 * P + 32 * MB + 36 * P + 28 * P + 4 * (4 + 7) * P + 32 * P


# -------------------------------------------- IRS2: the raw samples (issue 12)
def _irs2_scene(path="out.fits", naxis=64, **output):
    """NIRSpec IRS2 clocking on a small array: 4 outputs of naxis / 4 columns, each
    with 4 reference samples per 16 normal pixels, and the reference output: raw
    frames of 5 (naxis / 4) (20 / 16) = 1.5625 naxis columns."""
    return parse_scene({"seed": 6, "detector": {"preset": "NIRSPEC-IRS2", "naxis1": naxis,
                                                "naxis2": naxis},
                        "noise": {"preset": "none"},
                        "readout": {"pattern": "NRSIRS2RAPID", "ngroups": 3, "nints": 2},
                        "sources": {"background": 1.0},
                        "output": {"path": str(path), "truth": False, **output}})


def test_irs2_raw_samples_by_hand():
    b = estimate_budget(_irs2_scene(), products=("uncal",))
    P, X = 64 * 64, 64 * 100              # 100 = 5 outputs x (16 + 4) samples
    R, N, Nraw = X - P, 6 * P, 6 * X
    parts = dict(b.output_parts)
    # SCI 2 N; RAWREF 2 N_R and its temporary raw copy 2 N_R
    assert parts["the exposure 'out.fits'"] == 2 * N + 4 * 6 * R + HEADERS
    # the IRS2 uncal holds every raw sample: SCI, GROUPDQ 3 N_raw, PIXELDQ 4 X
    assert parts["the JWST uncal 'out_uncal.fits' (--uncal)"] == 3 * Nraw + 4 * X + HEADERS
    sim = estimate_budget(_irs2_scene())
    plain = estimate_budget(_scene(detector={"naxis1": 64, "naxis2": 64, "subarray": None,
                                             "ref_border": 4},
                                   readout={"ngroups": 3, "nints": 2}))
    # no noise: the raw samples' buffers only, 36 R
    assert sim.memory - plain.memory == 36 * R
    fit = estimate_budget(_irs2_scene(fit="ols", refpix="irs2"))
    none = estimate_budget(_irs2_scene(fit="ols"))
    # RAWREF 2 N_R, the raw cube in float32 4 N_raw, one output's samples 12 N_raw / 4
    assert fit.memory - none.memory == 2 * 6 * R + 4 * Nraw + 3 * Nraw


def test_irs2_exposure_size_bounds_the_file(tmp_path):
    """The output estimate of an IRS2 run bounds the exposure written, and exceeds it
    by the temporary raw copy of RAWREF (on disk while the file is written) plus at
    most the 64 kB allowed for headers: a factor 1 + N_R / (N + N_R) = 1.36 here."""
    scene = _irs2_scene(tmp_path / "x.fits", naxis=128)
    label = f"the exposure {str(tmp_path / 'x.fits')!r}"
    est = dict(estimate_budget(scene).output_parts)[label]
    run_scene(scene, progress=False)
    size = os.path.getsize(tmp_path / "x.fits")
    P, X = 128 * 128, 128 * 200
    N, NR = 6 * P, 6 * (X - P)
    assert size >= 2 * (N + NR)                         # SCI and RAWREF are there
    assert 0 <= est - 2 * NR - size <= HEADERS          # the rest is headers
    assert size < est <= (1 + NR / (N + NR)) * size + HEADERS


@pytest.mark.slow
def test_full_frame_irs2_uncal_size_bounds_the_file(tmp_path):
    # jwst writes the IRS2 uncal only in the full 2048 x 2048 frame: 3200 x 2048 raw
    # samples per group, 1.56 times the pixels the old estimate counted
    pytest.importorskip("jwst")
    from scenesim.pipelines.command import write_run_products
    scene = _irs2_scene(tmp_path / "x.fits", naxis=2048)
    scene = scene.replace(readout=dataclasses.replace(scene.readout, ngroups=2, nints=1))
    b = estimate_budget(scene, products=("uncal",))
    label = f"the JWST uncal {str(tmp_path / 'x_uncal.fits')!r} (--uncal)"
    est = dict(b.output_parts)[label]
    res = run_scene(scene, progress=False, products=("uncal",))
    write_run_products(scene, res, uncal=True)
    size = os.path.getsize(tmp_path / "x_uncal.fits")
    Nraw = 2 * 2048 * 3200
    assert size >= 3 * Nraw                             # SCI and GROUPDQ of the raw cube
    assert 0 <= est - size <= HEADERS                    # exact but for the headers


MEASURE_PRODUCTS = _PEAK_HEAD + textwrap.dedent("""\
    import scenesim.run
    from scenesim.pipelines.command import write_run_products
    import scenesim.pipelines.jwst, scenesim.pipelines.roman, scenesim.pipelines.reffiles
    import jwst.datamodels, roman_datamodels.datamodels
    from scenesim.budget import estimate_budget
    from scenesim.scene import load_scene
    """) + _PEAK_RESET + textwrap.dedent("""\
    res = scenesim.run.run_scene(scene, progress=False, products=("reffiles",))
    write_run_products(scene, res, reffiles=True)
    print(status("VmHWM") - base, estimate_budget(scene, products=("reffiles",)).memory,
          estimate_budget(scene).memory)
    """)


@pytest.mark.skipif(not os.path.exists("/proc/self/clear_refs"), reason="Linux only")
@pytest.mark.parametrize("readout", ["ma_table = [[0, 1], [1, 2], [3, 3]]\nname = \"X\"",
                                     "pattern = \"RAPID\"\nngroups = 10"],
                         ids=["roman", "jwst"])
def test_reference_files_memory_bounds_a_measured_run(readout, tmp_path):
    """Writing the reference files (--reffiles) is the peak of a run of a nonlinear
    512 x 512 array with dark current and hot pixels: the Roman linearity and inverse
    cubes (a readout that is no MULTIACCUM pattern), or the JWST dark cube of 10
    groups.  The estimate with the products bounds the measured peak (VmHWM over the
    run and the products, after the imports) within a factor 1.6 (the module notes'
    coefficients count every array at its full size; pages of zeros never written and
    the allocator's reuse of freed memory make the measured peak smaller on small
    arrays); the estimate without them (before issue 12's fix) is below it."""
    pytest.importorskip("jwst")
    pytest.importorskip("roman_datamodels")
    (tmp_path / "s.toml").write_text(textwrap.dedent("""\
        seed = 3
        [detector]
        naxis1 = 512
        naxis2 = 512
        [noise]
        preset = "none"
        [readout]
        """) + readout + textwrap.dedent("""
        [sources]
        dark_current = 0.005
        background = 1.0
        hot_pixel_fraction = 0.01
        [effects]
        full_well = 1e5
        nonlinearity = [-8e-7, -2e-12]
        [output]
        path = "s.fits"
        truth = false
        """))
    (tmp_path / "m.py").write_text(MEASURE_PRODUCTS)
    res = subprocess.run([sys.executable, "m.py", "s.toml"], cwd=tmp_path,
                         capture_output=True, text=True, timeout=600)
    assert res.returncode == 0, res.stderr
    measured, estimate, without = (float(v) for v in res.stdout.split())
    print(f"measured {measured / MB:.1f} MB, estimate {estimate / MB:.1f} MB, "
          f"without the products {without / MB:.1f} MB")
    assert without < measured <= estimate <= 1.6 * measured, \
        (measured / MB, estimate / MB, without / MB)


def test_the_budget_counts_read_indices_as_the_truth_stores_them():
    # budget._index_bytes restates read_index_dtype without importing it
    from scenesim.budget import _index_bytes
    from scenesim.detector.readout import read_index_dtype
    for n in (1, 32767, 32768, 2 ** 20):
        assert _index_bytes(n) == read_index_dtype(n).itemsize
