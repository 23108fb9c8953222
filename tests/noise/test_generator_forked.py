"""Large frames whose 1/f lines are made by forked helpers (``noise.generator._ForkedLines``).

* the frames are the same bytes as one thread's (the thread pool's) for every
  component, series grouping, reads subset, integration subset, DN output, reused
  buffers, interleaved detector and thread count, and the helpers really ran;
* only runs of at least ``Layout.fork_min_pixels`` pixels fork, never while another
  thread runs, never for the raw frames of an interleaved detector (their extra
  samples read every output's series again);
* no helper outlives its iterator: run to the end, closed early, never started and
  dropped; a helper's failure is one clear error in the parent.
"""

import gc
import threading

import numpy as np
import pytest

import noise.generator as generator_module
from noise import NIRSPEC_DEFAULTS, NoiseGenerator, preset
from noise.errors import HelperProcessError
from noise.fast.producer import available
from noise.generator import Layout

from forks import children_of, record_made

pytestmark = pytest.mark.skipif(not available(), reason="needs POSIX fork (Linux)")

ALL_ON = NIRSPEC_DEFAULTS.replace(rtn_fraction=0.02)     # every component, RTN too
FORK = Layout(fork_min_pixels=0)                          # fork whenever allowed
DET = preset("H2RG", naxis1=256, naxis2=256, n_out=4)     # 65536 px: the banded path


def _spy(monkeypatch):
    """Record every ``_ForkedLines`` made by the generator module."""
    return record_made(monkeypatch, generator_module, "_ForkedLines")


def _frames(det, params, threads, layout, **kw):
    gen = NoiseGenerator(det, params, rng=23, threads=threads, layout=layout)
    return [(i, k, tuple(p.copy() for p in f) if isinstance(f, tuple) else f.copy())
            for i, k, f in gen.frames(4, **kw)]


def _assert_same(got, ref):
    assert [(i, k) for i, k, _ in got] == [(i, k) for i, k, _ in ref]
    for (*_, a), (*_, b) in zip(got, ref):
        np.testing.assert_array_equal(a, b)


@pytest.mark.parametrize("case", [
    dict(),                                                  # 4 outputs, 3 groups
    dict(nints=3, integrations=[0, 2], reads=[1, 3]),        # skipped slots
    dict(dn_gain=1.7, reuse=2),                              # DN, reused buffers
    dict(threads=3),                                         # 3 helpers, 3 row threads
    dict(layout=Layout(fork_min_pixels=0, series_per_task=3, band_rows=64),
         det=preset("H2RG", naxis1=256, naxis2=256, n_out=8)),  # short last groups
    dict(det=preset("H2RG", naxis1=256, naxis2=256, n_out=1)),  # one merged series
    dict(det=preset("NIRSPEC-IRS2").stripe(0, 32, "S32")),   # interleaved slots
    dict(det=preset("WFI", ref_output=True).stripe(0, 16, "S16"), raw=True),  # + reference output
    dict(det=preset("WFI", ref_output=True).stripe(0, 16, "S16"), raw="split", dn_gain=1.3),
])
def test_forked_lines_give_one_threads_frames(monkeypatch, case):
    case = dict(case)
    det = case.pop("det", DET)
    threads = case.pop("threads", 2)
    layout = case.pop("layout", FORK)
    ref = _frames(det, ALL_ON, 1, layout, **case)
    made = _spy(monkeypatch)
    got = _frames(det, ALL_ON, threads, layout, **case)
    assert len(made) == 1 and made[0].nhelpers >= 1
    if case.get("raw") == "split":                           # (image, extra samples)
        got = [(i, k, np.hstack(f)) for i, k, f in got]
        ref = [(i, k, np.hstack(f)) for i, k, f in ref]
    _assert_same(got, ref)
    assert len({float(f.std()) for *_, f in ref}) == len(ref)   # frames differ


def test_only_long_runs_fork(monkeypatch):
    """Default layout: forking costs tens of ms, so a run forks from
    ``fork_min_pixels`` pixels in all (here 4 frames of 256^2) and not below, nor
    for the raw frames of an interleaved detector."""
    made = _spy(monkeypatch)
    ref = _frames(DET, ALL_ON, 1, Layout())
    _assert_same(_frames(DET, ALL_ON, 2, Layout()), ref)                  # 2^24 px
    _assert_same(_frames(DET, ALL_ON, 2, Layout(fork_min_pixels=4 * 65537)), ref)
    assert made == []
    _assert_same(_frames(DET, ALL_ON, 2, Layout(fork_min_pixels=4 * 65536)), ref)
    assert len(made) == 1
    det = preset("NIRSPEC-IRS2").stripe(0, 32, "S32")
    raw_ref = _frames(det, ALL_ON, 1, FORK, raw=True)
    _assert_same(_frames(det, ALL_ON, 2, FORK, raw=True), raw_ref)
    assert len(made) == 1


def test_no_fork_while_another_thread_runs(monkeypatch):
    made = _spy(monkeypatch)
    stop = threading.Event()
    t = threading.Thread(target=stop.wait)
    t.start()
    try:
        got = _frames(DET, ALL_ON, 2, FORK)
    finally:
        stop.set()
        t.join()
    assert made == []
    _assert_same(got, _frames(DET, ALL_ON, 1, FORK))


def test_helpers_never_outlive_their_iterator(monkeypatch):
    made = _spy(monkeypatch)
    before = children_of()
    gen = NoiseGenerator(DET, ALL_ON, rng=3, threads=2, layout=FORK)
    list(gen.frames(3))                                      # to the end
    assert children_of() == before
    it = gen.frames(50)                                      # closed early
    next(it)
    assert children_of() - before
    it.close()
    assert children_of() == before
    it = gen.frames(50)                                      # never started, dropped
    assert children_of() - before and len(made) == 3
    made.clear()                                             # the spy's reference
    del it
    gc.collect()
    assert children_of() == before


def _fail(*args):
    raise MemoryError("no room for the lines")


def test_a_helper_failure_is_one_clear_error(monkeypatch):
    monkeypatch.setattr(generator_module, "_make_band_lines", _fail)
    before = children_of()
    it = NoiseGenerator(DET, ALL_ON, rng=3, threads=2, layout=FORK).frames(4)
    with pytest.raises(HelperProcessError, match="MemoryError: no room for the lines"):
        next(it)
    it.close()
    assert children_of() == before
