"""Exposure and truth files.

Exposure: the JWST level-1b "uncal" layout, readable by astropy and by the JWST
calibration library's ramp fitting without changing its layout:

* primary HDU (no data) with the exposure keywords: NINTS, NGROUPS, NFRAMES, GROUPGAP,
  DROPFRM1, TFRAME, TGROUP, READPATT, NOUTPUTS, DETECTOR, SUBARRAY (+ SUBSTRT/SUBSIZE),
  GAIN (e-/DN), RDNOISE (e- per read, not CDS), SEED, SCENE and SSIMVER, plus every
  detector and noise parameter, and the charge effects: FULLWELL (e-), NONLIN and
  NLCOEFF (``c2,c3,...`` of ``m = q + c2 q^2 + c3 q^3``, e-), IPC (T/F) and, when
  IPC is on, IPCKERN: the nine values of the 3x3 kernel of
  :func:`scenesim.detector.ipc.apply_ipc`, row by row (``k[1+dy, 1+dx]`` is the fraction
  of a pixel's signal seen by its neighbour at ``(y+dy, x+dx)``; ``%.10g``; the
  engine's kernel as given, which ``apply_ipc`` renormalises to sum 1), so that a
  fit can undo it (:func:`scenesim.calib.prepare.header_ipc_kernel`);
* ``SCI``: uint16 DN, shape (nints, ngroups, ny, nx), streamed resultant by resultant;
* ``READS``: one row per resultant with its read indices, read times and mean time (the
  per-resultant read times that uneven patterns need).

Truth (``<stem>_truth.fits``): ``RATE`` (expected e-/s of collected charge per pixel,
the QE flat included, before IPC), ``RATE_IPC`` (after IPC: what a linear fit of the
raw ramps recovers), ``SATREAD``
(first saturated read per pixel and integration, as a frame index counted from reset,
-1 if none; only reads that some resultant uses are materialised, so a pixel that fills
its well during skipped frames reports the next read that is actually taken),
``SATGROUP`` (first resultant containing it), ``CRS`` (cosmic-ray deposits: time, pixel, charge, whether a
read saw it), ``SOURCES`` (the catalogue as rendered), and optionally ``CHARGE``
(noise-free charge resultants, e-) and ``NOISE`` (noise-only resultants, e-).

In memory: :class:`Exposure` holds what an exposure file holds (``SCI``, the primary
header and the ``READS`` table, exactly as :func:`read_exposure` returns them from a
file).  ``ExposureWriter(engine, None)`` returns one, so a run that wants slopes but
no ramp file fits the resultants straight from memory
(:func:`scenesim.calib.prepare.prepare_exposure` takes a path or an :class:`Exposure`); its
header and table go through the same FITS serialisation as the file's, so the fit
sees the same values to the last bit.

Every file is written to a temporary file and renamed when complete.
"""

import contextlib
import io
import os
import tempfile
from dataclasses import dataclass

import numpy as np
from astropy.io import fits
from astropy.table import Table

from noise.errors import FileFormatError
from noise.validate import check_writable
from noise.fitsio import StreamingFITS, atomic_path

from scenesim.io.header import exposure_cards

__all__ = ["Exposure", "ExposureWriter", "truth_path_for", "read_exposure",
           "read_truth"]

#: Output file buffer (bytes): small frames are written 1 MB at a time, not per frame.
_WRITE_BUFFER = 1 << 20


@dataclass(frozen=True, eq=False)
class Exposure:
    """An exposure in memory: the contents of an exposure file.

    Parameters
    ----------
    sci : ndarray, shape (nints, ngroups, ny, nx), uint16, DN
        Resultants (the ``SCI`` extension).
    header : astropy.io.fits.Header
        Primary header (``GAIN`` e-/DN, ``RDNOISE`` e- per read, ``TFRAME`` s, ...).
    reads : astropy.table.Table
        The ``READS`` table (one row per resultant, see
        :meth:`scenesim.detector.readout.Readout.read_table`).
    name : str
        Label recorded in the header of a fit of it (the file path, or
        ``'(in memory)'``).
    """

    sci: np.ndarray
    header: fits.Header
    reads: Table
    name: str = "(in memory)"

    @classmethod
    def read(cls, path):
        """Load an exposure file (see :func:`read_exposure`) as an :class:`Exposure`.

        Parameters
        ----------
        path : str or os.PathLike

        Returns
        -------
        Exposure
            ``name`` is ``os.fspath(path)``.

        Raises
        ------
        noise.errors.FileFormatError
            Missing file, or no ``SCI`` or ``READS`` extension.
        """
        path = os.fspath(path)
        sci, header, reads = read_exposure(path)
        return cls(sci, header, reads, path)


def truth_path_for(path):
    """``dir/stem_truth.fits`` for exposure ``dir/stem.fits``."""
    stem, ext = os.path.splitext(os.fspath(path))
    return f"{stem}_truth{ext or '.fits'}"


class _RawCube:
    """Big-endian float32 data appended to a temporary file, copied into FITS later."""

    def __init__(self, directory):
        fd, self.path = tempfile.mkstemp(prefix=".tmp-", suffix=".raw", dir=directory)
        self.f = os.fdopen(fd, "wb")

    def write(self, data):
        self.f.write(np.asarray(data, dtype=">f4").tobytes())

    def copy_into(self, stream, shape, name, cards):
        self.f.close()
        stream.begin_image(shape, np.float32, cards, name=name)
        with open(self.path, "rb") as f:
            stream.copy_raw(f, int(np.prod(shape)) * 4)
        stream.end_image()

    def discard(self):
        with contextlib.suppress(OSError):
            self.f.close()
        with contextlib.suppress(OSError):
            os.unlink(self.path)


class ExposureWriter:
    """The sink of a run: streams resultants to the exposure file and writes the truth.

    The writer does not run the engine: the orchestrator
    (:func:`scenesim.run.write_exposure`) pulls each :class:`scenesim.engine.Resultant`
    from the engine's run and hands it to :meth:`add`, then calls :meth:`finish` with
    the finished run.  Used as a context manager, an exception (or interrupt) before
    :meth:`finish` removes every temporary file and leaves existing files untouched.

    Parameters
    ----------
    engine : scenesim.engine.ChargeEngine
        Describes what is written (header, readout, truth rates); not run here.
    path : str or None
        Exposure file; ``None`` keeps the resultants in memory (:meth:`finish`
        returns them as an :class:`Exposure`).
    cards : sequence of (key, value, comment)
        Extra primary-header cards (scene, seed, PSF, ...).
    truth_path : str or None
        Truth file; ``None`` writes none.
    save_charge, save_noise : bool
        Add the noise-free charge and the noise-only resultants to the truth file.
    sources : astropy.table.Table or None
        Rendered source catalogue for the truth file.
    overwrite : bool
        Replace existing files.
    """

    def __init__(self, engine, path, *, cards=(), truth_path=None, save_charge=False,
                 save_noise=False, sources=None, overwrite=True):
        if path is not None:
            check_writable("output path", path, overwrite=overwrite)
        if truth_path is not None:
            check_writable("truth path", truth_path, overwrite=overwrite)
        self.engine, self.path, self.truth_path = engine, path, truth_path
        self.sources, self.overwrite = sources, overwrite
        det, ro = engine.detector, engine.readout
        self.shape = (ro.nints, ro.ngroups) + det.shape
        self.header = exposure_cards(engine, cards)
        self.save_charge = truth_path is not None and save_charge
        self.save_noise = truth_path is not None and save_noise
        self._stack = contextlib.ExitStack()
        self._stream = None
        self._sci = None
        self._raws = {}
        try:
            if path is not None:
                tmp = self._stack.enter_context(atomic_path(path, overwrite=overwrite))
                fobj = self._stack.enter_context(open(tmp, "wb", buffering=_WRITE_BUFFER))
                self._stream = StreamingFITS(fobj)
                self._stream.begin_image((), np.uint8, self.header)
                self._stream.end_image()
                self._stream.begin_image(self.shape, np.uint16,
                                         [("BUNIT", "DN", "raw counts")], name="SCI")
            else:
                self._sci = np.empty(self.shape, dtype=np.uint16)
            tdir = os.path.dirname(os.path.abspath(truth_path or path or "."))
            for name, wanted in (("CHARGE", self.save_charge),
                                 ("NOISE", self.save_noise)):
                if wanted:
                    self._raws[name] = _RawCube(tdir)
        except BaseException:
            self.abort()
            raise

    def add(self, res):
        """Write one :class:`scenesim.engine.Resultant` (they come in file order)."""
        if self._stream is not None:
            self._stream.write(res.dn)
        else:
            self._sci[res.integration, res.index] = res.dn
        if "CHARGE" in self._raws:
            self._raws["CHARGE"].write(res.charge)
        if "NOISE" in self._raws:
            self._raws["NOISE"].write(res.noise)

    def finish(self, run):
        """Complete the files from the finished ``run`` (its ``sat_read`` and
        ``cr_seen``) and rename them into place.

        Returns
        -------
        dict
            ``sat_read`` and ``cr_seen``; and, when ``path`` is None, ``sci``
            (nints, ngroups, ny, nx) uint16 DN held in memory and ``exposure``, an
            :class:`Exposure` of it whose header and ``READS`` table are those the
            file would have had, as :func:`read_exposure` would return them.
        """
        out = {"sat_read": run.sat_read, "cr_seen": run.cr_seen}
        ro, t_frame = self.engine.readout, self.engine.detector.frame_time
        try:
            if self._stream is not None:
                self._stream.end_image()
                self._stream.append_hdu(fits.BinTableHDU(ro.read_table(t_frame),
                                                         name="READS"))
            if self.truth_path is not None:
                _write_truth(self.engine, self.truth_path, self.header, out, self._raws,
                             self.sources, self.overwrite)
            self._stack.close()                 # renames the exposure into place
        except BaseException:
            self.abort()
            raise
        finally:
            self._discard_raws()
        if self._sci is not None:
            out["sci"] = self._sci
            out["exposure"] = Exposure(self._sci, _read_back_header(self.header),
                                       _read_back_table(ro.read_table(t_frame), "READS"))
        return out

    def abort(self):
        """Remove every temporary file; existing files are left as they were."""
        self._discard_raws()
        self._stack.__exit__(RuntimeError, RuntimeError("aborted"), None)

    def _discard_raws(self):
        for raw in self._raws.values():
            raw.discard()

    def __enter__(self):
        return self

    def __exit__(self, typ, exc, tb):
        if typ is not None:
            self.abort()
        return False


def _read_back_header(cards):
    """The primary header built from ``cards`` as the file stores and reads it back."""
    buf = io.BytesIO()
    stream = StreamingFITS(buf)
    stream.begin_image((), np.uint8, cards)
    stream.end_image()
    return fits.Header.fromstring(buf.getvalue().decode("ascii"))


def _read_back_table(table, name):
    """``table`` after a trip through a FITS binary table, as :func:`read_exposure`
    reads it from a file (same column types; ``meta`` from the table header)."""
    buf = io.BytesIO()
    fits.HDUList([fits.PrimaryHDU(), fits.BinTableHDU(table, name=name)]).writeto(buf)
    buf.seek(0)
    with fits.open(buf) as hdul:
        return Table.read(hdul[name])


def _write_truth(engine, path, header, out, raws, sources, overwrite):
    det, ro = engine.detector, engine.readout
    rate = engine.expected_rate()
    rate_ipc = engine.measured_rate(rate)
    read_to_res = {k: r for r, reads in enumerate(ro.resultants) for k in reads}
    sat = out["sat_read"]
    lut = np.full(ro.nreads + 1, -1, dtype=np.int16)
    for k, r in read_to_res.items():
        lut[k] = r
    satgroup = np.where(sat >= 0, lut[np.clip(sat, 0, ro.nreads)], -1).astype(np.int16)
    cr = engine.cosmic_rays
    nx = det.nx
    crs = Table({"TIME": cr.time, "X": cr.index % nx, "Y": cr.index // nx,
                 "CHARGE": cr.charge, "SEEN": out["cr_seen"]})
    with atomic_path(path, overwrite=overwrite) as tmp, open(tmp, "wb") as f:
        s = StreamingFITS(f)
        s.begin_image((), np.uint8, list(header) + [("FILETYPE", "truth", "")])
        s.end_image()
        for name, data, unit in (("RATE", rate, "electron/s"),
                                 ("RATE_IPC", rate_ipc, "electron/s")):
            s.begin_image(data.shape, np.float32, [("BUNIT", unit, "")], name=name)
            s.write(data.astype(np.float32))
            s.end_image()
        for name, data in (("SATREAD", sat), ("SATGROUP", satgroup)):
            s.begin_image(data.shape, np.int16, [("BUNIT", "index", "-1: never")],
                          name=name)
            s.write(data)
            s.end_image()
        s.append_hdu(fits.BinTableHDU(crs, name="CRS"))
        src = Table(sources) if sources is not None else Table({"x": [], "y": [],
                                                                "flux": []})
        for col in src.itercols():
            col.unit = None        # units are documented (e-/s, pixels), not stored
        s.append_hdu(fits.BinTableHDU(src, name="SOURCES"))
        shape = (ro.nints, ro.ngroups) + det.shape
        for name, raw in raws.items():
            raw.copy_into(s, shape, name, [("BUNIT", "electron", "")])


def read_exposure(path):
    """Load an exposure: ``(sci uint16 (nints, ngroups, ny, nx), header, reads Table)``."""
    if not os.path.isfile(path):
        raise FileFormatError(f"exposure file {path!r} does not exist")
    with fits.open(path) as hdul:
        names = [h.name for h in hdul]
        for need in ("SCI", "READS"):
            if need not in names:
                raise FileFormatError(
                    f"exposure file {path!r} has no {need!r} extension (found {names})")
        sci = np.asarray(hdul["SCI"].data)
        header = hdul[0].header.copy()
        reads = Table.read(hdul["READS"])
    return sci, header, reads


def read_truth(path):
    """Load a truth file as a dict of arrays/tables keyed by extension name."""
    if not os.path.isfile(path):
        raise FileFormatError(f"truth file {path!r} does not exist")
    out = {}
    with fits.open(path) as hdul:
        out["header"] = hdul[0].header.copy()
        for h in hdul[1:]:
            if isinstance(h, fits.BinTableHDU):
                out[h.name] = Table(h.data)
            else:
                out[h.name] = np.asarray(h.data)
    if "RATE" not in out:
        raise FileFormatError(f"truth file {path!r} has no 'RATE' extension")
    return out
