"""The forked producer of small-frame draws (noise.fast.producer), and what it feeds.

* the protocol: results arrive in order, a slot is reused only after its release, a
  failure in the child is raised in the parent with its traceback, closing early
  stops and reaps the child;
* the small-frame path gives the same frames whether the 1/f lines and reset levels
  come from the forked helper or are made in-process (threads = 2 against 1), and it
  really forks when it may (and not when another thread runs);
* single-output detectors synthesise correlated + uncorrelated pink as one series:
  checked against the amplitude definition (PSD level and frame variance of
  ``hypot(c_pink, u_pink)``), and the separate components refuse to be asked for.
"""

import os
import signal
import threading
import time

import numpy as np
import pytest

import noise.generator as generator_module
from noise import NIRSPEC_DEFAULTS, ZERO_NOISE, NoiseGenerator, preset
from noise.clock import Detector
from noise.errors import HelperProcessError, ParameterError, ScenesimError
from noise.fast.producer import ForkedProducer, available

from forks import children_of, record_made

pytestmark = pytest.mark.skipif(not available(), reason="needs POSIX fork (Linux)")


def _fill(j, outs):
    a, b = outs
    a[:] = j
    b[:] = -j


def test_results_in_order_through_a_small_ring():
    with ForkedProducer(_fill, 9, [(3, 4), (5,)], depth=2) as prod:
        for j in range(9):
            a, b = prod.get(j)
            assert a.shape == (3, 4) and b.shape == (5,)
            # the child may be at most depth - 1 results ahead: slot j % 2 still holds j
            assert (a == j).all() and (b == -j).all()
            prod.release(j)
        with pytest.raises(RuntimeError, match="in order"):
            prod.get(3)


def _fail_at_2(j, outs):
    if j == 2:
        raise ValueError("boom at two")
    outs[0][:] = j


def test_child_failure_is_raised_with_its_traceback():
    prod = ForkedProducer(_fail_at_2, 5, [(2,)], depth=3)
    try:
        for j in range(2):
            assert (prod.get(j)[0] == j).all()
            prod.release(j)
        with pytest.raises(RuntimeError, match="boom at two"):
            prod.get(2)
    finally:
        prod.close()


def test_close_early_reaps_the_child():
    prod = ForkedProducer(_fill, 1000, [(64,), (1,)], depth=2)
    prod.get(0)
    pid = prod.pid
    prod.close()
    prod.close()                                   # idempotent
    assert prod.pid is None
    with pytest.raises(ChildProcessError):         # already reaped: no zombie left
        os.waitpid(pid, os.WNOHANG)


def test_not_available_while_another_thread_runs():
    stop = threading.Event()
    t = threading.Thread(target=stop.wait)
    t.start()
    try:
        assert not available()
    finally:
        stop.set()
        t.join()
    assert available()


# ----------------------------------------------------------- the small-frame path
WINDOW = preset("H2RG", naxis1=256, naxis2=256).window(40, 60, 32, 24)


def _count_forks(monkeypatch):
    """Record the producers the generator makes (a list of them)."""
    return record_made(monkeypatch, generator_module, "ForkedProducer")


@pytest.mark.parametrize("kwargs", [dict(nints=100), dict(nints=130, reads=[0, 3]),
                                    dict(nints=100, dn_gain=2.0, reuse=2)])
def test_forked_draws_give_the_in_process_frames(monkeypatch, kwargs):
    """All components on (RTN too), a window: 2 threads (forked helper) == 1 thread.

    64 frames per batch here: 400 and 260 frames are 7 and 5 batches, enough to fork.
    """
    params = NIRSPEC_DEFAULTS.replace(rtn_fraction=0.02)
    made = _count_forks(monkeypatch)
    one = [f.copy() for *_, f in NoiseGenerator(WINDOW, params, rng=5, threads=1)
           .frames(4, **kwargs)]
    assert made == []
    two = [f.copy() for *_, f in NoiseGenerator(WINDOW, params, rng=5, threads=2)
           .frames(4, **kwargs)]
    assert len(made) == 1 and made[0].count >= generator_module._FORK_MIN_BATCHES
    assert len(one) == len(two)
    for a, b in zip(one, two):
        np.testing.assert_array_equal(a, b)


def test_no_fork_while_another_thread_runs(monkeypatch):
    made = _count_forks(monkeypatch)
    stop = threading.Event()
    t = threading.Thread(target=stop.wait)
    t.start()
    try:
        frames = [f.copy() for *_, f in NoiseGenerator(WINDOW, NIRSPEC_DEFAULTS, rng=6,
                                                       threads=2).frames(4, nints=100)]
    finally:
        stop.set()
        t.join()
    assert made == []
    ref = [f for *_, f in NoiseGenerator(WINDOW, NIRSPEC_DEFAULTS, rng=6,
                                         threads=1).frames(4, nints=100)]
    for a, b in zip(frames, ref):
        np.testing.assert_array_equal(a, b)


def test_consumer_stopping_early_leaves_no_child(monkeypatch):
    made = _count_forks(monkeypatch)
    it = NoiseGenerator(WINDOW, NIRSPEC_DEFAULTS, rng=7, threads=2).frames(4, nints=200)
    next(it)
    assert len(made) == 1
    pid = made[0]._pid
    it.close()                                     # finally: producer.close()
    assert made[0]._pid is None
    with pytest.raises(ChildProcessError):         # reaped: no zombie left
        os.waitpid(pid, os.WNOHANG)


# ----------------------------------------------------- merged pink on one output
ONE_OUT = Detector(name="T", naxis1=64, naxis2=64, n_out=1, nroh=12, nfoh=1,
                   ref_border=0)
RATE = 1.0 / ONE_OUT.dt


def test_merged_pink_psd_level(welch, pink_level):
    """c_pink and u_pink on one output: one 1/f series of amplitude hypot(c, u)."""
    c, u = 1.5, 0.8
    gen = NoiseGenerator(ONE_OUT, ZERO_NOISE.replace(c_pink=c, u_pink=u), rng=111,
                         threads=1)
    nseg, nper = 64, 2 ** 15
    x = gen.timeline("pink", 0, 0, nseg * nper)
    level = pink_level(np.hypot(c, u), RATE, ONE_OUT.frame_samples, ZERO_NOISE.f_min)
    f, psd, K = welch(x, nper, RATE)
    sel = np.arange(100, nper // 2 - 1, 2)
    ratio = psd[sel] * f[sel] / level
    # mean of N ratios, each a mean of K exponentials (relative sigma 1/sqrt(K)), bins
    # two apart (independent with a Hann window): standard error 1/sqrt(K N)
    se = 1.0 / np.sqrt(K * ratio.size)
    assert abs(ratio.mean() - 1.0) < 5 * se, (ratio.mean(), se)
    # the level separates the merged amplitude from c alone by far more than 5 se
    assert (c ** 2 + u ** 2) / c ** 2 - 1.0 > 10 * se


def test_merged_pink_frame_variance():
    """Only c_pink and u_pink: E[frame variance] = c^2 + u^2, and the frames hold
    the merged line."""
    c, u = 3.0, 1.0
    params = ZERO_NOISE.replace(c_pink=c, u_pink=u)
    frame = NoiseGenerator(ONE_OUT, params, rng=112, threads=1).cube(1)[0, 0]
    gen = NoiseGenerator(ONE_OUT, params, rng=112, threads=1)
    L = ONE_OUT.frame_samples
    x = gen.timeline("pink", 0, L, 2000 * L).reshape(2000, L)     # slots 1 .. 2000
    np.testing.assert_array_equal(x[0][ONE_OUT.pixel_sample_index()], frame)
    # amp^2 is the expected variance over a frame's L time-line samples, mean removed
    var = x.astype(np.float64).var(axis=1)
    # consecutive frames of a 1/f series are correlated: standard error from the
    # scatter of 40 batch means of 50 frames
    means = var.reshape(40, 50).mean(axis=1)
    se = means.std(ddof=1) / np.sqrt(40)
    assert abs(var.mean() - (c ** 2 + u ** 2)) < 5 * se, (var.mean(), se)
    assert abs(var.mean() - c ** 2) > 5 * se        # distinguishes c alone


def test_merged_pink_components_are_not_offered_separately():
    gen = NoiseGenerator(ONE_OUT, ZERO_NOISE.replace(c_pink=3.0, u_pink=1.0), rng=113)
    for name in ("c_pink", "u_pink"):
        with pytest.raises(ParameterError, match="'pink'"):
            gen.timeline(name, 0, 0, 10)
    # with one of them off nothing is merged: each is offered, and 'pink' is it
    only_c = NoiseGenerator(ONE_OUT, ZERO_NOISE.replace(c_pink=3.0), rng=113)
    np.testing.assert_array_equal(only_c.timeline("pink", 0, 0, 100),
                                  only_c.timeline("c_pink", 0, 0, 100))


def test_pink_is_the_sum_on_several_outputs():
    det = preset("H2RG", naxis1=128, naxis2=128, n_out=4)
    gen = NoiseGenerator(det, ZERO_NOISE.replace(c_pink=3.0, u_pink=1.0), rng=114)
    total = gen.timeline("pink", 2, 500, 1000)
    parts = gen.timeline("c_pink", 0, 500, 1000) + gen.timeline("u_pink", 2, 500, 1000)
    np.testing.assert_array_equal(total, parts)


def test_progress_bar_starts_no_thread():
    """The command's progress bar leaves the process single-threaded (so small frames
    may still fork) and leaves tqdm's own setting as it was."""
    from tqdm import tqdm

    from scenesim.run import progress_bar
    before = tqdm.monitor_interval
    bar = progress_bar(100, "read", "test")
    try:
        assert threading.active_count() == 1 and available()
        assert tqdm.monitor_interval == before
    finally:
        bar.close()


def _slow(j, arrays):
    time.sleep(0.05)
    arrays[0][:] = j


def test_killed_helper_gives_one_clear_error():
    # Old behaviour: a RuntimeError with a multi-line message, which the command
    # printed as a traceback.  New: HelperProcessError (a ScenesimError), one line.
    prod = ForkedProducer(_slow, 100, [(8,)], depth=2)
    try:
        prod.get(0)
        os.kill(prod.pid, signal.SIGKILL)
        with pytest.raises(HelperProcessError, match="ended without a result") as info:
            prod.release(0)
            prod.get(1)
            prod.release(1)
            prod.get(2)
        assert isinstance(info.value, ScenesimError)
        assert "\n" not in str(info.value)
    finally:
        prod.close()
    assert prod.pid is None


def test_helper_ignores_interrupts_the_parent_handles():
    # Ctrl-C reaches the whole process group: the helper ignores it (the parent stops
    # it), so the parent sees its own KeyboardInterrupt, not a helper failure
    prod = ForkedProducer(_slow, 100, [(8,)], depth=2)
    try:
        prod.get(0)
        os.kill(prod.pid, signal.SIGINT)
        os.kill(prod.pid, signal.SIGTERM)
        prod.release(0)
        assert (prod.get(1)[0] == 1).all()
    finally:
        prod.close()


class _Stop(Exception):
    pass


#: The at-fork hook of the next test (os.register_at_fork cannot be undone, so it
#: is registered once and acts only while armed).
_FORK_HOOK = {"armed": False, "masks": []}


def _before_fork():
    if _FORK_HOOK["armed"]:
        _FORK_HOOK["masks"].append(signal.pthread_sigmask(signal.SIG_BLOCK, []))
        os.kill(os.getpid(), signal.SIGTERM)      # lands inside fork's handlers


os.register_at_fork(before=_before_fork)


def test_an_interrupt_during_fork_is_raised_after_it_not_lost():
    # Old behaviour: a SIGTERM landing while os.fork ran its at-fork handlers was
    # raised inside them, printed as "Exception ignored" and lost; the run went on
    # and ended with status 0.  New: the interrupts are blocked across the fork, so
    # the signal stays pending and is raised once the producer is built, which is
    # then stopped (its child reaped).
    def stop(signum, frame):
        raise _Stop(signum)

    before = children_of()
    old = signal.signal(signal.SIGTERM, stop)
    _FORK_HOOK.update(armed=True, masks=[])
    try:
        with pytest.raises(_Stop):
            ForkedProducer(_slow, 100, [(8,)], depth=2)
    finally:
        _FORK_HOOK["armed"] = False
        signal.signal(signal.SIGTERM, old)
    blocked = _FORK_HOOK["masks"][0]
    assert {signal.SIGINT, signal.SIGTERM, signal.SIGHUP} <= blocked
    assert not {signal.SIGINT, signal.SIGTERM, signal.SIGHUP} & \
        signal.pthread_sigmask(signal.SIG_BLOCK, [])
    assert children_of() == before           # the child was reaped
