"""Input and output files against a hostile user, generated case by class.

Inputs: every reader of the project (``read_exposure``, ``Exposure.read``,
``read_exposure_header``, ``read_truth``, ``read_fit``, ``read_slopes``) and the
commands that read files (``scenesim fit FILE``; ``scenesim compare FIT TRUTH
[--exposure EXPOSURE]`` with any one of them bad) x
every class of bad file (:data:`BAD_FILES`: missing, a directory, empty, truncated,
cut inside the header, text, random bytes, a damaged header card, a truncated gzip, a
damaged gzip stream, a
dangling link, a FIFO, FITS without the needed extensions, and each other kind of
scenesim file, with its ``FILETYPE`` card and without it as older files have none).
Each case checks:

* library: :class:`noise.errors.FileFormatError`, one line, naming the file;
* command (``python -m scenesim.cli``, a subprocess): exit status 2, exactly one line
  on stderr naming the file, no ``Traceback``;
* both: no file created or changed in the case's directory (hashes before and after).

Outputs: a file-size limit (``RLIMIT_FSIZE`` set in ``preexec_fn``: EFBIG, which
Python gets as an OSError since it ignores SIGXFSZ) and a full disk (a 64 KiB tmpfs
in a private mount namespace, skipped where ``unshare`` is not allowed) for
``scenesim noise`` and ``scenesim run``: exit status 2, one line naming the output
and the reason (for the full disk: the size check's refusal before any work, and with
``--force`` the write's ENOSPC after the one-line warning), no temporary file left and
no partial output.
"""

import gzip
import hashlib
import os
import resource
import shlex
import shutil
import subprocess
import sys
from concurrent.futures import ThreadPoolExecutor

import numpy as np
import pytest
from astropy.io import fits

import noise
from noise import ZERO_NOISE, NoiseGenerator, preset, write_noise_fits
from noise.errors import FileFormatError
from noise.fitsio import TEMP_PATTERN
from scenesim.detector.readout import Readout
from scenesim.engine import ChargeEngine, EngineOptions
from scenesim.io.exposure import Exposure, read_exposure, read_exposure_header, read_truth
from scenesim.io.fitfile import FitResult, read_fit, read_slopes, write_fit
from scenesim.run import write_exposure

REPO = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
QUICK = os.path.join(REPO, "scenes", "quick.toml")
SHAPE = (16, 16)
KINDS = ("exposure", "truth", "slopes", "noise")


# ------------------------------------------------------------------ valid files
def _fit_result():
    f32 = np.float32
    z = np.zeros(SHAPE, f32)
    return FitResult(slope=z + 1, var_read=z + 1, var_poisson=z, chi2=z + 1,
                     dof=np.full(SHAPE, 2, np.int32), dq=np.zeros(SHAPE, np.uint32),
                     slope_ints=np.stack([z + 1]), var_ints=np.stack([z + 1]),
                     n_jumps=np.zeros(SHAPE, np.int32), gain=1.0, read_noise=5.0,
                     fitter="ols")


@pytest.fixture(scope="module")
def good(tmp_path_factory):
    """One valid file of each kind: ``{kind: path}``."""
    d = tmp_path_factory.mktemp("good")
    det = preset("H2RG", naxis1=SHAPE[1], naxis2=SHAPE[0])
    eng = ChargeEngine(det, Readout.multiaccum(1, 3), rate=10.0,
                       noise_params=noise.NoiseParams(), rng=2,
                       options=EngineOptions(threads=1))
    paths = {k: str(d / f"{k}.fits") for k in KINDS}
    write_exposure(eng, paths["exposure"], truth_path=paths["truth"])
    write_fit(paths["slopes"], _fit_result())
    write_noise_fits(paths["noise"], NoiseGenerator(det, ZERO_NOISE, rng=1, threads=1), 2)
    return paths


# ------------------------------------------------------------------ bad files
def _copy_cut(src, dst, nbytes):
    with open(src, "rb") as f:
        data = f.read()
    with open(dst, "wb") as f:
        f.write(data[:nbytes if nbytes >= 0 else len(data) // 2])
    return dst


def _damaged_card(src, dst):
    """The file with its first ``NAXIS1`` card's value replaced by a string."""
    with open(src, "rb") as f:
        data = bytearray(f.read())
    at = next(i for i in range(0, len(data), 80) if data[i:i + 9] == b"NAXIS1  =")
    data[at:at + 80] = b"NAXIS1  = 'sixteen'".ljust(80)
    with open(dst, "wb") as f:
        f.write(data)
    return dst


def _without_filetype(src, dst):
    """The file as written before the FILETYPE card existed."""
    with fits.open(src) as hdul:
        del hdul[0].header["FILETYPE"]
        hdul.writeto(dst, output_verify="exception")
    return dst


def _gz_truncated(src, dst):
    with open(src, "rb") as f:
        packed = gzip.compress(f.read())
    with open(dst, "wb") as f:
        f.write(packed[:len(packed) // 2])
    return dst


def _gz_damaged(src, dst):
    """Gzip of the good file with two bytes flipped in the middle of the compressed
    data: astropy reads it without an error and gives wrong pixel values (it never
    reads the gzip trailer, whose CRC would tell)."""
    with open(src, "rb") as f:
        packed = bytearray(gzip.compress(f.read()))
    packed[len(packed) // 2] ^= 0xFF
    packed[len(packed) // 2 + 1] ^= 0xFF
    with open(dst, "wb") as f:
        f.write(bytes(packed))
    return dst


def _make(case, d, kind, good):
    """Create the bad file of class ``case`` in ``d`` for a reader expecting ``kind``;
    return its path (it may not exist)."""
    mine = good[kind]
    if case == "missing":
        return str(d / "missing.fits")
    if case == "directory":
        (d / "adir.fits").mkdir()
        return str(d / "adir.fits")
    if case == "empty":
        (d / "empty.fits").write_bytes(b"")
        return str(d / "empty.fits")
    if case == "truncated":                          # a valid file cut in half
        return _copy_cut(mine, str(d / "half.fits"), -1)
    if case == "truncated-odd":                      # cut off a block boundary
        return _copy_cut(mine, str(d / "cut_odd.fits"),
                         2 * os.path.getsize(mine) // 3 + 77)
    if case == "last-hdu-lost":                      # cut at the last HDU's start
        with fits.open(mine) as hdul:
            start = hdul.fileinfo(len(hdul) - 1)["hdrLoc"]
        return _copy_cut(mine, str(d / "lost.fits"), start)
    if case == "header-cut":                         # cut inside the first header
        return _copy_cut(mine, str(d / "cut.fits"), 1000)
    if case == "text":
        (d / "notes.fits").write_text("these are my notes, not FITS\n")
        return str(d / "notes.fits")
    if case == "random-bytes":
        (d / "junk.fits").write_bytes(np.random.default_rng(3).bytes(6000))
        return str(d / "junk.fits")
    if case == "damaged-card":
        return _damaged_card(mine, str(d / "damaged.fits"))
    if case == "gzip-truncated":
        return _gz_truncated(mine, str(d / "half.fits.gz"))
    if case == "gzip-damaged":
        return _gz_damaged(mine, str(d / "flipped.fits.gz"))
    if case == "dangling-link":
        os.symlink(str(d / "gone.fits"), str(d / "link.fits"))
        return str(d / "link.fits")
    if case == "fifo":                               # opening it would block
        os.mkfifo(str(d / "pipe.fits"))
        return str(d / "pipe.fits")
    if case == "image-only":                         # FITS without the extensions
        fits.PrimaryHDU(np.zeros((4, 4), np.float32)).writeto(str(d / "image.fits"))
        return str(d / "image.fits")
    if case == "header-only":
        fits.PrimaryHDU().writeto(str(d / "bare.fits"))
        return str(d / "bare.fits")
    if case.startswith("kind:"):                     # another scenesim file
        other = case[5:]
        return shutil.copyfile(good[other], str(d / f"{other}_given.fits"))
    if case.startswith("old-kind:"):                 # ... from before FILETYPE
        other = case[9:]
        return _without_filetype(good[other], str(d / f"old_{other}.fits"))
    raise AssertionError(case)


#: Every class of bad input file.
BAD_FILES = (["missing", "directory", "empty", "truncated", "truncated-odd",
              "last-hdu-lost", "header-cut", "text",
              "random-bytes", "damaged-card", "gzip-truncated", "gzip-damaged", "dangling-link",
              "fifo",
              "image-only", "header-only"]
             + [f"kind:{k}" for k in KINDS] + [f"old-kind:{k}" for k in KINDS])


def _snapshot(directory):
    """``{relative path: sha256 | kind}`` of everything under ``directory``."""
    out = {}
    for root, dirs, files in os.walk(directory):
        for name in dirs + files:
            path = os.path.join(root, name)
            rel = os.path.relpath(path, directory)
            if os.path.islink(path):
                out[rel] = "link:" + os.readlink(path)
            elif os.path.isdir(path):
                out[rel] = "<dir>"
            elif os.path.isfile(path):
                with open(path, "rb") as f:
                    out[rel] = hashlib.sha256(f.read()).hexdigest()
            else:
                out[rel] = "<special>"
    return out


def _applies(case, kind):
    """A wrong-kind case needs another kind than the one the reader expects."""
    return not (case.endswith(f"kind:{kind}"))


# ------------------------------------------------------------------ library
READERS = {
    "read_exposure": (read_exposure, "exposure"),
    "Exposure.read": (Exposure.read, "exposure"),
    "read_exposure_header": (read_exposure_header, "exposure"),
    "read_truth": (read_truth, "truth"),
    "read_fit": (read_fit, "slopes"),
    "read_slopes": (lambda p: read_slopes(p, gain=1.0), "slopes"),
}

LIBRARY_CASES = [(r, c) for r in READERS for c in BAD_FILES
                 if _applies(c, READERS[r][1])]


@pytest.mark.parametrize("reader, case", LIBRARY_CASES)
def test_reader_bad_file_one_line_error(tmp_path, good, reader, case):
    # old: astropy/numpy tracebacks (OSError, TypeError, KeyError...) for most classes,
    # and a wrong-kind file read as if it were the right one or failing deep inside
    fn, kind = READERS[reader]
    path = _make(case, tmp_path, kind, good)
    before = _snapshot(tmp_path)
    with pytest.raises(FileFormatError) as info:
        fn(path)
    msg = str(info.value)
    assert "\n" not in msg and os.path.basename(path) in msg, msg
    assert _snapshot(tmp_path) == before


@pytest.mark.parametrize("reader", READERS)
def test_reader_accepts_the_good_file_with_and_without_filetype(tmp_path, good, reader):
    fn, kind = READERS[reader]
    fn(good[kind])
    fn(_without_filetype(good[kind], str(tmp_path / "old.fits")))


# ------------------------------------------------------------------ command
#: The command's input classes (the brief's list; the library runs every class).
CLI_FILES = ["missing", "directory", "empty", "truncated", "text", "image-only"] + [
    f"kind:{k}" for k in KINDS]

#: ``(name, argv with {bad}, what the bad file should be)``; ``truth.fits`` and
#: ``slopes.fits`` are valid files copied into the case's directory.
COMMANDS = [("fit", ["fit", "{bad}"], "exposure"),
            ("compare-fit", ["compare", "{bad}", "truth.fits"], "slopes"),
            ("compare-truth", ["compare", "slopes.fits", "{bad}"], "truth"),
            ("compare-exposure", ["compare", "slopes.fits", "truth.fits", "--exposure",
                                  "{bad}"], "exposure")]

CLI_CASES = [(name, case) for name, _, kind in COMMANDS for case in CLI_FILES
             if _applies(case, kind)]

#: Cases of the fast suite (about 1 s of interpreter start-up each); the others are
#: marked ``slow`` (run in CI).
_FIRST_WRONG_KIND = {name: next(f"kind:{k}" for k in KINDS if k != kind)
                    for name, _, kind in COMMANDS}
CLI_FAST = [(name, case) for name, case in CLI_CASES
            if case in ("missing", "truncated", "text", _FIRST_WRONG_KIND[name])]
CLI_SLOW = [c for c in CLI_CASES if c not in CLI_FAST]


def _cli(argv, cwd, **kwargs):
    env = dict(os.environ, PYTHONDONTWRITEBYTECODE="1")
    return subprocess.run([sys.executable, "-m", "scenesim.cli", *argv], cwd=cwd,
                          capture_output=True, text=True, stdin=subprocess.DEVNULL,
                          env=env, timeout=300, **kwargs)


def _run_cli_cases(cases, tmp_path_factory, good):
    """Run command ``cases`` as subprocesses, two at a time: ``{case: (path, rc,
    stderr, snapshot before, snapshot after)}``."""
    def run(key):
        name, case = key
        argv, kind = next((a, k) for n, a, k in COMMANDS if n == name)
        d = tmp_path_factory.mktemp(f"{name}-{case.replace(':', '-')}")
        shutil.copyfile(good["truth"], d / "truth.fits")
        shutil.copyfile(good["slopes"], d / "slopes.fits")
        path = _make(case, d, kind, good)
        before = _snapshot(d)
        res = _cli([a.format(bad=os.path.basename(path)) for a in argv], d)
        return key, (path, res.returncode, res.stderr, before, _snapshot(d))

    with ThreadPoolExecutor(2) as pool:
        return dict(pool.map(run, cases))


@pytest.fixture(scope="module")
def cli_fast(tmp_path_factory, good):
    return _run_cli_cases(CLI_FAST, tmp_path_factory, good)


@pytest.fixture(scope="module")
def cli_slow(tmp_path_factory, good):
    return _run_cli_cases(CLI_SLOW, tmp_path_factory, good)


def _one_line(stderr, *must_name):
    lines = [ln for ln in stderr.splitlines() if ln.strip()]
    assert "Traceback" not in stderr, stderr
    assert len(lines) == 1, stderr
    for word in must_name:
        assert word in lines[0], (word, lines[0])
    return lines[0]


def _check_cli_case(outcome):
    path, rc, stderr, before, after = outcome
    assert rc == 2, stderr
    _one_line(stderr, os.path.basename(path))
    assert after == before                   # nothing created, nothing changed


@pytest.mark.parametrize("command, case", CLI_FAST)
def test_command_bad_file_one_line_exit_2(cli_fast, command, case):
    # old: tracebacks from astropy (empty, truncated, text files), a wrong kind of
    # file failing deep inside the fitter or compare
    _check_cli_case(cli_fast[(command, case)])


@pytest.mark.slow
@pytest.mark.parametrize("command, case", CLI_SLOW)
def test_command_bad_file_one_line_exit_2_more(cli_slow, command, case):
    _check_cli_case(cli_slow[(command, case)])


# ------------------------------------------------------------------ outputs
def _limit_fsize(nbytes):
    def preexec():
        resource.setrlimit(resource.RLIMIT_FSIZE, (nbytes, resource.RLIM_INFINITY))
    return preexec


def _temps(directory):
    return [n for n in os.listdir(directory) if TEMP_PATTERN.fullmatch(n)
            or n.startswith(".tmp-")]


NOISE = ["noise", "--preset", "H1RG", "--naxis", "128", "--frames", "4", "-q", "-o"]


@pytest.mark.parametrize("argv, output", [
    (NOISE + ["out.fits"], "out.fits"),
    (NOISE + ["out.fits.gz"], "out.fits.gz"),
    (["run", QUICK, "-q", "-o", "quick.fits"], "quick.fits"),
])
def test_file_size_limit_one_line_nothing_left(tmp_path, argv, output):
    # old: temp removed, but an OSError traceback ("File too large") was printed
    res = _cli(argv, tmp_path, preexec_fn=_limit_fsize(64 << 10))
    assert res.returncode == 2, res.stderr
    _one_line(res.stderr, output, "File too large", "EFBIG")
    assert os.listdir(tmp_path) == []


@pytest.mark.slow
def test_file_size_limit_on_the_fit_of_a_run(tmp_path):
    """The exposure (1.3 MB) and truth (0.8 MB) fit under 2 MB, the slope file (2.7
    MB) does not: written by astropy (numpy's short write, no errno)."""
    res = _cli(["run", QUICK, "-q", "-o", "quick.fits", "--fit", "ols"], tmp_path,
               preexec_fn=_limit_fsize(2 << 20))
    assert res.returncode == 2, res.stderr
    _one_line(res.stderr, "_ols.fits", "File too large")
    # the files finished before the fit stay, and the line names them (before: the
    # line did not say so)
    kept = sorted(n for n in os.listdir(tmp_path) if not n.startswith("."))
    assert kept == ["quick.fits", "quick_truth.fits"], kept
    assert all(f"'{name}'" in res.stderr for name in kept), res.stderr
    assert _temps(tmp_path) == []
    assert not [n for n in os.listdir(tmp_path) if "_ols" in n]
    for name in os.listdir(tmp_path):                 # whatever is there is complete
        with fits.open(tmp_path / name) as hdul:
            hdul.verify("exception")
            [np.asarray(h.data) for h in hdul]


@pytest.mark.parametrize("value", [np.nan, np.inf, -np.inf])
@pytest.mark.parametrize("gz", [False, True])
def test_a_non_finite_float_sci_value_is_named_with_its_place(good, tmp_path, value,
                                                               gz):
    # A float SCI (accepted: float32 and float64 give the uint16 file's slopes) with
    # one non-finite value: NaN and -inf stopped in the fitter with its internal
    # argument names ('resultants' ... 'saturated'), +inf was silently taken as
    # saturation.  Now one line naming the file, the value and its place, by the
    # streamed reader and by the whole-file one (.gz).
    with fits.open(good["exposure"]) as hdul:
        hdul["SCI"].data = hdul["SCI"].data.astype(np.float32)
        hdul["SCI"].data[0, 2, 5, 7] = value
        name = "f.fits.gz" if gz else "f.fits"
        hdul.writeto(tmp_path / name)
    res = _cli(["fit", name, "-o", "o.fits", "-q"], tmp_path)
    assert res.returncode == 2, res.stderr
    _one_line(res.stderr, f"'{name}'", f"SCI holds {value}",
              "integration 0, group 2, pixel (y=5, x=7)")
    assert sorted(os.listdir(tmp_path)) == [name]


def test_file_size_limit_on_the_fits_temporary_cube_says_so(good, tmp_path):
    """``scenesim fit`` prepares the ramps into a temporary float32 cube first (here
    3 x SHAPE x 4 bytes, above the limit; the exposure read is not limited).  The line
    named the slope file alone, which is smaller than the limit it was said to pass."""
    shutil.copyfile(good["exposure"], tmp_path / "e.fits")
    cube = 4 * 3 * SHAPE[0] * SHAPE[1]
    res = _cli(["fit", "e.fits", "-o", "f.fits", "-q"], tmp_path,
               preexec_fn=_limit_fsize(cube // 2))
    assert res.returncode == 2, res.stderr
    _one_line(res.stderr, "'f.fits'", f"temporary float32 cube of {cube} bytes",
              "File too large", f"is {cube // 2} bytes")
    assert os.listdir(tmp_path) == ["e.fits"]


def _unshare_works():
    if shutil.which("unshare") is None or not sys.platform.startswith("linux"):
        return False
    probe = subprocess.run(["unshare", "-Urm", "sh", "-c",
                            "mount -t tmpfs -o size=64k tmpfs /mnt"],
                           capture_output=True, stdin=subprocess.DEVNULL)
    return probe.returncode == 0


@pytest.mark.skipif(not _unshare_works(),
                    reason="needs unshare -Urm (user and mount namespaces) for a tmpfs")
@pytest.mark.parametrize("argv", [NOISE + ["{mnt}/out.fits"],
                                  ["run", QUICK, "-q", "-o", "{mnt}/quick.fits"]])
@pytest.mark.parametrize("force", [False, True])
def test_disk_full_one_line_nothing_left(tmp_path, argv, force):
    """A 64 KiB tmpfs (private to the command) is too small: the size check refuses
    the run before any work (scenesim.budget); forced, the tmpfs fills up: ENOSPC."""
    # old: temp removed, but an OSError traceback was printed
    mnt = tmp_path / "mnt"
    mnt.mkdir()
    cmd = shlex.join([sys.executable, "-m", "scenesim.cli"]
                     + [a.format(mnt=mnt) for a in argv] + (["--force"] if force else []))
    where = shlex.quote(str(mnt))
    script = (f"mount -t tmpfs -o size=64k tmpfs {where} || exit 99; {cmd}; rc=$?; "
              f"ls -A {where}; exit $rc")
    res = subprocess.run(["unshare", "-Urm", "sh", "-c", script], capture_output=True,
                         text=True, stdin=subprocess.DEVNULL, timeout=300,
                         env=dict(os.environ, PYTHONDONTWRITEBYTECODE="1"))
    assert res.returncode == 2, res.stderr
    if force:
        # the forced run's one warning line, then the error
        warning, *rest = [ln for ln in res.stderr.splitlines() if ln.strip()]
        assert warning.startswith(f"scenesim {argv[0]}: warning: forced: ")
        _one_line("\n".join(rest), str(mnt), "No space left on device", "ENOSPC")
    else:
        _one_line(res.stderr, f"free in {str(mnt)!r}", "--force")
    assert res.stdout.split() == []           # the tmpfs is empty: no temp, no output
