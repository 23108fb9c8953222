"""Streaming FITS output, written atomically; FITS input, read safely.

Cubes are written frame by frame, so memory does not grow with the number of frames:
the header is written first, then each frame's bytes (big-endian, as FITS requires),
then the padding to a multiple of 2880 bytes.

Outputs
-------
Everything goes to a temporary file in the destination directory, renamed over the
destination only when complete (:func:`atomic_path`, :func:`atomic_file`), so an
interrupted or failed run never leaves a partial or corrupt file:

* temporary files are named ``.scenesim-<pid>-<random>.<target basename>.tmp``
  (:data:`TEMP_PATTERN`), carrying the writing process's id.  A process killed by
  SIGKILL cannot remove its own; :func:`remove_stale_temps` removes those whose owner
  is no longer alive (never a live process's) at the start of the next run;
* a finished file gets the mode ``open()`` would give it, ``0o666 & ~umask`` (the
  temporary file is created ``0o600``);
* a name ending in ``.gz`` is written gzip-compressed (astropy reads it back
  transparently); other compression endings (``.bz2``, ``.xz``, ``.zip``, ``.fz``,
  ...) are refused (:func:`check_output_name`) rather than written uncompressed under
  a compressed name.  :func:`derived_path` names a file derived from another
  (``out.fits.gz`` -> ``out_truth.fits.gz``), keeping the full extension;
* an operating-system error while writing (disk full, ``ulimit -f``, I/O error)
  removes the temporary file and raises :class:`noise.errors.OutputError`, one line
  naming the output and the reason (:func:`output_error`);
* a long noise-only ramp (:func:`write_noise_fits`) is streamed to disk as it is
  written and not kept in the page cache (:class:`WriteBehind`).

Inputs
------
:func:`open_fits` opens a FITS file for reading and turns every failure, while opening
or while reading inside its block (missing file, a directory, an empty, truncated,
corrupt or non-FITS file, astropy's warnings about one), into one
:class:`noise.errors.FileFormatError` naming the file.
"""

import contextlib
import errno as _errno
import gzip
import io
import math
import os
import re
import shutil
import sys
import tempfile
import threading
import warnings
import zlib
from concurrent.futures import ThreadPoolExecutor
from importlib import metadata

import numpy as np
from astropy.io import fits
from astropy.utils.exceptions import AstropyWarning

from noise.validate import (check_bool, check_choice, check_float, check_instance,
                            check_int, check_path, check_str, check_writable, describe,
                            is_sequence)
from noise.errors import (FileFormatError, OutputError, ParameterError,
                          ParameterTypeError, ScenesimError)

__all__ = ["atomic_path", "atomic_file", "StreamingFITS", "WriteBehind",
           "WriterThread", "package_version", "write_noise_fits", "TEMP_PATTERN",
           "temp_file", "remove_stale_temps", "check_output_name", "derived_path",
           "output_error", "input_path", "open_fits", "same_file", "is_gzip_file"]

_BLOCK = 2880

#: Temporary files: ``.scenesim-<pid>-<random>.<target basename>.tmp``; group 1 is the
#: owner's process id.
TEMP_PATTERN = re.compile(r"\.scenesim-(\d+)-[A-Za-z0-9_]+\.(.+)\.tmp", re.DOTALL)

#: FITS file extensions (a compression ending may follow).
_FITS_EXTENSIONS = (".fits", ".fit", ".fts")

#: Compression endings astropy reads but scenesim does not write: refused.
_REFUSED_COMPRESSION = (".bz2", ".xz", ".zip", ".z", ".fz", ".zst", ".lzma", ".lz4",
                        ".7z", ".tgz")

#: zlib level of ``.gz`` outputs: level 1 compresses simulated ramps as well as the
#: default 6 to within 3 % of the size, 1.5-2x faster (uint16 ramp 73 % at 44 MB/s
#: against 22 MB/s; slope file 52 % against 50 %).
_GZIP_LEVEL = 1

#: Room left for the target's name inside a temporary file's name (NAME_MAX is 255).
_TEMP_NAME_ROOM = 200

_UMASK_LOCK = threading.Lock()


def package_version():
    """Installed version of the ``scenesim`` distribution (``'unknown'`` if not installed)."""
    try:
        return metadata.version("scenesim")
    except metadata.PackageNotFoundError:
        return "unknown"


# ---------------------------------------------------------------- output names
def _is_gzip(path):
    return os.fspath(path).lower().endswith(".gz")


def check_output_name(name, path):
    """``path`` if scenesim can write a file of that name, else raise.

    A name ending in ``.gz`` is written gzip-compressed; the other compression
    endings astropy knows (``.bz2``, ``.xz``, ``.zip``, ``.Z``, ``.fz``, ...) are
    refused, so no file is ever written uncompressed under a compressed name.

    Raises
    ------
    noise.errors.ParameterError
        Naming ``name``, the path and what is allowed.
    """
    path = os.fspath(path)
    low = path.lower()
    for ending in _REFUSED_COMPRESSION:
        if low.endswith(ending):
            raise ParameterError(
                f"{name!r}: {path!r} asks for {path[-len(ending):]} compression, which "
                f"scenesim does not write; use a .fits name, or .fits.gz for gzip")
    return path


def derived_path(path, suffix):
    """The name of a file derived from ``path``: ``suffix`` inserted before the full
    extension.

    ``out.fits`` + ``'_truth'`` -> ``out_truth.fits``; ``out.fits.gz`` + ``'_ols'`` ->
    ``out_ols.fits.gz``; a name with no extension gets ``.fits`` (``out`` ->
    ``out_truth.fits``).  The directory is kept; dots in it do not count.

    Parameters
    ----------
    path : str or os.PathLike
    suffix : str
        E.g. ``'_truth'`` or ``'_gls'``.

    Returns
    -------
    str
    """
    path = os.fspath(path)
    head, base = os.path.split(path)
    stem, ext = os.path.splitext(base)
    if ext.lower() == ".gz":
        inner_stem, inner = os.path.splitext(stem)
        if inner.lower() in _FITS_EXTENSIONS:
            stem, ext = inner_stem, inner + ext
    return os.path.join(head, f"{stem}{suffix}{ext or '.fits'}")


def _file_size_limit():
    """The soft ``RLIMIT_FSIZE`` in bytes, or None when unlimited or unknown."""
    try:
        import resource
        soft = resource.getrlimit(resource.RLIMIT_FSIZE)[0]
    except (ImportError, OSError, ValueError, AttributeError):
        return None
    return None if soft == resource.RLIM_INFINITY else int(soft)


def output_error(path, exc, *, what=None):
    """:class:`noise.errors.OutputError` for the OS error ``exc`` met writing ``path``:
    one line, ``cannot write 'path': <reason> (<ERRNO>)``; with ``what``, ``cannot
    write 'path' (<what>): ...`` (a temporary file, which the user never named).

    The error number is looked for along the exception's chain (astropy re-raises
    write errors without it).  A short write without one (numpy's ``tofile``, which
    astropy uses, reports only the byte counts) is explained from the free space of
    ``path``'s directory and the file-size limit."""
    path = os.fspath(path)
    cause = exc
    for _ in range(16):                     # astropy re-raises without the errno
        if cause is None or getattr(cause, "errno", None) is not None:
            break
        cause = cause.__cause__ or cause.__context__
    if cause is not None and getattr(cause, "errno", None) is not None:
        exc = cause
    code = getattr(exc, "errno", None)
    text = " ".join(str(getattr(exc, "strerror", None) or exc).split()) \
        or type(exc).__name__
    limit = _file_size_limit()
    details = []
    if code is None:                    # a short write: find the likely reason
        free = None
        with contextlib.suppress(OSError, AttributeError):
            st = os.statvfs(os.path.dirname(os.path.abspath(path)))
            free = st.f_bavail * st.f_frsize
        if free is not None and free < (1 << 20):
            code = _errno.ENOSPC
        elif limit is not None:
            code = _errno.EFBIG
        if code is not None:
            details.append(f"short write: {text}")
            text = os.strerror(code)
    if code in _errno.errorcode:
        details.insert(0, _errno.errorcode[code])
    if code == _errno.EFBIG and limit is not None:
        details.insert(1, f"the file-size limit, ulimit -f, is {limit} bytes")
    reason = f"{text} ({'; '.join(details)})" if details else text
    said = f"{path!r} ({what})" if what else repr(path)
    return OutputError(f"cannot write {said}: {reason}", code)


# ---------------------------------------------------------------- temporary files
def temp_file(target, *, tag=None):
    """Create an empty temporary file beside ``target`` and return its path.

    Named ``.scenesim-<pid>-<random>.<target basename>[.<tag>].tmp``
    (:data:`TEMP_PATTERN`), mode ``0o600``.  The caller renames or removes it; if the
    process is killed first, :func:`remove_stale_temps` removes it later.
    """
    target = os.fspath(target)
    directory = os.path.dirname(os.path.abspath(target))
    base = os.path.basename(target) + (f".{tag}" if tag else "")
    while len(os.fsencode(base)) > _TEMP_NAME_ROOM:
        base = base[:-1]
    fd, tmp = tempfile.mkstemp(prefix=f".scenesim-{os.getpid()}-", suffix=f".{base}.tmp",
                               dir=directory)
    os.close(fd)
    return tmp


def _pid_alive(pid):
    """False only when no process ``pid`` exists (unknown counts as alive)."""
    if pid <= 0:
        return True
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except (OSError, OverflowError):     # PermissionError: another user's live process
        return True
    return True


def remove_stale_temps(directory="."):
    """Remove the temporary files of dead scenesim processes from ``directory``.

    A process killed by SIGKILL (or a power cut) leaves its temporary files behind.
    Those matching :data:`TEMP_PATTERN` whose owner process id is no longer alive are
    removed; a live process's files (this one's included) are never touched, nor
    files of another user, symbolic links or anything else.

    Parameters
    ----------
    directory : str or os.PathLike
        Directory to clean (not recursive).  A missing or unreadable directory has
        nothing to remove.

    Returns
    -------
    list of str
        The paths removed, sorted.
    """
    if os.name != "posix":
        return []
    directory = os.fspath(directory)
    removed = []
    try:
        entries = list(os.scandir(directory))
    except OSError:
        return []
    uid = os.getuid()
    for entry in entries:
        match = TEMP_PATTERN.fullmatch(entry.name)
        if match is None:
            continue
        try:
            if (not entry.is_file(follow_symlinks=False)
                    or entry.stat(follow_symlinks=False).st_uid != uid):
                continue
        except OSError:
            continue
        if _pid_alive(int(match.group(1))):
            continue
        try:
            os.unlink(entry.path)
        except OSError:
            continue
        removed.append(entry.path)
    return sorted(removed)


def _umask():
    """The process's umask, read without changing it where the system allows."""
    try:
        with open("/proc/self/status", encoding="ascii", errors="replace") as f:
            for line in f:
                if line.startswith("Umask:"):
                    return int(line.split()[1], 8)
    except (OSError, ValueError, IndexError):
        pass
    with _UMASK_LOCK:                    # set-and-restore, most restrictive meanwhile
        mask = os.umask(0o077)
        os.umask(mask)
    return mask


#: Outputs renamed into place by this process, in order (see :func:`completed_outputs`).
_COMPLETED = []


def record_completed(path):
    """Note that ``path`` was written completely (renamed into place)."""
    path = os.fspath(path)
    if path not in _COMPLETED:
        _COMPLETED.append(path)


def completed_outputs():
    """The files this process has written completely so far (renamed into place by
    :func:`atomic_path` or another atomic writer), in order: what an interrupted
    command keeps."""
    return list(_COMPLETED)


#: Existing files this process was told to replace (see :func:`stale_outputs`).
_REPLACING = []


def record_replacing(path):
    """Note that the existing file ``path`` is an output this command replaces."""
    path = os.path.abspath(os.fspath(path))
    if path not in _REPLACING:
        _REPLACING.append(path)


def stale_outputs():
    """The files this process was to replace (:func:`record_replacing`) and has not
    (yet): after an interrupt they are still an earlier run's, beside the new files
    (a probe's ``run --overwrite`` stopped while fitting kept the new exposure and
    truth beside the old slope file)."""
    done = {os.path.abspath(p) for p in _COMPLETED}
    return [p for p in _REPLACING if p not in done and os.path.lexists(p)]


@contextlib.contextmanager
def atomic_path(path, *, overwrite=False):
    """Yield a temporary path beside ``path``; rename it to ``path`` on success.

    The temporary file is :func:`temp_file`'s; on success it gets the mode ``open()``
    would give (``0o666 & ~umask``) and is renamed over ``path``.  On any exception
    the temporary file is removed and ``path`` is left untouched; an operating-system
    error (disk full, file-size limit, ...) is raised as
    :class:`noise.errors.OutputError` naming ``path``.

    Raises
    ------
    noise.errors.ParameterError
        Before anything is created: the directory is missing or not writable, ``path``
        is a directory, exists without ``overwrite``, or has a refused compression
        ending (:func:`check_output_name`).
    """
    path = check_writable("path", path, overwrite=overwrite)
    check_output_name("path", path)
    try:
        tmp = temp_file(path)
    except OSError as exc:
        raise output_error(path, exc) from exc
    try:
        yield tmp
        os.chmod(tmp, 0o666 & ~_umask())
        os.replace(tmp, path)
        record_completed(path)
    except BaseException as exc:
        with contextlib.suppress(OSError):
            os.unlink(tmp)
        if isinstance(exc, OSError) and not isinstance(exc, ScenesimError):
            raise output_error(path, exc) from exc
        raise


@contextlib.contextmanager
def atomic_file(path, *, overwrite=False, buffering=-1):
    """Yield a binary file object writing ``path`` atomically (see :func:`atomic_path`).

    A ``path`` ending in ``.gz`` is gzip-compressed on the fly (no extra pass over the
    data); any other is written as it is.  The file is closed, then renamed into
    place, when the block ends without an exception.
    """
    path = os.fspath(path)
    with atomic_path(path, overwrite=overwrite) as tmp:
        with open(tmp, "wb", buffering=buffering) as raw:
            if _is_gzip(path):
                with gzip.GzipFile(filename=os.path.basename(path)[:-3], mode="wb",
                                   fileobj=raw, compresslevel=_GZIP_LEVEL,
                                   mtime=0) as gz:
                    yield gz
            else:
                yield raw


class WriteBehind:
    """Hand a streamed output to the disk as it is written, and drop it from the cache.

    Why: a ramp is written once and not read back by the process that writes it, yet
    every byte written through the page cache takes a fresh page there.  Where the
    kernel must first obtain that page (on the virtual machine measured for
    BENCHMARKS.md, most likely because freed guest memory goes back to the host and
    is faulted in again), the writing thread spent ~20 ms of kernel CPU per 8 MB
    frame, against ~1.4 ms into pages freed moments before
    (``tests/tools/write_cost.py`` measures both): with the simulator's threads on
    every core, that CPU is taken from them.  After each piece, :meth:`written` asks
    the kernel to start writing the new bytes to disk
    (``posix_fadvise(POSIX_FADV_DONTNEED)`` starts write-back of dirty pages) and
    drops the pages of the piece written ``lag`` pieces before, clean by then, so the
    next pieces reuse them.  The data reach the disk sooner than the kernel's own
    write-back would send them, and the cache keeps only the last ``lag`` pieces of
    the file.

    It is advice only: pages still being written are left in place, it does not wait
    for the write-back to finish (it runs in the writer thread, beside the frames'
    making), and where ``posix_fadvise`` is missing or refuses the file (a pipe, some file
    systems) it does nothing.  A file read right after it was written is then read
    from disk, so it is used only for outputs that no step of the same run reads
    back (:func:`write_noise_fits`; the exposure of a ``scenesim run`` or a batch
    realisation that is not fitted, ``ExposureWriter(write_behind=True)`` of
    :mod:`scenesim.io.exposure`).

    Parameters
    ----------
    f : binary file object
        The output (a buffered or raw file with ``fileno``; anything else, e.g. a
        gzip stream, disables it).
    lag : int
        Pieces kept in the cache behind the one just written (>= 1).
    min_bytes : int
        A piece is handed over once at least this many bytes were written since the
        last one (>= 0; small frames are grouped, so the file's buffer still batches
        their writes).
    """

    def __init__(self, f, lag=2, min_bytes=1 << 22):
        self._f = f
        self._lag = check_int("lag", lag, minimum=1)
        self._min = check_int("min_bytes", min_bytes, minimum=0)
        self._ranges = []
        self._done = 0
        self.active = hasattr(os, "posix_fadvise") and isinstance(
            f, (io.BufferedWriter, io.FileIO))
        if self.active:
            try:
                self._fd = f.fileno()
                self._done = f.tell()
            except (OSError, ValueError):
                self.active = False

    def _advise(self, start, stop):
        try:
            os.posix_fadvise(self._fd, start, stop - start, os.POSIX_FADV_DONTNEED)
        except OSError:
            self.active = False

    def written(self):
        """Call after each piece is written: start its write-back, drop an old one."""
        if not self.active or self._f.tell() - self._done < max(self._min, 1):
            return
        self._f.flush()
        end = self._f.tell()
        self._ranges.append((self._done, end))
        self._done = end
        self._advise(*self._ranges[-1])          # starts writing the piece out
        if len(self._ranges) > self._lag and self.active:
            self._advise(*self._ranges.pop(0))   # written out by now: drop its pages


class WriterThread:
    """Writes handed to one background thread, in order, one pending at most.

    The streaming writers (:func:`write_noise_fits`, the exposure writer of
    :mod:`scenesim.io.exposure`) write frame ``k`` here while the caller makes frame
    ``k + 1``.  A write's exception is raised by the next :meth:`submit` or by
    :meth:`wait`; :meth:`close` waits for the last write (its exception dropped: the
    caller is already failing or has waited) and ends the thread.
    """

    def __init__(self):
        self._pool = ThreadPoolExecutor(1, thread_name_prefix="scenesim-write")
        self._pending = None

    def submit(self, fn, *args):
        """Wait for the write in progress, then start ``fn(*args)``."""
        self.wait()
        self._pending = self._pool.submit(fn, *args)

    def wait(self):
        """Wait for the write in progress (its exception raised here)."""
        pending, self._pending = self._pending, None
        if pending is not None:
            pending.result()

    def close(self):
        """Wait for the last write and end the thread (idempotent)."""
        if self._pool is not None:
            with contextlib.suppress(Exception):
                self.wait()
            self._pool.shutdown(wait=True)
            self._pool = None


# ---------------------------------------------------------------- reading
def _one_line(exc, limit=240):
    text = " ".join(str(exc).split()) or type(exc).__name__
    return text if len(text) <= limit else text[:limit - 3] + "..."


def input_path(path, what="file"):
    """``path`` (str, bytes or os.PathLike) as a str, or a ParameterError naming
    ``what`` it should be."""
    try:
        return os.fsdecode(os.fspath(path))
    except TypeError as exc:
        raise ParameterError(
            f"the {what} must be a path (str or os.PathLike), got "
            f"{type(path).__name__}") from exc


@contextlib.contextmanager
def open_fits(path, what="file", *, memmap=None):
    """Open the FITS file ``path`` for reading, every failure one clear error.

    Inside the block, astropy's warnings about the file (truncation, a damaged
    header) are errors, and any exception other than the project's own, raised while
    opening or reading, becomes a :class:`noise.errors.FileFormatError` that names
    the file, ``what`` it should be and what is wrong, in one line.

    Parameters
    ----------
    path : str or os.PathLike
    what : str
        What the file should be, for the message (``'exposure'``, ``'truth file'``).
    memmap : bool or None
        Passed to :func:`astropy.io.fits.open`.

    Yields
    ------
    astropy.io.fits.HDUList
    """
    path = input_path(path, what)
    if not os.path.exists(path):
        raise FileFormatError(f"{what} {path!r} does not exist")
    if os.path.isdir(path):
        raise FileFormatError(f"{what} {path!r} is a directory, not a FITS file")
    if not os.path.isfile(path):
        raise FileFormatError(f"{what} {path!r} is not a regular file")
    try:
        empty = os.path.getsize(path) == 0
    except OSError as exc:
        raise FileFormatError(f"cannot read {what} {path!r}: {_one_line(exc)}") from exc
    if empty:
        raise FileFormatError(f"{what} {path!r} is empty, not a FITS file")
    _check_gzip(path, what)
    with warnings.catch_warnings():
        warnings.simplefilter("error", AstropyWarning)
        try:
            # the file object is ours, so it is closed even when astropy fails
            # inside fits.open (it leaves its own open on some damaged headers)
            with open(path, "rb") as f, fits.open(f, memmap=memmap) as hdul:
                yield hdul
        except ScenesimError:
            raise
        except Exception as exc:             # noqa: BLE001 - anything astropy/numpy raise
            text = _one_line(exc)
            if "SIMPLE" in text:
                msg = f"{what} {path!r} is not a FITS file (no SIMPLE card at its start)"
            elif isinstance(exc, (OSError, EOFError, Warning)):
                msg = f"cannot read {what} {path!r}: {text}"
            else:                     # astropy/numpy tripping over a damaged header
                msg = f"cannot read {what} {path!r}: damaged FITS file ({text})"
            raise FileFormatError(msg) from exc


def same_file(a, b):
    """True if paths ``a`` and ``b`` name the same file (any spelling or link), or
    would once created (the same real path)."""
    if os.path.exists(a) and os.path.exists(b):
        return os.path.samefile(a, b)
    return os.path.realpath(a) == os.path.realpath(b)


_GZIP_MAGIC = b"\x1f\x8b"
_GZIP_CHUNK = 1 << 24
_gzip_verified = {}          # (path, inode, size, mtime_ns) -> True, of this process
_gzip_lock = threading.Lock()


def is_gzip_file(path):
    """True if the file at ``path`` starts with the gzip magic bytes (whatever its
    name: ``x.FITS.GZ`` is as compressed as ``x.fits.gz``)."""
    try:
        with open(path, "rb") as f:
            return f.read(2) == _GZIP_MAGIC
    except OSError:
        return False


def _check_gzip(path, what):
    """Refuse a gzip-compressed file whose stream is damaged.

    astropy reads a ``.fits.gz`` only as far as its HDUs go and never reaches the
    gzip trailer, so a damaged byte in the compressed data went unnoticed and gave
    wrong pixel values (a flipped byte in a 3-frame noise file changed 6 of them).
    Decompressing the whole stream once checks its CRC and length.  A file verified
    before in this process, unchanged since (path, inode, size, modification time),
    is not decompressed again.
    """
    if not is_gzip_file(path):
        return
    try:
        st = os.stat(path)
    except OSError as exc:
        raise FileFormatError(f"cannot read {what} {path!r}: {_one_line(exc)}") from exc
    key = (os.path.realpath(path), st.st_ino, st.st_size, st.st_mtime_ns)
    with _gzip_lock:
        if _gzip_verified.get(key):
            return
    try:
        with gzip.open(path, "rb") as g:
            while g.read(_GZIP_CHUNK):
                pass
    except (OSError, EOFError, zlib.error) as exc:     # BadGzipFile is an OSError
        raise FileFormatError(f"cannot read {what} {path!r}: damaged gzip stream "
                              f"({_one_line(exc)})") from exc
    with _gzip_lock:
        if len(_gzip_verified) > 256:
            _gzip_verified.clear()
        _gzip_verified[key] = True


_BITPIX = {np.dtype(np.uint8): 8, np.dtype(np.int16): 16, np.dtype(np.uint16): 16,
           np.dtype(np.int32): 32, np.dtype(np.uint32): 32, np.dtype(np.int64): 64,
           np.dtype(np.float32): -32, np.dtype(np.float64): -64}


class StreamingFITS:
    """Write image HDUs to an open binary file, data streamed in pieces.

    Use :meth:`begin_image` with the full shape, then :meth:`write` the data in C order
    (any number of pieces), then :meth:`end_image`.  ``uint16``/``uint32`` are stored
    with ``BZERO`` as FITS requires.  Other HDUs (tables) can be appended with
    :meth:`append_hdu`.
    """

    def __init__(self, fileobj):
        self.f = fileobj
        self._remaining = 0
        self._written = 0
        self._first = True
        self._dtype = None
        self._buf = None

    def _header(self, shape, dtype, cards, name):
        dtype = np.dtype(dtype)
        if dtype not in _BITPIX:
            raise ParameterError(f"'dtype' {dtype} cannot be written to FITS")
        hdr = fits.Header()
        if self._first:
            hdr["SIMPLE"] = True
        else:
            hdr["XTENSION"] = "IMAGE"
        hdr["BITPIX"] = _BITPIX[dtype]
        hdr["NAXIS"] = len(shape)
        for i, n in enumerate(reversed(shape)):
            hdr[f"NAXIS{i + 1}"] = int(n)
        if self._first:
            hdr["EXTEND"] = True
        else:
            hdr["PCOUNT"] = 0
            hdr["GCOUNT"] = 1
        if dtype == np.uint16:
            hdr["BZERO"] = 32768
            hdr["BSCALE"] = 1
        elif dtype == np.uint32:
            hdr["BZERO"] = 2147483648
            hdr["BSCALE"] = 1
        if name:
            hdr["EXTNAME"] = name
        for key, value, comment in cards:
            hdr[key] = (value, _fit_comment(key, value, comment))
        return hdr

    def begin_image(self, shape, dtype, cards=(), name=None):
        """Start an image HDU of ``shape`` and ``dtype`` with extra header ``cards``."""
        hdr = self._header(shape, dtype, cards, name)
        self.f.write(hdr.tostring().encode("ascii"))
        self._first = False
        self._dtype = np.dtype(dtype)
        self._buf = None
        self._remaining = int(np.prod(shape)) if len(shape) else 0
        self._written = 0

    def write(self, data):
        """Append a piece of the current image's data (C order)."""
        data = np.asarray(data, dtype=self._dtype)
        if data.size > self._remaining:
            raise ParameterError("more data written than the image shape holds")
        if self._dtype in (np.uint16, np.uint32):
            # FITS stores uintN as intN with BZERO 2**(N-1): v - 2**(N-1) is v with
            # its top bit flipped, read as intN; flipped and byte-swapped in place in a
            # reused buffer (the file object has taken the bytes when write returns)
            if self._buf is None or self._buf.size < data.size:
                self._buf = np.empty(data.size, dtype=self._dtype)
            raw = self._buf[:data.size].reshape(data.shape)
            top = 0x8000 if self._dtype == np.uint16 else 0x80000000
            np.bitwise_xor(data, self._dtype.type(top), out=raw)
            if sys.byteorder == "little":
                raw.byteswap(inplace=True)
        else:
            raw = np.ascontiguousarray(data.astype(self._dtype.newbyteorder(">"),
                                                   copy=False))
        self.f.write(raw.data)
        self._remaining -= data.size
        self._written += raw.nbytes

    def copy_raw(self, src, nbytes):
        """Append ``nbytes`` of already big-endian data for the current image from the
        binary file object ``src`` (e.g. a spooled temporary file)."""
        if nbytes != self._remaining * self._dtype.itemsize:
            raise ParameterError(
                f"raw copy of {nbytes} bytes does not match the {self._remaining} "
                f"values the image still needs")
        self.f.flush()
        shutil.copyfileobj(src, self.f, 16 << 20)
        self._remaining = 0
        self._written += nbytes

    def end_image(self):
        """Finish the current image (pads to 2880 bytes)."""
        if self._remaining:
            raise ParameterError(f"image incomplete: {self._remaining} values missing")
        pad = (-self._written) % _BLOCK
        self.f.write(b"\0" * pad)

    def append_hdu(self, hdu):
        """Append a complete astropy HDU (e.g. a ``BinTableHDU``)."""
        if self._first:
            raise ParameterError("the first HDU must be an image (primary)")
        if isinstance(hdu, fits.PrimaryHDU):
            hdu = fits.ImageHDU(hdu.data, hdu.header)
        self.f.write(_hdu_bytes(hdu))


def _fit_comment(key, value, comment):
    """Shorten ``comment`` so the card fits in 80 characters (no truncation warning)."""
    used = len(fits.Card(key, value).image.rstrip())
    room = 80 - used - 3
    return comment[:room] if room > 0 else ""


def _hdu_bytes(hdu):
    buf = io.BytesIO()
    fits.HDUList([fits.PrimaryHDU(), hdu]).writeto(buf)
    raw = buf.getvalue()
    # drop the dummy primary HDU (header only: a multiple of 2880 bytes)
    hdr_len = len(fits.PrimaryHDU().header.tostring())
    return raw[hdr_len:]


#: Keywords that describe a FITS file's structure: never taken from a caller.
_STRUCTURAL = re.compile(r"^(SIMPLE|BITPIX|NAXIS\d*|EXTEND|BZERO|BSCALE|BLANK|END|"
                         r"PCOUNT|GCOUNT|XTENSION|EXTNAME|EXTVER|TFIELDS|T[A-Z]+\d+|"
                         r"ZIMAGE|Z[A-Z]+\d*|CHECKSUM|DATASUM|CONTINUE|COMMENT|HISTORY)$")


def _check_extra_card(card):
    """``(key, value, comment)`` of a caller's header card, or a ParameterError: a
    standard keyword (1-8 of A-Z, 0-9, '-', '_') that is not structural, a value FITS
    holds (bool, int, finite float, printable ASCII string) and an ASCII comment."""
    key, value, comment = card if len(card) == 3 else (*card, "")
    if not isinstance(key, str) or not re.fullmatch(r"[A-Z0-9_-]{1,8}", key.upper()):
        raise ParameterError(f"'extra_cards': keyword {key!r} must be 1-8 characters of "
                             f"A-Z, 0-9, '-' and '_'")
    key = key.upper()
    if _STRUCTURAL.match(key):
        raise ParameterError(f"'extra_cards': {key!r} describes the file's structure "
                             f"(scenesim writes it); use another keyword")
    if isinstance(value, (bool, np.bool_)):
        value = bool(value)
    elif isinstance(value, (int, np.integer)):
        value = int(value)
        if not -2 ** 63 <= value < 2 ** 63:
            raise ParameterError(f"'extra_cards': {key} = {value!r} does not fit a FITS "
                                 f"integer (64-bit)")
    elif isinstance(value, (float, np.floating)):
        value = float(value)
        if not math.isfinite(value):
            raise ParameterError(f"'extra_cards': {key} = {value!r} is not finite; FITS "
                                 f"holds finite numbers")
    elif isinstance(value, str):
        check_str(f"extra_cards {key}", value, label=True)
    else:
        raise ParameterTypeError(f"'extra_cards': {key} must be a bool, an integer, a "
                                 f"finite number or a string, got {describe(value)}")
    if not isinstance(comment, str):
        raise ParameterTypeError(f"'extra_cards': the comment of {key} must be a string, "
                                 f"got {describe(comment)}")
    check_str(f"extra_cards {key} comment", comment, label=True)
    return key, value, comment


def write_noise_fits(path, generator, nframes, *, nints=1, unit="e", gain=1.0,
                     overwrite=False, progress=None, extra_cards=()):
    """Stream a noise-only ramp to a FITS file, atomically.

    Parameters
    ----------
    path : str
        Output file; a name ending in ``.gz`` is written gzip-compressed.
    generator : noise.NoiseGenerator
    nframes : int
        Read frames per integration.
    nints : int
        Integrations.
    unit : {'e', 'DN'}
        ``'e'``: float32 electrons.  ``'DN'``: uint16, electrons / ``gain``, rounded and
        clipped to [0, 65535].
    gain : float
        e-/DN, used for ``unit='DN'`` and recorded in the header.  With ``'DN'`` the
        noise of the generator's detector must fit in the 16-bit range in electrons,
        ``gain * 65535``, with the bias 5 rms spreads inside it at the bias
        pattern's extremes, or the ADC would clip it
        (:meth:`noise.NoiseParams.check_adc`).
    overwrite : bool
        Replace an existing file (default: refuse it).
    progress : callable, optional
        Called with the number of frames written after each frame.
    extra_cards : sequence of (key, value[, comment])
        More primary-header cards.

    The data have shape (nframes, ny, nx) for one integration, else
    (nints, nframes, ny, nx).  The header records every detector and noise parameter,
    the seed and the package version (``FILETYPE = 'noise'``).

    Raises
    ------
    noise.errors.ParameterError
        A bad argument or output name, before anything is written.
    noise.errors.OutputError
        The file could not be written (disk full, file-size limit); nothing is left.
    """
    # (noise.generator imports this module)
    from noise.generator import MAX_FRAMES, MAX_FRAMES_TOTAL, NoiseGenerator
    path = check_path("path", path)
    check_instance("generator", generator, NoiseGenerator, "a noise.NoiseGenerator")
    unit = check_choice("unit", unit, ("e", "DN"))
    gain = check_float("gain", gain, minimum=0.0, strict_min=True)
    nframes = check_int("nframes", nframes, minimum=1, maximum=MAX_FRAMES)
    nints = check_int("nints", nints, minimum=1, maximum=MAX_FRAMES)
    if nframes * nints > MAX_FRAMES_TOTAL:
        raise ParameterError(f"'nframes' x 'nints' = {nframes} x {nints}: at most "
                             f"{MAX_FRAMES_TOTAL} frames per file")
    overwrite = check_bool("overwrite", overwrite)
    if progress is not None and not callable(progress):
        raise ParameterTypeError(f"'progress' must be callable or None, got "
                                 f"{type(progress).__name__} {describe(progress)}")
    if isinstance(extra_cards, (str, bytes)) or not is_sequence(extra_cards) or \
            not all(isinstance(c, tuple) and len(c) in (2, 3) for c in extra_cards):
        raise ParameterTypeError(f"'extra_cards' must be a sequence of (key, value[, "
                                 f"comment]) tuples, got {describe(extra_cards)}")
    extra_cards = [_check_extra_card(c) for c in extra_cards]
    template = generator.params.pca0_file          # the one file the generator reads
    if template is not None and same_file(path, template):
        raise ParameterError(
            f"'path' {os.fspath(path)!r} is the generator's 'pca0_file' (a file it "
            f"reads): it is never replaced, even with overwrite=True")
    if unit == "DN":
        # no noise clipped at the 16-bit ADC (noise.params module notes)
        try:
            generator.params.check_adc(gain, 16, generator.detector)
        except ParameterError as exc:
            raise ParameterError(f"unit='DN' (16-bit): {exc}") from exc
    det = generator.detector
    shape = ((nframes,) if nints == 1 else (nints, nframes)) + det.shape
    dtype = np.float32 if unit == "e" else np.uint16
    cards = [("ORIGIN", "scenesim", "noise-only HxRG ramp"),
             ("FILETYPE", "noise", "scenesim file: noise-only ramp"),
             ("NEXTEND", 0, "extensions after the primary HDU"),
             ("SSIMVER", package_version(), "scenesim package version"),
             ("BUNIT", "electron" if unit == "e" else "DN", "data unit"),
             ("GAIN", gain, "[e-/DN]"),
             ("NINTS", nints, "integrations"),
             ("NFRAMES", nframes, "read frames per integration"),
             ("SEEDENT", str(generator.entropy), "root SeedSequence entropy"),
             ("SEEDKEY", ",".join(map(str, generator.key)) or "-", "root spawn key")]
    cards += det.to_header_cards() + generator.params.to_header_cards()
    ours = {c[0] for c in cards}
    for key, _, _ in extra_cards:
        if key in ours:
            raise ParameterError(f"'extra_cards': {key!r} is a card scenesim writes "
                                 f"itself (the file's provenance); use another keyword")
    cards += extra_cards
    with atomic_file(path, overwrite=overwrite, buffering=1 << 20) as f:
        out = StreamingFITS(f)
        out.begin_image(shape, dtype, cards)
        # DN frames are converted in the generator's worker threads (bit-identical
        # to noise.adc.to_dn)
        # frame k is written by a writer thread while frame k + 1 is generated
        # (two frame buffers in turn; writes stay in order, one pending at most)
        frames = generator.frames(nframes, nints=nints,
                                  dn_gain=None if unit == "e" else gain, reuse=2)
        # the ramp goes to disk as it is written, not into the page cache
        behind = WriteBehind(f)

        def write(frame):
            out.write(frame)
            behind.written()

        writer = WriterThread()
        try:
            for n, (_, _, frame) in enumerate(frames):
                writer.submit(write, frame)
                if progress is not None:
                    progress(n + 1)
            writer.wait()
        finally:
            writer.close()
            frames.close()
        out.end_image()
    return path
