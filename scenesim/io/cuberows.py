"""Row blocks of a resultant cube read from its file, for a fit that streams.

A ramp fit needs every resultant of a pixel but nothing of the pixels far from it,
so :func:`scenesim.rampfit.fit_ramps` can read its cube by blocks of rows instead
of holding it (a 4096 x 4096 x 100 cube is 6.7 GB in float32; its fit's outputs
are ~40 bytes per pixel whatever the ramp length).  A *row source* is any object
with

* ``shape``: ``(nints, nres, ny, nx)``;
* ``dtype``: the dtype of what ``rows`` returns;
* ``rows(y0, y1)``: the resultants of rows ``y0:y1`` of every integration and
  resultant, an ndarray ``(nints, nres, y1 - y0, nx)``; called from several threads
  at once;
* ``all_finite`` (optional): ``True`` when the values cannot be NaN or inf (integer
  data), so the fitter's finiteness pre-pass over the file is skipped.

:class:`CubeRows` is one for an uncompressed C-ordered cube at a byte offset of a
file: each block is ``nints x nres`` positioned reads (``os.preadv``, no memory
map, so the pages read are not counted in the process's resident memory, and
nothing is cached here), converted to float32 electrons.  :func:`exposure_rows`
opens the ``SCI`` cube of an exposure file (:mod:`scenesim.io.exposure`: uint16 DN,
BZERO 32768, big-endian) and :func:`npy_rows` a ``.npy`` file; :meth:`CubeRows.frames`
reads whole frames.  :class:`NpyCube` is a float32 ``.npy`` cube that is also written
in place, by frames or rows (the temporary cube of the streamed preparation of
:func:`scenesim.calib.prepare.fit_exposure_file`).

The values are those of the in-memory path to the last bit: ``DN.astype(float32) *
float32(gain)`` as :func:`scenesim.calib.prepare.prepare_exposure` computes
electrons, and the ``.npy`` values as stored.
"""

import os

import numpy as np

from noise.errors import FileFormatError, ParameterError
from noise.fitsio import input_path, is_gzip_file, open_fits
from noise.validate import check_float, check_int

from scenesim.io.exposure import _check_exposure

__all__ = ["CubeRows", "NpyCube", "exposure_rows", "npy_rows"]

_F32 = np.float32


class CubeRows:
    """Row blocks of a C-ordered ``(nints, nres_file, ny, nx)`` cube in a file.

    Parameters
    ----------
    path : str or os.PathLike
        The file (uncompressed).
    offset : int
        Byte offset of the cube's first value.
    shape : tuple of 4 int
        ``(nints, nres_file, ny, nx)`` as stored.
    file_dtype : numpy dtype
        Stored dtype, byte order included (e.g. ``'>i2'``, ``'<f4'``).
    nres : int or None
        Read the first ``nres`` resultants of each integration only (None: all).
    gain : float
        Multiplies the values (e-/DN), as float32; 1 leaves float32 data untouched.
    bzero : int
        Added to integer data before the gain (FITS ``BZERO``: 32768 for uint16).
    name : str or None
        The extension the cube is (``'SCI'``): float values must then be finite,
        and the first that is not is named with its place (a file error); None:
        values as stored.
    """

    def __init__(self, path, offset, shape, file_dtype, *, nres=None, gain=1.0,
                 bzero=0, name=None):
        self.path = os.fspath(path)
        self._offset = int(offset)
        self._file_dtype = np.dtype(file_dtype)
        nints, nres_file, ny, nx = (int(v) for v in shape)
        nres = nres_file if nres is None else check_int("nres", nres, minimum=1)
        if nres > nres_file:
            raise ParameterError(f"'nres' must be at most the {nres_file} resultants "
                                 f"of {self.path!r}, got {nres}")
        self._file_shape = (nints, nres_file, ny, nx)
        self.shape = (nints, nres, ny, nx)
        self._gain = _F32(check_float("gain", gain, minimum=0.0, strict_min=True))
        self._bzero = int(bzero)
        self._name = name
        integer = self._file_dtype.kind in "iu"
        self.all_finite = integer
        self.dtype = np.dtype(_F32) if integer or self._file_dtype.itemsize <= 4 \
            else np.dtype(np.float64)
        need = self._offset + self._file_dtype.itemsize * int(np.prod(self._file_shape))
        size = os.path.getsize(self.path)
        if size < need:
            raise FileFormatError(f"{self.path!r} is truncated: its cube {shape} needs "
                                  f"{need} bytes, the file has {size}")

    def rows(self, y0, y1):
        """Rows ``y0:y1`` of every integration and resultant: ndarray ``(nints, nres,
        y1 - y0, nx)`` of :attr:`dtype` (e- for integer data times the gain)."""
        nints, nres_file, ny, nx = self._file_shape
        nres = self.shape[1]
        raw = np.empty((nints, nres, (y1 - y0) * nx), self._file_dtype)
        fd = os.open(self.path, os.O_RDONLY)
        try:
            for k in range(nints):
                for r in range(nres):
                    _read_into(fd, raw[k, r], self._pos(k, r, y0), self.path)
        finally:
            os.close(fd)
        out = self._values(raw).reshape(nints, nres, y1 - y0, nx)
        self._check_finite(out, 0, 0, y0)
        return out

    def frames(self, k, r0, r1):
        """Resultants ``r0:r1`` of integration ``k``, whole frames: ndarray ``(r1 -
        r0, ny, nx)`` of :attr:`dtype` (one positioned read: they are contiguous)."""
        ny, nx = self.shape[2:]
        raw = np.empty((r1 - r0, ny, nx), self._file_dtype)
        fd = os.open(self.path, os.O_RDONLY)
        try:
            _read_into(fd, raw, self._pos(k, r0, 0), self.path)
        finally:
            os.close(fd)
        out = self._values(raw)
        self._check_finite(out[None], k, r0, 0)
        return out

    def _check_finite(self, out, k0, r0, y0):
        """Refuse a non-finite value of a named float cube (``out`` (nints, nres,
        rows, nx) from integration ``k0``, resultant ``r0``, row ``y0``)."""
        if self._name is None or self.all_finite or np.isfinite(out).all():
            return
        k, r, y, x = (int(v) for v in np.argwhere(~np.isfinite(out))[0])
        raise FileFormatError(
            f"{self.path!r}: {self._name} holds {out[k, r, y, x]} at integration "
            f"{k0 + k}, group {r0 + r}, pixel (y={y0 + y}, x={x}); its values must be "
            f"finite (a saturated or bad pixel is a DQ flag, not a value)")

    def _pos(self, k, r, y):
        """Byte position of row ``y`` of resultant ``r`` of integration ``k``."""
        _, nres_file, ny, nx = self._file_shape
        return self._offset + (((k * nres_file + r) * ny + y) * nx) \
            * self._file_dtype.itemsize

    def _values(self, raw):
        """Stored values ``raw`` as :attr:`dtype`, with BZERO and the gain."""
        if self._file_dtype.kind in "iu":
            if self._file_dtype == np.dtype(">i2") and self._bzero == 32768:
                # uint16 stored with BZERO: flip the sign bit, exactly the uint16 value
                vals = (raw.view(">u2") ^ np.uint16(0x8000)).astype(np.uint16)
            else:
                vals = raw.astype(np.int64) + self._bzero
            out = vals.astype(_F32)
            if self._gain != 1:
                out *= self._gain
        else:
            out = raw.astype(self.dtype)
            if self._gain != 1:
                out *= self.dtype.type(self._gain)
        return out


def _read_into(fd, arr, pos, path):
    """Fill the contiguous ndarray ``arr`` from byte ``pos`` of the open file ``fd``."""
    buf = memoryview(arr).cast("B")
    got = 0
    while got < len(buf):                      # short reads: continue
        more = os.preadv(fd, [buf[got:]], pos + got)
        if more == 0:
            raise FileFormatError(f"{path!r} ended at byte {pos + got} while reading")
        got += more


class NpyCube(CubeRows):
    """A float32 ``.npy`` cube ``(nints, nres, ny, nx)`` written and read in place.

    :meth:`create` makes the file (sparse, zeros) and the object; frames and rows are
    then written with positioned writes (``os.pwrite``) and read as a
    :class:`CubeRows` (no memory map, so nothing of the file counts in the process's
    resident memory).  The values read are those written, to the last bit.  The
    caller removes the file.
    """

    @classmethod
    def create(cls, path, shape):
        """Create ``path`` holding a zero float32 cube of ``shape`` and return it."""
        shape = tuple(int(v) for v in shape)
        if len(shape) != 4 or min(shape) < 1:
            raise ParameterError(f"'shape' must be 4 positive integers (nints, nres, "
                                 f"ny, nx), got {shape!r}")
        with open(path, "wb") as f:
            np.lib.format.write_array_header_1_0(
                f, {"descr": np.lib.format.dtype_to_descr(np.dtype("<f4")),
                    "fortran_order": False, "shape": shape})
            offset = f.tell()
            f.truncate(offset + 4 * int(np.prod(shape)))
        return cls(path, offset, shape, "<f4")

    def write_frames(self, k, r0, values):
        """Write ``values`` ``(n, ny, nx)`` as resultants ``r0:r0 + n`` of
        integration ``k``."""
        arr = np.ascontiguousarray(values, dtype="<f4")
        self._write(arr, self._pos(k, r0, 0))

    def write_rows(self, y0, values):
        """Write ``values`` ``(nints, nres, n, nx)`` as rows ``y0:y0 + n`` of every
        integration and resultant."""
        arr = np.asarray(values, dtype="<f4")
        for k in range(arr.shape[0]):
            for r in range(arr.shape[1]):
                self._write(np.ascontiguousarray(arr[k, r]), self._pos(k, r, y0))

    def _write(self, arr, pos):
        buf = memoryview(arr).cast("B")
        fd = os.open(self.path, os.O_WRONLY)
        try:
            done = 0
            while done < len(buf):
                done += os.pwrite(fd, buf[done:], pos + done)
        finally:
            os.close(fd)


def exposure_rows(path, *, gain=None, nres=None):
    """The ``SCI`` cube of an exposure file as row blocks in electrons.

    Parameters
    ----------
    path : str or os.PathLike
        Exposure file (:mod:`scenesim.io.exposure`), uncompressed.
    gain : float or None
        e-/DN; None: the header's ``GAIN`` (1 if absent).
    nres : int or None
        The first ``nres`` resultants only (None: all ``NGROUPS``).

    Returns
    -------
    CubeRows
        ``rows(y0, y1)`` gives ``SCI[:, :nres, y0:y1].astype(float32) *
        float32(gain)``.

    Raises
    ------
    noise.errors.FileFormatError
        Not an exposure, a compressed file, or a ``SCI`` that is not 16-bit integer
        or 32/64-bit float data with ``BSCALE`` 1.
    """
    path = input_path(path, "exposure")
    if str(path).lower().endswith(".gz") or is_gzip_file(path):   # X.FITS.GZ too
        raise FileFormatError(f"{path!r}: row blocks need an uncompressed exposure "
                              f"file (gunzip it first)")
    with open_fits(path, "exposure") as hdul:
        _check_exposure(hdul, path)
        hdr = hdul["SCI"].header
        index = [h.name for h in hdul].index("SCI")
        offset = hdul.fileinfo(index)["datLoc"]
        bitpix = hdr["BITPIX"]
        bscale, bzero = hdr.get("BSCALE", 1), hdr.get("BZERO", 0)
        shape = tuple(hdr[f"NAXIS{i}"] for i in (4, 3, 2, 1))
        gain = hdul[0].header.get("GAIN", 1.0) if gain is None else gain
    kinds = {16: ">i2", -32: ">f4", -64: ">f8"}
    if bitpix not in kinds or bscale != 1 or (bitpix < 0 and bzero != 0) \
            or bzero not in (0, 32768):
        raise FileFormatError(f"exposure file {path!r}: SCI must be 16-bit integers "
                              f"(BZERO 0 or 32768) or floats with BSCALE 1, got BITPIX="
                              f"{bitpix}, BSCALE={bscale}, BZERO={bzero}")
    return CubeRows(path, offset, shape, kinds[bitpix], nres=nres, gain=gain,
                    bzero=int(bzero), name="SCI")


def npy_rows(path, *, nres=None):
    """A ``.npy`` cube ``(nres, ny, nx)`` or ``(nints, nres, ny, nx)`` (C order, not
    pickled) as row blocks, values as stored (float32 for integer data)."""
    path = os.fspath(path)
    with open(path, "rb") as f:
        try:
            version = np.lib.format.read_magic(f)
            read_header = np.lib.format.read_array_header_1_0 if version == (1, 0) \
                else np.lib.format.read_array_header_2_0
            shape, fortran, dtype = read_header(f)
        except ValueError as exc:
            raise FileFormatError(f"{path!r} is not a .npy file: {exc}") from exc
        offset = f.tell()
    if fortran or len(shape) not in (3, 4) or dtype.kind not in "iuf":
        raise FileFormatError(f"{path!r}: need a C-ordered 3-D or 4-D numeric cube, got "
                              f"shape {shape}, dtype {dtype}, fortran_order {fortran}")
    shape = shape if len(shape) == 4 else (1,) + tuple(shape)
    return CubeRows(path, offset, shape, dtype, nres=nres)
