"""Streaming FITS output, written atomically.

Cubes are written frame by frame, so memory does not grow with the number of frames:
the header is written first, then each frame's bytes (big-endian, as FITS requires),
then the padding to a multiple of 2880 bytes.  Everything goes to a temporary file in
the destination directory, renamed over the destination only when complete, so an
interrupted or failed run never leaves a partial or corrupt file.
"""

import contextlib
import io
import os
import shutil
import sys
import tempfile
from concurrent.futures import ThreadPoolExecutor
from importlib import metadata

import numpy as np
from astropy.io import fits

from noise.validate import check_float, check_writable
from noise.errors import ParameterError

__all__ = ["atomic_path", "StreamingFITS", "package_version",
           "write_noise_fits"]

_BLOCK = 2880


def package_version():
    """Installed version of the ``scenesim`` distribution (``'unknown'`` if not installed)."""
    try:
        return metadata.version("scenesim")
    except metadata.PackageNotFoundError:
        return "unknown"


@contextlib.contextmanager
def atomic_path(path, *, overwrite=True):
    """Yield a temporary path beside ``path``; rename it to ``path`` on success.

    On any exception the temporary file is removed and ``path`` is left untouched.
    """
    path = check_writable("path", path, overwrite=overwrite)
    directory = os.path.dirname(os.path.abspath(path))
    fd, tmp = tempfile.mkstemp(prefix=".tmp-", suffix=".fits", dir=directory)
    os.close(fd)
    try:
        yield tmp
        os.replace(tmp, path)
    except BaseException:
        with contextlib.suppress(OSError):
            os.unlink(tmp)
        raise


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


def write_noise_fits(path, generator, nframes, *, nints=1, unit="e", gain=1.0,
                     overwrite=True, progress=None, extra_cards=()):
    """Stream a noise-only ramp to a FITS file, atomically.

    Parameters
    ----------
    path : str
        Output file.
    generator : noise.NoiseGenerator
    nframes : int
        Read frames per integration.
    nints : int
        Integrations.
    unit : {'e', 'DN'}
        ``'e'``: float32 electrons.  ``'DN'``: uint16, electrons / ``gain``, rounded and
        clipped to [0, 65535].
    gain : float
        e-/DN, used for ``unit='DN'`` and recorded in the header.
    progress : callable, optional
        Called with the number of frames written after each frame.

    The data have shape (nframes, ny, nx) for one integration, else
    (nints, nframes, ny, nx).  The header records every detector and noise parameter,
    the seed and the package version.
    """
    if unit not in ("e", "DN"):
        raise ParameterError(f"'unit' must be 'e' or 'DN', got {unit!r}")
    gain = check_float("gain", gain, minimum=0.0, strict_min=True)
    nframes = int(nframes)
    nints = int(nints)
    if nframes < 1 or nints < 1:
        raise ParameterError(
            f"'nframes' and 'nints' must be >= 1, got {nframes!r} and {nints!r}")
    det = generator.detector
    shape = ((nframes,) if nints == 1 else (nints, nframes)) + det.shape
    dtype = np.float32 if unit == "e" else np.uint16
    cards = [("ORIGIN", "scenesim", "noise-only HxRG ramp"),
             ("SSIMVER", package_version(), "scenesim package version"),
             ("BUNIT", "electron" if unit == "e" else "DN", "data unit"),
             ("GAIN", gain, "[e-/DN]"),
             ("NINTS", nints, "integrations"),
             ("NFRAMES", nframes, "read frames per integration"),
             ("SEEDENT", str(generator.entropy), "root SeedSequence entropy"),
             ("SEEDKEY", ",".join(map(str, generator.key)) or "-", "root spawn key")]
    cards += det.to_header_cards() + generator.params.to_header_cards() + list(extra_cards)
    with atomic_path(path, overwrite=overwrite) as tmp:
        with open(tmp, "wb", buffering=1 << 20) as f:
            out = StreamingFITS(f)
            out.begin_image(shape, dtype, cards)
            # DN frames are converted in the generator's worker threads (bit-identical
            # to noise.adc.to_dn)
            # frame k is written by a writer thread while frame k + 1 is generated
            # (two frame buffers in turn; writes stay in order, one pending at most)
            frames = generator.frames(nframes, nints=nints,
                                      dn_gain=None if unit == "e" else gain, reuse=2)
            with ThreadPoolExecutor(1) as writer:
                pending = None
                try:
                    for n, (_, _, frame) in enumerate(frames):
                        if pending is not None:
                            pending.result()
                        pending = writer.submit(out.write, frame)
                        if progress is not None:
                            progress(n + 1)
                    if pending is not None:
                        pending.result()
                finally:
                    frames.close()
            out.end_image()
    return path
