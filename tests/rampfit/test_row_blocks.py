"""The fit by row blocks: its result does not depend on the block size, and a cube
read from its file block by block (never in memory) gives the same bytes as the
cube in memory.

Correctness only: the fit's time and memory against ramp length are measured by
``scenesim bench fit`` (BENCHMARKS.md), not asserted here.
"""

import os
import tracemalloc

import numpy as np
import pytest
from astropy.io import fits
from astropy.table import Table

from noise.errors import FileFormatError, ParameterError
from noise.fitsio import StreamingFITS
from ramp_sim import jwst_times, roman_times, simulate
from scenesim.io.cuberows import exposure_rows, npy_rows
from scenesim.io.exposure import read_exposure
from scenesim.io.header import filetype_card, nextend_card
from scenesim.rampfit import fit_ramps
from scenesim.rampfit import fitter as fitter_module

FIELDS = ("slope", "var_read", "var_poisson", "chi2", "dof", "dq", "slope_ints",
          "var_ints", "n_jumps")


def assert_same_bytes(a, b):
    """Every output array of two FitResults identical: dtype, shape and bytes."""
    for name in FIELDS:
        x, y = getattr(a, name), getattr(b, name)
        assert x.dtype == y.dtype and x.shape == y.shape, name
        assert x.tobytes() == y.tobytes(), name


def mixed_scene(times, shape=(36, 28), nints=2, seed=11):
    """Resultants (e-) where every branch of the fit runs somewhere.

    Top half dark (0.02 e-/s: every pixel takes its weights from its neighbours,
    so the refit solves whole blocks), bottom half bright (2000 e-/s) with one dark
    pixel in 7 (a sparse refit gathers them), a 3 x 3 star, jumps in 1 pixel of 6,
    saturation late in one column and from the start in another.
    """
    rng = np.random.default_rng(seed)
    ny, nx = shape
    rate = np.full(shape, 0.02)
    rate[ny // 2:] = 2000.0
    dark = rng.random(shape) < 1 / 7
    rate[ny // 2:][dark[ny // 2:]] = 0.02
    rate[4:7, 10:13] = 5e4
    t_end = times[-1][-1]
    hit = rng.random(shape) < 1 / 6
    hits = (np.where(hit, rng.uniform(0, t_end, shape), np.inf),
            np.where(hit, rng.uniform(50, 2000, shape), 0.0))
    res = simulate(rng, rate, times, 3.0, shape, nints=nints, hits=hits)
    sat = np.zeros(res.shape, bool)
    sat[:, len(times) // 2:, :, 5] = True          # late saturation
    sat[:, :, :, 6] = True                          # saturated from the first read
    res[sat] = np.nan                               # flagged values may be NaN
    return res.astype(np.float32), sat


@pytest.mark.parametrize("times", [jwst_times(8), roman_times()],
                         ids=["rapid8", "roman9"])
def test_block_size_does_not_change_a_bit(times, monkeypatch):
    kinds = set()
    items = fitter_module._refit_items

    def spy(*args):
        for fn, arg in items(*args):
            kinds.add(fn.__name__)
            yield fn, arg

    monkeypatch.setattr(fitter_module, "_refit_items", spy)
    res, sat = mixed_scene(times)
    ny, nx = res.shape[2:]
    rn = np.random.default_rng(3).uniform(2.5, 3.5, (ny, nx))
    refmask = np.zeros((ny, nx), bool)
    refmask[:2] = refmask[-2:] = True
    kw = dict(read_noise=rn, saturated=sat, jump_threshold=4.0, refmask=refmask,
              zero_point=0.0)
    ref = fit_ramps(res, times, threads=1, block_rows=ny, **kw)
    # the scene exercises what it should: jumps, neighbours' weights, saturation
    assert ref.n_jumps.sum() > 10 and (ref.dq != 0).any()
    for rows, threads in ((1, 1), (3, 2), (7, 2), (ny - 1, 1), (None, 2)):
        assert_same_bytes(ref, fit_ramps(res, times, threads=threads,
                                         block_rows=rows, **kw))
    # both refits ran: whole dark blocks, and bright blocks' dark pixels gathered
    assert kinds == {"fit_rows", "fit_pixels"}


@pytest.mark.parametrize("fitter,variance_rate",
                         [("ols", "local"), ("cds", "fit"), ("gls", "fit"),
                          ("gls", "known")])
def test_block_size_independence_of_every_fitter(fitter, variance_rate):
    times = jwst_times(6)
    res, sat = mixed_scene(times, shape=(20, 16), nints=1, seed=5)
    vr = np.full(res.shape[2:], 0.5) if variance_rate == "known" else variance_rate
    kw = dict(read_noise=3.0, saturated=sat[0], fitter=fitter, variance_rate=vr,
              jump_threshold=4.0)
    ref = fit_ramps(res[0], times, threads=1, block_rows=20, **kw)
    for rows in (1, 4, 9):
        assert_same_bytes(ref, fit_ramps(res[0], times, threads=2, block_rows=rows,
                                         **kw))


def test_default_blocks_on_one_and_two_threads_give_the_same_bytes():
    # two threads take longer blocks by default (solver.CHUNK_PIXELS_THREADED):
    # 512 x 512 pixels are 32 blocks of 16 rows on one thread, 8 of 64 on two
    times = jwst_times(5)
    res, sat = mixed_scene(times, shape=(512, 512), nints=1, seed=7)
    kw = dict(read_noise=3.0, saturated=sat[0], jump_threshold=4.0)
    ref = fit_ramps(res[0], times, threads=1, **kw)
    assert_same_bytes(ref, fit_ramps(res[0], times, threads=2, **kw))


class CountingRows:
    """A row source over an array that records every block asked for."""

    def __init__(self, array):
        self.array = array
        self.shape = array.shape
        self.dtype = array.dtype
        self.calls = []

    def rows(self, y0, y1):
        self.calls.append((y0, y1))
        return self.array[:, :, y0:y1].copy()


def test_a_row_source_is_read_by_blocks_only():
    times = jwst_times(8)
    res, sat = mixed_scene(times, nints=1)
    ny = res.shape[2]
    src = CountingRows(res)
    kw = dict(read_noise=3.0, saturated=sat, jump_threshold=4.0)
    got = fit_ramps(src, times, block_rows=5, threads=2, **kw)
    assert_same_bytes(fit_ramps(res, times, threads=1, **kw), got)
    assert max(y1 - y0 for y0, y1 in src.calls) <= 5
    # finiteness pass, first fit, two refits at most: each row read <= 4 times
    counts = np.zeros(ny, int)
    for y0, y1 in src.calls:
        counts[y0:y1] += 1
    assert counts.min() >= 2 and counts.max() <= 4


def write_exposure_file(path, dn, gain):
    """A minimal exposure file (primary + uint16 SCI + READS) of ``dn``."""
    nints, nres = dn.shape[:2]
    with open(path, "wb") as f:
        s = StreamingFITS(f)
        s.begin_image((), np.uint8, [filetype_card("exposure"), nextend_card(2),
                                     ("GAIN", gain, "e-/DN")])
        s.end_image()
        s.begin_image(dn.shape, np.uint16, name="SCI")
        for k in range(nints):
            for r in range(nres):
                s.write(dn[k, r])
        s.end_image()
        s.append_hdu(fits.BinTableHDU(Table({"resultant": np.arange(nres)}), name="READS"))


def test_exposure_file_read_by_blocks_gives_the_in_memory_fit(tmp_path):
    times = roman_times()
    res, _ = mixed_scene(times, nints=2)
    dn = np.clip(np.rint(np.nan_to_num(res, nan=70000.0) / 1.7 + 500), 0,
                 65535).astype(np.uint16)
    path = str(tmp_path / "exp.fits")
    write_exposure_file(path, dn, 1.7)
    sci, hdr, _ = read_exposure(path)
    electrons = sci.astype(np.float32) * np.float32(hdr["GAIN"])
    src = exposure_rows(path)
    assert src.shape == sci.shape and src.all_finite
    assert src.rows(3, 9).tobytes() == electrons[:, :, 3:9].tobytes()
    kw = dict(read_noise=3.0, jump_threshold=4.0)
    assert_same_bytes(fit_ramps(electrons, times, threads=1, **kw),
                      fit_ramps(src, times, threads=2, block_rows=4, **kw))
    # the first 5 resultants only
    short = exposure_rows(path, nres=5)
    assert_same_bytes(fit_ramps(electrons[:, :5], times[:5], threads=1, **kw),
                      fit_ramps(short, times[:5], threads=2, block_rows=3, **kw))


def test_streamed_fit_memory_is_bounded_by_blocks_not_by_the_cube(tmp_path):
    """A 128 x 128 x 100 float32 cube (6.6 MB) fitted from its .npy file by 2-row
    blocks: numpy's allocations peak far below the cube.  Expected: the outputs
    (~40 bytes per pixel, 0.66 MB = 0.1 cube) plus one block's work arrays (~30
    bytes per value over 1/64 of the cube's values at 4 bytes each: ~0.12 cube); the
    bound 0.4 cube leaves a factor ~2, and the in-memory fit holds the cube itself."""
    times = jwst_times(100)
    rng = np.random.default_rng(8)
    cube = simulate(rng, 5.0, times, 5.0, (128, 128)).astype(np.float32)
    path = str(tmp_path / "cube.npy")
    np.save(path, cube)
    ref = fit_ramps(cube, times, read_noise=5.0, threads=1)
    del cube
    src = npy_rows(path)
    tracemalloc.start()
    try:
        got = fit_ramps(src, times, read_noise=5.0, threads=1, block_rows=2)
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert_same_bytes(ref, got)
    cube_bytes = os.path.getsize(path)
    assert peak < 0.4 * cube_bytes, (peak, cube_bytes)


def test_bad_row_sources_and_block_rows_are_refused_before_work(tmp_path):
    times = jwst_times(4)
    res = np.ones((4, 6, 5), np.float32) * np.arange(4)[:, None, None]

    class Bad(CountingRows):
        def rows(self, y0, y1):
            return self.array[:, :, y0:y1 + 1]

    with pytest.raises(ParameterError, match="block_rows"):
        fit_ramps(res, times, read_noise=1.0, block_rows=0)
    with pytest.raises(ParameterError, match="expected"):
        fit_ramps(Bad(res[None]), times, read_noise=1.0, block_rows=2)
    src = CountingRows(res[None])
    src.shape = (1, 4, 6)
    with pytest.raises(ParameterError, match="nints, nres, ny, nx"):
        fit_ramps(src, times, read_noise=1.0)
    assert src.calls == []
    nan = res[None].copy()
    nan[0, 2, 4, 1] = np.nan
    src = CountingRows(nan)
    with pytest.raises(ParameterError, match="integration 0 resultant 2 has 1 NaN"):
        fit_ramps(src, times, read_noise=1.0, block_rows=2)
    path = tmp_path / "cube.npy"
    np.save(path, res)
    with pytest.raises(ParameterError, match="nres"):
        npy_rows(path, nres=5)
    path.write_bytes(path.read_bytes()[:-8])
    with pytest.raises(FileFormatError, match="truncated"):
        npy_rows(path)


def test_exposure_rows_refuses_what_it_cannot_read_by_blocks(tmp_path):
    dn = np.full((1, 3, 4, 5), 7, np.uint16)
    path = str(tmp_path / "exp.fits")
    write_exposure_file(path, dn, 2.0)
    src = exposure_rows(path)
    # the header's GAIN, and an explicit one
    assert np.all(src.rows(0, 4) == 14.0) and src.dtype == np.float32
    assert np.all(exposure_rows(path, gain=0.5).rows(1, 2) == 3.5)
    with pytest.raises(ParameterError, match="nres"):
        exposure_rows(path, nres=4)
    gz = tmp_path / "exp.fits.gz"
    gz.write_bytes(b"")
    with pytest.raises(FileFormatError, match="uncompressed"):
        exposure_rows(gz)
    truncated = tmp_path / "short.fits"
    truncated.write_bytes((tmp_path / "exp.fits").read_bytes()[:2880 * 3])
    with pytest.raises(FileFormatError):
        exposure_rows(truncated)
