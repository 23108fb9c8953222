"""Output files that leave nothing behind and say what went wrong (issue 12).

Every writer of the project (the exposure and truth of :class:`ExposureWriter`,
:func:`write_fit`, :func:`noise.write_noise_fits`) is checked for:

* temporary files named ``.scenesim-<pid>-<random>.<target>.tmp``, and
  :func:`noise.fitsio.remove_stale_temps` removing those of dead processes only;
* the umask's mode on every finished file, as ``open()`` gives;
* ``.fits.gz`` written gzip-compressed, derived names keeping the full extension, and
  other compression endings refused before anything is written;
* a full disk: :class:`noise.errors.OutputError` (one line naming the file and the
  reason) and no temporary file left;
* headers that astropy verifies and writes back (``output_verify='exception'``), in
  memory and on disk, with a ``FILETYPE`` card; old files' detector cards still read.
"""

import errno
import gzip
import io
import os
import re
import signal
import stat
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from astropy.io import fits

import noise
from noise import ZERO_NOISE, NoiseGenerator, preset, write_noise_fits
from noise.clock import detector_from_header
from noise.errors import OutputError, ParameterError, ScenesimError
from noise.fitsio import TEMP_PATTERN, derived_path, remove_stale_temps, temp_file
from scenesim.detector.readout import Readout
from scenesim.engine import ChargeEngine, EngineOptions
from scenesim.io.exposure import read_exposure, truth_path_for
from scenesim.io.fitfile import FitResult, read_fit, write_fit
from scenesim.run import write_exposure

SHAPE = (16, 16)


def _det():
    return preset("H2RG", naxis1=SHAPE[1], naxis2=SHAPE[0])


def _engine():
    """A small exposure with every noise component, a rate and 2 x 3 resultants."""
    return ChargeEngine(_det(), Readout.multiaccum(1, 3, nints=2), rate=20.0,
                        noise_params=noise.NoiseParams(), rng=3,
                        options=EngineOptions(threads=1))


def _fit_result():
    rng = np.random.default_rng(5)
    f32 = np.float32
    return FitResult(slope=rng.normal(10, 1, SHAPE).astype(f32),
                     var_read=np.full(SHAPE, 0.5, f32), var_poisson=np.full(SHAPE, 0.2, f32),
                     chi2=np.ones(SHAPE, f32), dof=np.full(SHAPE, 4, np.int32),
                     dq=np.zeros(SHAPE, np.uint32),
                     slope_ints=rng.normal(10, 1, (2,) + SHAPE).astype(f32),
                     var_ints=np.ones((2,) + SHAPE, f32),
                     n_jumps=np.zeros(SHAPE, np.int32), gain=1.5, read_noise=5.0,
                     fitter="ols")


def _noise_gen():
    # the bias 6 rms spreads (5 e-) above code 0: the DN file clips nothing
    return NoiseGenerator(_det(), ZERO_NOISE.replace(rd_noise=5.0, bias_offset=30.0),
                          rng=1, threads=1)


def _write(kind, path, **kwargs):
    """Write one output of ``kind`` to ``path``: every writer of the project."""
    path = str(path)
    if kind == "exposure":
        write_exposure(_engine(), path, **kwargs)
    elif kind == "truth":                          # the truth file beside an exposure
        write_exposure(_engine(), None, truth_path=path, **kwargs)
    elif kind == "truth+cubes":                    # CHARGE and NOISE via raw temp files
        write_exposure(_engine(), None, truth_path=path, save_charge=True,
                       save_noise=True, **kwargs)
    elif kind == "fit":
        write_fit(path, _fit_result(), **kwargs)
    elif kind == "noise":
        write_noise_fits(path, _noise_gen(), 3, **kwargs)
    elif kind == "noise-DN":
        write_noise_fits(path, _noise_gen(), 3, unit="DN", gain=2.0, **kwargs)
    else:
        raise AssertionError(kind)
    return path


KINDS = ("exposure", "truth", "truth+cubes", "fit", "noise", "noise-DN")


# ------------------------------------------------------------------ temporary files
def test_temp_file_name_carries_pid_and_target(tmp_path):
    # old: tempfile.mkstemp(prefix=".tmp-", suffix=".fits"): no owner, no target
    tmp = temp_file(tmp_path / "out.fits.gz", tag="charge")
    name = os.path.basename(tmp)
    m = TEMP_PATTERN.fullmatch(name)
    assert m is not None and int(m.group(1)) == os.getpid()
    assert m.group(2) == "out.fits.gz.charge" and name.startswith(".scenesim-")
    assert stat.S_IMODE(os.stat(tmp).st_mode) == 0o600      # private while written
    # a very long target name still gives a name the file system accepts
    long_tmp = temp_file(tmp_path / ("x" * 250 + ".fits"))
    assert len(os.path.basename(long_tmp)) <= 255
    assert TEMP_PATTERN.fullmatch(os.path.basename(long_tmp))


def test_writers_use_the_named_temp_file(tmp_path):
    seen = []
    write_noise_fits(tmp_path / "n.fits", _noise_gen(), 3,
                     progress=lambda n: seen.append(os.listdir(tmp_path)))
    names = {n for listing in seen for n in listing}
    assert names and all(TEMP_PATTERN.fullmatch(n) for n in names), names
    assert {int(TEMP_PATTERN.fullmatch(n).group(1)) for n in names} == {os.getpid()}
    assert os.listdir(tmp_path) == ["n.fits"]


def _dead_pid():
    """The id of a process that has exited (and been reaped)."""
    proc = subprocess.Popen([sys.executable, "-c", "pass"])
    proc.wait()
    return proc.pid


def test_remove_stale_temps_only_dead_owners(tmp_path):
    dead = _dead_pid()
    stale = tmp_path / f".scenesim-{dead}-abc12345.out.fits.tmp"
    mine = tmp_path / f".scenesim-{os.getpid()}-abc12345.out.fits.tmp"
    init = tmp_path / ".scenesim-1-abc12345.out.fits.tmp"       # pid 1 is alive
    other = tmp_path / f".tmp-{dead}.fits"                       # not our pattern
    keep_dir = tmp_path / f".scenesim-{dead}-dir00000.x.fits.tmp"
    link = tmp_path / f".scenesim-{dead}-lnk00000.x.fits.tmp"
    target = tmp_path / "target.fits"
    for p in (stale, mine, init, other, target):
        p.write_bytes(b"x")
    keep_dir.mkdir()
    link.symlink_to(target)
    removed = remove_stale_temps(tmp_path)
    assert removed == [str(stale)]
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted(
        p.name for p in (mine, init, other, keep_dir, link, target))
    assert remove_stale_temps(tmp_path) == []
    assert remove_stale_temps(tmp_path / "no_such_dir") == []


_KILLED_WRITER = """
import sys
import noise
gen = noise.NoiseGenerator(noise.preset("H2RG", naxis1=256, naxis2=256),
                           noise.NoiseParams(), rng=1, threads=1)
noise.write_noise_fits(sys.argv[1], gen, 400, progress=lambda n: print(n, flush=True))
"""


def test_sigkill_leaves_a_named_temp_that_the_next_run_removes(tmp_path):
    """SIGKILL cannot be caught: the temp file stays, named with the dead owner's pid,
    and remove_stale_temps (called by the next run) removes exactly it."""
    # old: a '.tmp-XXXX.fits' that nothing ever recognised or removed
    out = tmp_path / "big.fits"
    proc = subprocess.Popen([sys.executable, "-c", _KILLED_WRITER, str(out)],
                            stdout=subprocess.PIPE, stderr=subprocess.DEVNULL)
    try:
        assert proc.stdout.readline().strip() == b"1"       # writing has started
    finally:
        proc.send_signal(signal.SIGKILL)
        proc.wait()
        proc.stdout.close()
    left = os.listdir(tmp_path)
    assert len(left) == 1 and not out.exists()
    m = TEMP_PATTERN.fullmatch(left[0])
    assert m and int(m.group(1)) == proc.pid and m.group(2) == "big.fits"
    assert remove_stale_temps(tmp_path) == [str(tmp_path / left[0])]
    assert os.listdir(tmp_path) == []


# ------------------------------------------------------------------ modes
@pytest.mark.parametrize("umask", [0o022, 0o027, 0o002, 0o077])
def test_outputs_get_the_umask_mode(tmp_path, umask):
    # old: every output was 0600 (mkstemp's mode), whatever the umask
    old = os.umask(umask)
    try:
        for kind in ("exposure", "truth+cubes", "fit", "noise"):
            path = _write(kind, tmp_path / f"{kind}.fits")
            assert stat.S_IMODE(os.stat(path).st_mode) == 0o666 & ~umask, kind
    finally:
        os.umask(old)


# ------------------------------------------------------------------ names, gzip
@pytest.mark.parametrize("path, suffix, expected", [
    ("out.fits", "_truth", "out_truth.fits"),
    ("out.fits.gz", "_truth", "out_truth.fits.gz"),
    ("out.fits.gz", "_ols", "out_ols.fits.gz"),
    ("dir.v2/out.FITS.GZ", "_gls", os.path.join("dir.v2", "out_gls.FITS.GZ")),
    ("out.fit", "_cds", "out_cds.fit"),
    ("out", "_truth", "out_truth.fits"),
    ("dir.v2/out", "_truth", os.path.join("dir.v2", "out_truth.fits")),
    ("a.b.gz", "_x", "a.b_x.gz"),
])
def test_derived_path_keeps_the_full_extension(path, suffix, expected):
    # old: truth_path_for('out.fits.gz') == 'out.fits_truth.gz' (and 'out.fits_ols.gz')
    assert derived_path(path, suffix) == expected
    if suffix == "_truth":
        assert truth_path_for(path) == expected


@pytest.mark.parametrize("kind", KINDS)
def test_gz_outputs_are_gzip_and_read_back_identical(tmp_path, kind):
    # old: a '.fits.gz' output was plain FITS under a '.gz' name
    plain = _write(kind, tmp_path / "a.fits")
    packed = _write(kind, tmp_path / "b.fits.gz")
    with open(packed, "rb") as f:
        assert f.read(2) == b"\x1f\x8b"
    with gzip.open(packed) as f:
        assert f.read() == Path(plain).read_bytes()       # the same FITS bytes
    with fits.open(packed) as hdul:
        hdul.verify("exception")
    assert sorted(os.listdir(tmp_path)) == ["a.fits", "b.fits.gz"]


def test_gz_exposure_and_fit_read_back(tmp_path):
    path = _write("exposure", tmp_path / "e.fits.gz")
    sci, hdr, reads = read_exposure(path)
    assert sci.shape == (2, 3) + SHAPE and hdr["FILETYPE"] == "exposure"
    write_fit(tmp_path / "f.fits.gz", _fit_result())
    np.testing.assert_array_equal(read_fit(tmp_path / "f.fits.gz").slope,
                                  _fit_result().slope)


@pytest.mark.parametrize("ending", [".fits.bz2", ".fits.xz", ".fits.zip", ".fits.Z",
                                    ".fits.fz"])
@pytest.mark.parametrize("kind", ["exposure", "truth", "fit", "noise"])
def test_other_compressions_refused_before_writing(tmp_path, kind, ending):
    # old: written uncompressed under the compressed name
    with pytest.raises(ParameterError, match=re.escape(ending[5:]) + ".*compression"):
        _write(kind, tmp_path / f"x{ending}")
    assert os.listdir(tmp_path) == []


# ------------------------------------------------------------------ disk full
class _FullDisk(io.RawIOBase):
    """A file that takes ``room`` bytes, then fails with ENOSPC (as a full disk)."""

    def __init__(self, path, room):
        self._f = open(path, "wb", buffering=0)
        self.name = path
        self.room = room

    def writable(self):
        return True

    def write(self, b):
        n = memoryview(b).nbytes
        if n > self.room:
            raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))
        self.room -= n
        return self._f.write(b)

    def close(self):
        self._f.close()
        super().close()


@pytest.fixture
def full_disk(monkeypatch):
    """Files opened for writing by the writers (outputs and raw cubes) whose name
    contains ``victim`` get ``room`` bytes of disk."""
    import noise.fitsio
    import scenesim.io.exposure
    state = {"victim": None, "room": 0}

    def fake_open(path, mode="r", buffering=-1, **kwargs):
        if "w" in mode and state["victim"] in os.path.basename(path):
            return io.BufferedWriter(_FullDisk(path, state["room"]), 1 << 12)
        return open(path, mode, buffering, **kwargs)

    monkeypatch.setattr(noise.fitsio, "open", fake_open, raising=False)
    monkeypatch.setattr(scenesim.io.exposure, "open", fake_open, raising=False)
    return state


@pytest.mark.parametrize("kind, victim, room", [
    ("exposure", "e.fits", 10000),           # in the SCI cube
    ("exposure", "e.fits", 100),             # in the primary header
    ("exposure+truth", "e_truth.fits", 8000),  # the truth, after the exposure
    ("truth+cubes", "CHARGE", 3000),         # a raw cube of the truth
    ("fit", "f.fits", 5000),
    ("noise", "n.fits", 5000),
])
def test_disk_full_raises_output_error_and_leaves_nothing(tmp_path, full_disk, kind,
                                                          victim, room):
    # old: the temp file was removed but a bare OSError traceback came out
    full_disk.update(victim=victim, room=room)
    target = {"exposure": "e.fits", "exposure+truth": "e_truth.fits",
              "truth+cubes": "e_truth.fits", "fit": "f.fits", "noise": "n.fits"}[kind]
    with pytest.raises(OutputError) as info:
        if kind == "exposure+truth":
            write_exposure(_engine(), str(tmp_path / "e.fits"),
                           truth_path=str(tmp_path / "e_truth.fits"))
        elif kind == "truth+cubes":
            _write(kind, tmp_path / "e_truth.fits")
        else:
            _write(kind, tmp_path / target)
    msg = str(info.value)
    assert "\n" not in msg and repr(str(tmp_path / target)) in msg
    assert "No space left on device (ENOSPC)" in msg
    assert isinstance(info.value, ScenesimError) and isinstance(info.value, OSError)
    assert info.value.errno == errno.ENOSPC
    assert os.listdir(tmp_path) == []         # exposure, truth and temp files gone


# ------------------------------------------------------------------ verification
def _verify_and_rewrite(hdul, tmp_path):
    hdul.verify("exception")
    out = tmp_path / "rewritten.fits"
    hdul.writeto(out, output_verify="exception", overwrite=True)
    with fits.open(out) as back:
        assert len(back) == len(hdul)


@pytest.mark.parametrize("kind", KINDS)
def test_every_file_verifies_and_round_trips(tmp_path, kind):
    # old: "NAXISj keyword out of range ('NAXIS1D' when NAXIS == 0)" on every file
    path = _write(kind, tmp_path / f"{kind}.fits")
    with fits.open(path) as hdul:
        _verify_and_rewrite(hdul, tmp_path)
        hdr = hdul[0].header
        assert "NAXIS1D" not in hdr and "NAXIS2D" not in hdr
        expected = {"exposure": "exposure", "fit": "slopes", "noise": "noise",
                    "noise-DN": "noise"}.get(kind, "truth")
        assert hdr["FILETYPE"] == expected
        if kind != "fit":                      # a fit copies no detector cards
            assert (hdr["DETNAX1"], hdr["DETNAX2"]) == (SHAPE[1], SHAPE[0])
            assert detector_from_header(hdr) == _det()


def test_in_memory_outputs_verify(tmp_path):
    exp = write_exposure(_engine(), None)["exposure"]
    assert exp.header["FILETYPE"] == "exposure"
    _verify_and_rewrite(fits.HDUList([fits.PrimaryHDU(header=exp.header),
                                      fits.ImageHDU(exp.sci, name="SCI"),
                                      fits.BinTableHDU(exp.reads, name="READS")]),
                        tmp_path)
    _verify_and_rewrite(_fit_result().to_hdul(), tmp_path)


def test_old_detector_card_names_still_read():
    """Files written before the rename carry NAXIS1D/NAXIS2D."""
    det = preset("H2RG").window(8, 16, 32, 24, name="W")
    hdr = fits.Header()
    for key, value, _ in det.to_header_cards():
        hdr[{"DETNAX1": "NAXIS1D", "DETNAX2": "NAXIS2D"}.get(key, key)] = value
    assert "DETNAX1" not in hdr
    assert detector_from_header(hdr) == det
