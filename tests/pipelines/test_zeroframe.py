"""The zero frame of a JWST uncal: the first read of each integration, from a re-run
whose draws are the exposure's own (no pipeline needed)."""

import numpy as np
import pytest

from noise.errors import FileFormatError
from scenesim.detector.readout import Readout
from scenesim.engine import EngineOptions
from scenesim.pipelines.zeroframe import has_zero_frame, split_first_group, zero_frames
from scenesim.run import build_engine, write_exposure
from scenesim.scene import parse_scene


def _scene(*, seed=11, noise="none", rate=2000.0, pattern="MEDIUM8", ngroups=3, nints=2):
    return parse_scene({
        "seed": seed,
        "detector": {"preset": "NIRCAM", "nfoh": 2,
                     "subarray": {"kind": "window", "x0": 0, "y0": 0, "nx": 32,
                                  "ny": 32}},
        "noise": {"preset": noise},
        "readout": {"pattern": pattern, "ngroups": ngroups, "nints": nints},
        "sources": {"background": rate},
        "effects": {"gain": 2.0},
        "output": {"path": "x.fits", "truth": False}})


def _exposure(scene, options=EngineOptions()):
    engine, _ = build_engine(scene, options=options)
    return engine, write_exposure(engine, None)["exposure"].sci


def test_which_patterns_have_one():
    assert has_zero_frame(Readout.named("MEDIUM8", 3), "NIRCAM")
    assert not has_zero_frame(Readout.named("RAPID", 3), "NIRCAM")      # group 1 is it
    assert not has_zero_frame(Readout.named("NRS", 3), "NIRSPEC")
    ro = Readout.named("MEDIUM8", 3)
    assert split_first_group(ro) == tuple((k,) for k in range(8)) + ro.resultants[1:]


def test_noise_free_zero_frame_is_the_first_read():
    """No noise, no shot noise: read k holds exactly rate (k + 1) t_frame (rolling
    reset), so the zero frame is rint(rate t_frame / gain) and group 1 the rounded
    mean of the rounded reads 1..8."""
    options = EngineOptions(shot_noise=False)
    scene = _scene()
    engine, sci = _exposure(scene, options)
    zero = zero_frames(scene, sci, options=options)
    t, g = engine.detector.frame_time, engine.gain
    rate = engine.rate * np.ones(engine.detector.shape)
    assert np.array_equal(zero[0], np.rint(rate * t / g).astype(np.uint16))
    assert np.array_equal(zero[1], zero[0])          # every integration starts alike
    reads = np.rint(rate[None] * np.arange(1, 9)[:, None, None] * t / g)
    assert np.array_equal(sci[0, 0], np.rint(reads.mean(axis=0)).astype(np.uint16))
    assert np.any(zero[0] > 0)


def test_zero_frame_with_shot_noise_against_theory():
    """With shot noise (no read noise): E[group 1 - zero frame] = rate t_frame (4.5 -
    1) / gain DN (reads 1..8 average to 4.5 frame times); pixels are independent."""
    scene = _scene(seed=5)
    engine, sci = _exposure(scene)
    zero = zero_frames(scene, sci)
    live = ~engine.detector.reference_mask()
    d = (sci[:, 0].astype(np.float64) - zero)[:, live]
    expect = 2000.0 * engine.detector.frame_time * 3.5 / engine.gain
    # 2 x 576 independent pixels: 5 standard errors of the mean, plus 0.05 DN for the
    # ADC rounding (each term's rounding error is within +-0.5 DN, mean ~0)
    assert abs(d.mean() - expect) < 5 * d.std() / np.sqrt(d.size) + 0.05
    # the zero frame's charge is Poisson(rate t_frame): variance = mean (DN: / gain)
    z = zero[:, live].astype(np.float64) * engine.gain
    lam = 2000.0 * engine.detector.frame_time
    # 1152 draws: the sample variance has a relative s.e. of sqrt(2/n) = 4 %; 5 sigma,
    # plus the gain^2/12 = 0.33 e-^2 of the ADC rounding
    assert abs(z.var() - lam - engine.gain ** 2 / 12) < 5 * np.sqrt(2 / z.size) * lam


def test_noisy_run_is_the_same_realisation_and_a_foreign_one_is_refused():
    scene = _scene(noise="nirspec", rate=50.0, seed=21)
    _, sci = _exposure(scene)
    zero = zero_frames(scene, sci)                  # every group rebuilt bit for bit
    assert zero.shape == (2, 32, 32)
    _, other = _exposure(scene.replace(seed=22))
    with pytest.raises(FileFormatError, match="not this scene's realisation"):
        zero_frames(scene, other)


@pytest.mark.parametrize("threads", [1, 2])
def test_the_run_keeps_the_zero_frame_the_re_run_rebuilds(threads):
    """The zero frame kept by the run itself (simulate(zero_frame=True)) is the one
    the independent re-run with the first group split rebuilds (which checks every
    group of the exposure bit for bit), with noise and shot noise, for any threads;
    a run not asked for it keeps none."""
    scene = _scene(noise="nirspec", rate=50.0, seed=23)
    options = EngineOptions(threads=threads)
    engine, _ = build_engine(scene, options=options)
    out = write_exposure(engine, None, zero_frame=True)
    assert np.array_equal(out["zero_frame"],
                          zero_frames(scene, out["exposure"].sci, options=options))
    engine, _ = build_engine(scene, options=options)
    assert "zero_frame" not in write_exposure(engine, None)
