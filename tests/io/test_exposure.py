"""Tests of :mod:`scenesim.io.exposure`: file layout, header keywords, truth contents and
atomic writing (no partial or temporary file left behind on failure)."""

import os

import numpy as np
import pytest
from astropy.table import Table

import noise
from noise.clock import preset
from noise.errors import FileFormatError, ParameterError
from scenesim.engine import ChargeEngine, CosmicRayHits, EngineOptions, VariableSource
from scenesim.io.exposure import Exposure, read_exposure, read_truth, truth_path_for
from scenesim.run import write_exposure
from scenesim.sky.lightcurve import LightCurve
from scenesim.detector.readout import Readout


def _det():
    """64x64 H2RG, t_frame = (64 + 1) * (16 + 12) * 1e-5 s = 0.0182 s."""
    return preset("H2RG", naxis1=64, naxis2=64)


def _ma_readout(nints=2):
    return Readout.multiaccum(4, 3, groupgap=2, nskip=1, nints=nints, name="TESTPATT")


def test_truth_path_for():
    assert truth_path_for(os.path.join("a", "x.fits")) == os.path.join("a", "x_truth.fits")
    assert truth_path_for("y") == "y_truth.fits"


def test_round_trip_header_and_noise_free_ramp(tmp_path):
    det = _det()
    ro = _ma_readout()
    rate = 150.0
    gain = 1.0
    eng = ChargeEngine(det, ro, rate=rate, gain=gain, rng=8,
                       options=EngineOptions(shot_noise=False))
    path = tmp_path / "exp.fits"
    write_exposure(eng, str(path), cards=[("SCENE", "unit", "scene name")])
    sci, hdr, reads = read_exposure(str(path))
    assert sci.dtype == np.uint16
    assert sci.shape == (2, 3, 64, 64)
    tf = 65 * 28 * 1e-5
    expected = {"NINTS": 2, "NGROUPS": 3, "NFRAMES": 4, "GROUPGAP": 2, "DROPFRM1": 1,
                "READPATT": "TESTPATT", "NOUTPUTS": 4, "DETECTOR": "H2RG",
                "SUBARRAY": "FULL", "GAIN": gain, "SCENE": "unit"}
    for key, value in expected.items():
        assert hdr[key] == value, key
    assert hdr["TFRAME"] == pytest.approx(tf, rel=1e-12)
    assert hdr["TGROUP"] == pytest.approx((4 + 2) * tf, rel=1e-12)
    # READS table: group g averages reads 1+6g .. 4+6g, read k at (k+1) t_frame
    assert len(reads) == 3
    for g in range(3):
        first = 1 + 6 * g
        assert reads["FIRST_READ"][g] == first
        assert reads["NREADS"][g] == 4
        assert list(reads["READS"][g]) == list(range(first, first + 4))
        assert reads["TMEAN"][g] == pytest.approx(tf * (first + 1.5 + 1), rel=1e-12)
        np.testing.assert_allclose(reads["READ_TIMES"][g],
                                   tf * (np.arange(first, first + 4) + 1), rtol=1e-12)
    # zero noise, constant rate: resultant = rate * tbar; each read rounds by <= 0.5 DN
    # and the average of the rounded reads is rounded again: |error| <= 1 DN
    reg = ~det.reference_mask()
    for i in range(2):
        for g in range(3):
            tbar = tf * (1 + 6 * g + 1.5 + 1)
            assert np.all(np.abs(sci[i, g][reg] - rate * tbar) <= 1.0 + 1e-9)
            assert np.all(sci[i, g][~reg] == 0)
    assert [p.name for p in tmp_path.iterdir()] == ["exp.fits"]


def test_in_memory_equals_file(tmp_path):
    det = _det()
    ro = _ma_readout(nints=1)

    def eng():
        return ChargeEngine(det, ro, rate=30.0, noise_params=noise.NoiseParams(),
                            rng=77, options=EngineOptions(threads=1))

    out = write_exposure(eng(), None, cards=[("SCENE", "mem", "scene name")])
    mem = out["sci"]
    path = str(tmp_path / "e.fits")
    write_exposure(eng(), path, cards=[("SCENE", "mem", "scene name")])
    sci, hdr, reads = read_exposure(path)
    np.testing.assert_array_equal(sci, mem)
    # the in-memory Exposure holds what read_exposure returns from the file: the
    # same array, header cards (values and comments) and READS table
    exp = out["exposure"]
    assert isinstance(exp, Exposure) and exp.sci is mem
    def cards(h):
        return [(c.keyword, c.value, c.comment) for c in h.cards]

    assert cards(exp.header) == cards(hdr)
    assert exp.reads.colnames == reads.colnames
    for name in reads.colnames:
        assert exp.reads[name].dtype == reads[name].dtype, name
        np.testing.assert_array_equal(exp.reads[name], reads[name], name)
    back = Exposure.read(path)
    assert back.name == path and cards(back.header) == cards(hdr)
    assert [p.name for p in tmp_path.iterdir()] == ["e.fits"]


def test_truth_file_contents(tmp_path):
    det = _det()
    ro = Readout.from_reads([[0], [1, 2], [4]], nints=2)
    nx = det.nx
    tf = det.frame_time
    rate = np.full(det.shape, 2000.0)
    full_well = 100.0                       # rate*t_frame = 36.4 e- per frame
    cr = CosmicRayHits(np.array([2.5 * tf, 100.0]), np.array([20 * nx + 30, 5 * nx + 9]),
                       np.array([321.0, 50.0]))
    idx = np.array([33 * nx + 33])
    src = VariableSource(idx, np.array([500.0]), LightCurve.step(tf * 2.0, before=0.0, after=1.0))
    sources = Table({"x": [33.0], "y": [33.0], "flux": [500.0]})

    def make():
        return ChargeEngine(det, ro, rate=rate, full_well=full_well, cosmic_rays=cr,
                            variable_sources=[src], noise_params=noise.NoiseParams(),
                            ipc_kernel=np.array([[0, 0.01, 0], [0.01, 0.96, 0.01],
                                                 [0, 0.01, 0]]),
                            rng=5, options=EngineOptions(threads=1, shot_noise=False))

    path = str(tmp_path / "e.fits")
    tpath = truth_path_for(path)
    out = write_exposure(make(), path, truth_path=tpath, save_charge=True,
                         save_noise=True, sources=sources)
    truth = read_truth(tpath)
    for name in ("RATE", "RATE_IPC", "SATREAD", "SATGROUP", "CRS", "SOURCES",
                 "CHARGE", "NOISE"):
        assert name in truth, name
    # reference run of the engine itself, same seed
    charge = np.zeros((2, 3) + det.shape, np.float32)
    noise_r = np.zeros_like(charge)

    with make().simulate(save_charge=True, save_noise=True) as run:
        for res in run:
            charge[res.integration, res.index] = res.charge
            noise_r[res.integration, res.index] = res.noise
    ref = {"sat_read": run.sat_read}
    np.testing.assert_array_equal(truth["CHARGE"], charge)
    np.testing.assert_array_equal(truth["NOISE"], noise_r)
    np.testing.assert_array_equal(truth["SATREAD"], ref["sat_read"])
    np.testing.assert_array_equal(out["sat_read"], ref["sat_read"])
    # expected rate: 2000 e-/s on regular pixels, 0 on reference pixels; the step
    # source (on from 2 tf) at its mean over the integrations' windows, the spans of
    # their resultants' mean times: integration i resets at 6 i tf, its resultants
    # average reads at 1, (2, 3) and 5 tf after, each read t_p (the pixel's clock
    # offset) into its frame, so [1, 5] tf + t_p (on for (3 + t_p / tf) / 4 of it)
    # and [7, 11] tf + t_p (on)
    reg = ~det.reference_mask()
    exp_rate = np.where(reg, 2000.0, 0.0)
    tp = det.pixel_time()[33, 33]
    exp_rate[33, 33] += 500.0 * ((3 + tp / tf) / 4 + 1.0) / 2
    np.testing.assert_allclose(truth["RATE"], exp_rate, rtol=1e-6)
    # RATE_IPC conserves flux away from the border (kernel sums to 1)
    np.testing.assert_allclose(truth["RATE_IPC"][10:50, 10:50].sum(),
                               truth["RATE"][10:50, 10:50].sum(), rtol=1e-3)
    # saturation at 100 e- (no shot noise): read k holds 36.4 (k+1) e- -> first read
    # k=2 (109.2 e-), which is in resultant 1 (reads 1, 2)
    assert np.all(truth["SATREAD"][:, reg] == 2)
    assert np.all(truth["SATGROUP"][:, reg] == 1)
    assert np.all(truth["SATREAD"][:, ~reg] == -1)
    assert np.all(truth["SATGROUP"][:, ~reg] == -1)
    crs = truth["CRS"]
    np.testing.assert_allclose(crs["TIME"], [2.5 * tf, 100.0])
    assert list(crs["X"]) == [30, 9] and list(crs["Y"]) == [20, 5]
    np.testing.assert_allclose(crs["CHARGE"], [321.0, 50.0])
    # the second deposit falls after the last read of the exposure: never seen
    assert list(crs["SEEN"]) == [True, False]
    assert list(truth["SOURCES"]["x"]) == [33.0]
    assert sorted(p.name for p in tmp_path.iterdir()) == ["e.fits", "e_truth.fits"]


def test_truth_cosmic_charge_injected(tmp_path):
    """CHARGE in the truth file holds exactly the injected deposit (no shot noise)."""
    det = _det()
    ro = Readout.from_reads([[0], [1], [2]])
    nx = det.nx
    tf = det.frame_time
    # pixel (20, 30) is read at t_pix + slot * tf; 2.5 tf lies between its reads 1, 2
    cr = CosmicRayHits(np.array([2.5 * tf]), np.array([20 * nx + 30]), np.array([321.0]))
    eng = ChargeEngine(det, ro, cosmic_rays=cr, rng=1,
                       options=EngineOptions(shot_noise=False))
    tpath = str(tmp_path / "t_truth.fits")
    write_exposure(eng, None, truth_path=tpath, save_charge=True)
    truth = read_truth(tpath)
    expect = np.zeros((1, 3) + det.shape)
    assert det.pixel_time()[20, 30] < 0.5 * tf
    expect[0, 2, 20, 30] = 321.0
    np.testing.assert_array_equal(truth["CHARGE"], expect)
    assert list(truth["CRS"]["SEEN"]) == [True]
    assert "NOISE" not in truth


def test_missing_directory_leaves_nothing(tmp_path):
    det = _det()
    eng = ChargeEngine(det, Readout.from_reads([[0]]), rate=1.0, rng=1)
    calls = []
    bad = str(tmp_path / "nope" / "x.fits")
    with pytest.raises(ParameterError, match="does not exist"):
        write_exposure(eng, bad, progress=calls.append)
    with pytest.raises(ParameterError, match="does not exist"):
        write_exposure(eng, str(tmp_path / "ok.fits"),
                       truth_path=str(tmp_path / "nope" / "t.fits"), progress=calls.append)
    assert calls == []                       # raised before any read was simulated
    assert list(tmp_path.iterdir()) == []


def test_existing_file_without_overwrite(tmp_path):
    det = _det()
    eng = ChargeEngine(det, Readout.from_reads([[0]]), rate=1.0, rng=1)
    path = tmp_path / "x.fits"
    path.write_bytes(b"keep")
    with pytest.raises(ParameterError, match="exists"):
        write_exposure(eng, str(path), overwrite=False)
    assert path.read_bytes() == b"keep"


class _FailingCurve:
    """Light curve whose integral raises on its 3rd call (mid-run failure)."""

    flux = np.array([1.0])

    def __init__(self):
        self.calls = 0

    def integral(self, t1, t2):
        self.calls += 1
        if self.calls >= 3:
            raise RuntimeError("light curve failed")
        return np.asarray(t2, float) - np.asarray(t1, float)


def test_failure_mid_run_leaves_no_files(tmp_path):
    det = _det()
    ro = Readout.from_reads([[k] for k in range(5)])
    curve = _FailingCurve()
    src = VariableSource(np.array([1000]), np.array([10.0]), curve)
    eng = ChargeEngine(det, ro, rate=5.0, variable_sources=[src],
                       noise_params=noise.NoiseParams(), rng=1)
    path = tmp_path / "x.fits"
    with pytest.raises(RuntimeError, match="light curve failed"):
        write_exposure(eng, str(path), truth_path=truth_path_for(str(path)),
                       save_charge=True, save_noise=True)
    assert curve.calls == 3
    assert list(tmp_path.iterdir()) == []


def test_failure_mid_run_keeps_old_file(tmp_path):
    det = _det()
    ro = Readout.from_reads([[k] for k in range(5)])
    src = VariableSource(np.array([1000]), np.array([10.0]), _FailingCurve())
    eng = ChargeEngine(det, ro, variable_sources=[src], rng=1)
    path = tmp_path / "x.fits"
    path.write_bytes(b"old")
    with pytest.raises(RuntimeError):
        write_exposure(eng, str(path), overwrite=True)
    assert path.read_bytes() == b"old"
    assert [p.name for p in tmp_path.iterdir()] == ["x.fits"]


def test_read_missing_files(tmp_path):
    with pytest.raises(FileFormatError):
        read_exposure(str(tmp_path / "none.fits"))
    with pytest.raises(FileFormatError):
        read_truth(str(tmp_path / "none.fits"))


# ------------------------------------------------------------------ write-behind
def _advice_calls(monkeypatch):
    """Record every posix_fadvise call; make WriteBehind hand over every resultant."""
    from noise.fitsio import WriteBehind
    calls = []
    monkeypatch.setattr(os, "posix_fadvise", lambda fd, off, n, adv: calls.append((off, n)),
                        raising=False)
    monkeypatch.setattr(os, "POSIX_FADV_DONTNEED", 4, raising=False)
    monkeypatch.setattr(WriteBehind.__init__, "__defaults__", (2, 0))
    return calls


def test_write_behind_writes_the_same_files_and_hands_each_resultant_over(
        tmp_path, monkeypatch):
    """``write_behind`` changes what the page cache keeps, never the bytes: exposure
    and truth files are identical with and without it.  With it, the SCI bytes of
    every resultant are advised once when written and once when dropped (lag 2):
    2 calls per resultant less the last two drops."""
    calls = _advice_calls(monkeypatch)
    det, ro = _det(), _ma_readout(nints=2)

    def run(name, behind):
        eng = ChargeEngine(det, ro, rate=30.0, noise_params=noise.NoiseParams(), rng=5,
                           options=EngineOptions(threads=1))
        path = str(tmp_path / f"{name}.fits")
        write_exposure(eng, path, truth_path=str(tmp_path / f"{name}_truth.fits"),
                       save_charge=True, write_behind=behind)
        return path

    run("plain", False)
    assert calls == []
    run("behind", True)
    n_res = ro.nints * ro.ngroups
    assert len(calls) == 2 * n_res - 2, calls
    # order: pieces 0 and 1 written, then (piece k written, piece k - 2 dropped)
    written = calls[:2] + calls[2::2]
    dropped = calls[3::2]
    size = det.ny * det.nx * 2                     # one resultant of uint16 DN
    assert [n for _, n in written] == [size] * n_res
    assert [b - a for (a, _), (b, _) in zip(written, written[1:])] == [size] * (n_res - 1)
    assert dropped == written[:n_res - 2]
    for a, b in (("plain.fits", "behind.fits"), ("plain_truth.fits", "behind_truth.fits")):
        assert (tmp_path / a).read_bytes() == (tmp_path / b).read_bytes(), a
    with pytest.raises(ParameterError, match="'write_behind'"):
        write_exposure(ChargeEngine(det, ro, rate=1.0, rng=1),
                       str(tmp_path / "x.fits"), write_behind="yes")
    assert not (tmp_path / "x.fits").exists()
