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
  per-resultant read times that uneven patterns need);
* ``RAWREF`` (only for a detector with interleaved reference samples or a reference
  output, ``noise.clock.Detector.has_raw_samples``, e.g. NIRSpec IRS2): uint16 DN,
  (nints, ngroups, ny, n), those samples in the order of the raw columns that hold
  them (``Detector.raw_columns()``, ``image_x < 0``), so that ``SCI`` and ``RAWREF``
  together are every sample read (:func:`raw_resultants`).

Truth (``<stem>_truth.fits``): ``RATE`` (expected e-/s of collected charge per pixel,
the QE flat included, before IPC; a variable source at its light curve's mean over the
integrations' windows, the spans their slopes measure), ``RATE_IPC`` (after IPC: what
a linear fit of the raw ramps recovers), ``SATREAD`` (first saturated read per pixel
and integration, as a frame index counted from reset, -1 if none: the first read whose
charge reached the full well or whose charge and noise read the ADC's top code; only
reads that some resultant uses are materialised, so a pixel that fills its well during
skipped frames reports the next read that is actually taken; int16, int32 for a
readout of more than 32767 reads), ``SATGROUP`` (first resultant containing it),
``CRS`` (cosmic-ray deposits: time, pixel, charge, whether a read saw it), ``SOURCES``
(the stars as rendered, one row each: the inline stars in the scene's order, then the
catalogue's rows in its order, so catalogue row ``i`` is row ``len(stars) + i``; with a
catalogue, its ``id`` first and its other columns last, null on the inline stars'
rows), ``LCINTS`` (with variable sources, ``SOURCE`` its row of ``SOURCES``: each
one's light-curve mean and collected rate in every integration's window, the truth of
per-integration
slopes where the light curve is flat over the window, and of CDS slopes always:
:func:`_light_curve_table`), ``READS`` (the exposure's table of read indices and
times, so that a truth grades a fit of any readout without its exposure), and
optionally ``CHARGE`` (noise-free signal resultants, e-: the collected charge after
saturation, nonlinearity and IPC, before the noise and the ADC, i.e. ``K(p(min(q,
FW)))``, not the collected charge ``q``) and ``NOISE`` (noise-only resultants, e-).

What this plain writer lacks for the JWST pipeline (so ``calwebb_detector1`` does not
take its files; with the ``jwst`` extra, :func:`scenesim.pipelines.jwst.write_uncal`
writes the uncal file that it does take): ``INSTRUME``, ``EXP_TYPE``, a JWST
``DETECTOR`` name (``DETECTOR`` is the HxRG preset's), ``DATE-OBS``, ``FASTAXIS`` and
``SLOWAXIS``, ``FRMDIVSR``, ``DRPFRMS1`` (it writes ``DROPFRM1``), the ``INT_TIMES``
table, ``GROUPDQ``/``PIXELDQ`` and the ``ASDF`` extension the data models write.

In memory: :class:`Exposure` holds what an exposure file holds (``SCI``, the primary
header and the ``READS`` table, exactly as :func:`read_exposure` returns them from a
file).  ``ExposureWriter(engine, None)`` returns one, so a run that wants slopes but
no ramp file fits the resultants straight from memory
(:func:`scenesim.calib.prepare.prepare_exposure` takes a path or an :class:`Exposure`); its
header and table go through the same FITS serialisation as the file's, so the fit
sees the same values to the last bit.

Every file is written to a temporary file and renamed when complete
(:func:`noise.fitsio.atomic_file`): a name ending in ``.gz`` is gzip-compressed; an
operating-system error while writing (disk full, ``ulimit -f``) removes every
temporary file and raises :class:`noise.errors.OutputError` naming the file.  Derived
names keep the full extension (:func:`derived_path`: ``out.fits.gz`` ->
``out_truth.fits.gz``).  The readers raise :class:`noise.errors.FileFormatError`, one
line naming the file, for anything that is not the file they expect (missing, empty,
truncated, not FITS, or another kind of scenesim file: ``FILETYPE``).
"""

import contextlib
import io
import os
from dataclasses import dataclass

import numpy as np
from astropy.io import fits
from astropy.table import Table

from noise.clock import column_runs, copy_columns
from noise.errors import FileFormatError, ScenesimError
from noise.validate import check_bool, check_writable
from noise.fitsio import (StreamingFITS, WriteBehind, WriterThread, atomic_file,
                          check_output_name, derived_path, input_path, open_fits,
                          output_error, temp_file)

from scenesim.detector.readout import read_index_dtype
from scenesim.io.header import (check_file_kind, exposure_cards, filetype_card,
                                nextend_card)

__all__ = ["Exposure", "ExposureWriter", "truth_path_for", "derived_path",
           "read_exposure", "read_exposure_header", "read_truth", "read_raw_reference",
           "raw_resultants"]

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
    raw_ref : ndarray or None
        The ``RAWREF`` extension (interleaved reference and reference-output
        samples, uint16 DN), or None.
    """

    sci: np.ndarray
    header: fits.Header
    reads: Table
    name: str = "(in memory)"
    raw_ref: np.ndarray | None = None

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
            As :func:`read_exposure`.
        """
        path = input_path(path, "exposure")
        sci, header, reads = read_exposure(path)
        return cls(sci, header, reads, path, read_raw_reference(path))


def truth_path_for(path):
    """``dir/stem_truth.fits`` for exposure ``dir/stem.fits`` (the full extension
    kept: ``stem.fits.gz`` -> ``stem_truth.fits.gz``; :func:`derived_path`)."""
    return derived_path(path, "_truth")


class _RawCube:
    """Big-endian float32 data appended to a temporary file, copied into FITS later.

    The temporary file is :func:`noise.fitsio.temp_file`'s, beside ``target`` (the
    truth file) and tagged with the extension ``name``."""

    def __init__(self, target, name, dtype=">f4"):
        self.target = target
        self.dtype = np.dtype(dtype)
        self.path = temp_file(target, tag=name)
        try:
            self.f = open(self.path, "wb")
        except BaseException:
            with contextlib.suppress(OSError):
                os.unlink(self.path)
            raise

    def write(self, data):
        try:
            if self.dtype.kind == "u":          # FITS: signed integers + BZERO
                data = (np.asarray(data, dtype=np.int32) - 32768).astype(">i2")
            self.f.write(np.asarray(data, dtype=self.dtype if self.dtype.kind != "u"
                                    else ">i2").tobytes())
        except OSError as exc:
            raise output_error(self.target, exc) from exc

    def copy_into(self, stream, shape, name, cards):
        self.f.close()
        stream.begin_image(shape, self.dtype.newbyteorder("="), cards, name=name)
        with open(self.path, "rb") as f:
            stream.copy_raw(f, int(np.prod(shape)) * self.dtype.itemsize)
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
    The exposure's resultants are written by a writer thread while the engine makes
    the next one (one write pending at most; a resultant's ``dn`` array is not changed
    after the engine hands it over): the engine's threads no longer wait while the
    caller's thread writes.

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
        Replace existing files (default: refuse them).
    write_behind : bool
        The exposure is not read again by this process: hand its resultants to the
        disk as they are written and keep them out of the page cache
        (:class:`noise.fitsio.WriteBehind`; fresh page-cache pages cost ~20 ms of
        kernel CPU per 8 MB on the machine of BENCHMARKS.md, taken from the engine's
        threads).  Leave it off when the run reads the file back (a fit, the
        pipeline products): the read would then come from disk into fresh pages.

    Raises
    ------
    noise.errors.ParameterError
        An output path cannot be written (before anything is created).
    noise.errors.OutputError
        From :meth:`add` or :meth:`finish`: a file could not be written (disk full,
        file-size limit); every temporary file is removed.
    """

    def __init__(self, engine, path, *, cards=(), truth_path=None, save_charge=False,
                 save_noise=False, sources=None, overwrite=False, write_behind=False):
        write_behind = check_bool("write_behind", write_behind)
        if path is not None:
            check_writable("output path", path, overwrite=overwrite)
            check_output_name("output path", path)
        if truth_path is not None:
            check_writable("truth path", truth_path, overwrite=overwrite)
            check_output_name("truth path", truth_path)
        self.engine, self.path, self.truth_path = engine, path, truth_path
        self.sources, self.overwrite = sources, overwrite
        det, ro = engine.detector, engine.readout
        self.shape = (ro.nints, ro.ngroups) + det.shape
        self.header = exposure_cards(engine, cards)
        self.save_charge = truth_path is not None and save_charge
        self.save_noise = truth_path is not None and save_noise
        self._stack = contextlib.ExitStack()
        self._stream = None
        self._writer = None                 # the writer thread of the exposure's SCI
        self._behind = None                 # its WriteBehind (write_behind=True)
        self._sci = None
        self._raws = {}
        self._rawref = None
        self._rawref_mem = None
        self.rawref_shape = None
        if det.has_raw_samples:
            _, _, image_x = det.raw_columns()
            self.rawref_shape = (ro.nints, ro.ngroups, det.ny, int((image_x < 0).sum()))
            self.header = [nextend_card(3) if c[0] == "NEXTEND" else c
                           for c in self.header]
        try:
            if path is not None:
                fobj = self._stack.enter_context(
                    atomic_file(path, overwrite=overwrite, buffering=_WRITE_BUFFER))
                with self._writing():
                    self._stream = StreamingFITS(fobj)
                    self._stream.begin_image((), np.uint8, self.header)
                    self._stream.end_image()
                    self._stream.begin_image(self.shape, np.uint16,
                                             [("BUNIT", "DN", "raw counts")], name="SCI")
                self._writer = WriterThread()
                if write_behind:
                    self._behind = WriteBehind(fobj)
                if self.rawref_shape is not None:
                    self._rawref = _RawCube(path, "RAWREF", ">u2")
            else:
                self._sci = np.empty(self.shape, dtype=np.uint16)
                if self.rawref_shape is not None:
                    self._rawref_mem = np.empty(self.rawref_shape, dtype=np.uint16)
            for name, wanted in (("CHARGE", self.save_charge),
                                 ("NOISE", self.save_noise)):
                if wanted:
                    try:
                        self._raws[name] = _RawCube(truth_path, name)
                    except OSError as exc:
                        raise output_error(truth_path, exc) from exc
        except BaseException:
            self.abort()
            raise

    @contextlib.contextmanager
    def _writing(self):
        """An OS error writing the exposure becomes an OutputError naming it."""
        try:
            yield
        except OSError as exc:
            if isinstance(exc, ScenesimError):
                raise
            raise output_error(self.path, exc) from exc

    def _wait_write(self):
        """Wait for the SCI write in progress; its OS error as an OutputError."""
        try:
            self._writer.wait()
        except OSError as exc:
            if isinstance(exc, ScenesimError):
                raise
            raise output_error(self.path, exc) from exc

    def _stop_writer(self):
        """Wait for the writer thread's last write (its error ignored) and end it."""
        if self._writer is not None:
            self._writer.close()

    def add(self, res):
        """Write one :class:`scenesim.engine.Resultant` (they come in file order).

        The exposure's part is written by the writer thread after this returns:
        ``res.dn`` must not be changed until the next :meth:`add` or :meth:`finish`
        (the engine never changes it).  An error of that write is raised by the next
        call.
        """
        if self._stream is not None:
            self._wait_write()
            self._writer.submit(self._write_sci, res.dn)
        else:
            self._sci[res.integration, res.index] = res.dn
        if self._rawref is not None:
            self._rawref.write(res.raw_ref)
        elif self._rawref_mem is not None:
            self._rawref_mem[res.integration, res.index] = res.raw_ref
        if "CHARGE" in self._raws:
            self._raws["CHARGE"].write(res.charge)
        if "NOISE" in self._raws:
            self._raws["NOISE"].write(res.noise)

    def _write_sci(self, dn):
        """One resultant into the SCI cube (in the writer thread)."""
        self._stream.write(dn)
        if self._behind is not None:
            self._behind.written()

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
                self._wait_write()
                self._stop_writer()
                with self._writing():
                    self._stream.end_image()
                    if self._rawref is not None:
                        self._rawref.copy_into(self._stream, self.rawref_shape, "RAWREF",
                                               [("BUNIT", "DN", "raw counts")])
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
                                       _read_back_table(ro.read_table(t_frame), "READS"),
                                       raw_ref=self._rawref_mem)
        return out

    def abort(self):
        """Remove every temporary file; existing files are left as they were."""
        self._stop_writer()
        self._discard_raws()
        self._stack.__exit__(RuntimeError, RuntimeError("aborted"), None)

    def _discard_raws(self):
        for raw in self._raws.values():
            raw.discard()
        if self._rawref is not None:
            self._rawref.discard()

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


def _light_curve_table(engine, sources):
    """The ``LCINTS`` table of the variable sources (None without any): per source
    and integration, the window its slope measures at its brightest pixel (s from
    the exposure's start, :meth:`scenesim.engine.ChargeEngine.source_windows`; each
    pixel's own clock offset shifts its window by under one frame time), the
    relative flux its CDS slopes measure (``LC_MEAN``: the light curve's mean over
    each pixel's window, or with averaged groups each read's charge counted,
    :meth:`scenesim.engine.ChargeEngine._slope_means`; the pixels weighted by their
    rates) and the rate the array collects then (``FLUX``, e-/s: ``flux_on_array``
    times that mean: the expected sum of the source's pixels' CDS slopes).
    That box mean is what a CDS slope, or a shot-noise dominated
    GLS slope, of the integration measures; an OLS or read-noise dominated GLS slope
    weights the window's middle more (a parabola), so where the light curve changes
    within an integration they differ (a step at a quarter of the window: OLS +3.8
    %, a probe's noise-free case).  Where it is flat over the window every fitter
    measures ``FLUX``."""
    if not engine.variable:
        return None
    windows = [engine.source_windows(v) for v in engine.variable]
    means = engine.light_curve_means()
    nint = engine.readout.nints
    src = Table(sources)
    # the i-th variable source is the i-th row with a light curve (star order,
    # scenesim.sky.rates.scene_rates)
    rows = np.flatnonzero(np.asarray(src["light_curve"]) != "") \
        if "light_curve" in src.colnames else np.arange(len(engine.variable))
    on = np.asarray(src["flux_on_array" if "flux_on_array" in src.colnames else "flux"],
                    dtype=float)[rows]
    return Table({"SOURCE": np.repeat(rows, nint),
                  "X": np.repeat(np.asarray(src["x"], dtype=float)[rows], nint),
                  "Y": np.repeat(np.asarray(src["y"], dtype=float)[rows], nint),
                  "INTEGRATION": np.tile(np.arange(nint), rows.size),
                  "T_START": np.concatenate([w[0] for w in windows]),
                  "T_END": np.concatenate([w[1] for w in windows]),
                  "LC_MEAN": means.ravel(), "FLUX": (on[:, None] * means).ravel()})


#: ``SOURCES`` columns whose units are documented, not stored (a catalogue's own
#: columns keep theirs).
_SOURCE_UNITS = ("x", "y", "flux", "flux_on_array", "flux_lost_stamp", "stamp_radius")


def _write_truth(engine, path, header, out, raws, sources, overwrite):
    det, ro = engine.detector, engine.readout
    rate = engine.expected_rate()
    rate_ipc = engine.measured_rate(rate)
    read_to_res = {k: r for r, reads in enumerate(ro.resultants) for k in reads}
    sat = out["sat_read"]
    index = read_index_dtype(ro.nreads)
    lut = np.full(ro.nreads + 1, -1, dtype=index)
    for k, r in read_to_res.items():
        lut[k] = r
    satgroup = np.where(sat >= 0, lut[np.clip(sat, 0, ro.nreads)], -1).astype(index)
    cr = engine.cosmic_rays
    nx = det.nx
    crs = Table({"TIME": cr.time, "X": cr.index % nx, "Y": cr.index // nx,
                 "CHARGE": cr.charge, "SEEN": out["cr_seen"]})
    lcints = _light_curve_table(engine, sources)
    replace = {c[0]: c for c in (filetype_card("truth"),
                                 nextend_card(7 + len(raws) + (lcints is not None)))}
    header = [replace.get(c[0], c) for c in header]
    with atomic_file(path, overwrite=overwrite, buffering=_WRITE_BUFFER) as f:
        s = StreamingFITS(f)
        s.begin_image((), np.uint8, header)
        s.end_image()
        for name, data, unit in (("RATE", rate, "electron/s"),
                                 ("RATE_IPC", rate_ipc, "electron/s")):
            s.begin_image(data.shape, np.float32, [("BUNIT", unit, "")], name=name)
            s.write(data.astype(np.float32))
            s.end_image()
        for name, data in (("SATREAD", sat), ("SATGROUP", satgroup)):
            s.begin_image(data.shape, data.dtype, [("BUNIT", "index", "-1: never")],
                          name=name)
            s.write(data)
            s.end_image()
        s.append_hdu(fits.BinTableHDU(crs, name="CRS"))
        src = Table(sources) if sources is not None else Table({"x": [], "y": [],
                                                                "flux": []})
        for col in src.itercols():
            if col.name in _SOURCE_UNITS:
                col.unit = None    # units are documented (e-/s, pixels), not stored
        s.append_hdu(fits.BinTableHDU(src, name="SOURCES"))
        if lcints is not None:
            s.append_hdu(fits.BinTableHDU(lcints, name="LCINTS"))
        # the read times of every resultant, as the exposure's: a truth graded without
        # its exposure (slopes only, a pipeline's product) needs them for any readout
        # that is not MULTIACCUM (an MA table, explicit resultants)
        s.append_hdu(fits.BinTableHDU(ro.read_table(engine.detector.frame_time),
                                      name="READS"))
        shape = (ro.nints, ro.ngroups) + det.shape
        for name, raw in raws.items():
            raw.copy_into(s, shape, name, [("BUNIT", "electron", "")])


def read_exposure(path):
    """Load an exposure file.

    Parameters
    ----------
    path : str or os.PathLike

    Returns
    -------
    sci : ndarray, shape (nints, ngroups, ny, nx), uint16, DN
    header : astropy.io.fits.Header
        The primary header.
    reads : astropy.table.Table
        The ``READS`` table.

    Raises
    ------
    noise.errors.FileFormatError
        One line naming the file: missing, a directory, empty, truncated, corrupt or
        not FITS, another kind of scenesim file (truth, slopes, noise-only), or no
        4-D ``SCI`` or no ``READS`` extension.
    """
    path = input_path(path, "exposure")
    with open_fits(path, "exposure") as hdul:
        _check_exposure(hdul, path)
        sci = np.asarray(hdul["SCI"].data)
        header = hdul[0].header.copy()
        reads = Table.read(hdul["READS"])
    if sci.dtype.kind == "f" and not np.isfinite(sci).all():
        k, r, y, x = (int(v) for v in np.argwhere(~np.isfinite(sci))[0])
        raise FileFormatError(
            f"{path!r}: SCI holds {sci[k, r, y, x]} at integration {k}, group {r}, "
            f"pixel (y={y}, x={x}); its values must be finite (a saturated or bad "
            f"pixel is a DQ flag, not a value)")
    return sci, header, reads


def read_raw_reference(path):
    """The ``RAWREF`` extension of an exposure file (uint16 DN, (nints, ngroups, ny,
    n)), or None if it has none (a detector without raw samples)."""
    path = input_path(path, "exposure")
    with open_fits(path, "exposure") as hdul:
        if "RAWREF" not in [h.name for h in hdul]:
            return None
        return np.asarray(hdul["RAWREF"].data)


def raw_resultants(exposure, detector):
    """Every sample read, in the raw layout of ``detector``
    (:meth:`noise.clock.Detector.raw_columns`): ``SCI`` and ``RAWREF`` of
    ``exposure`` (an :class:`Exposure`) together, (nints, ngroups, ny, raw_nx) uint16.

    Raises
    ------
    noise.errors.FileFormatError
        The exposure has no ``RAWREF`` or its shape does not fit the detector.
    """
    _, _, image_x = detector.raw_columns()
    extra = np.flatnonzero(image_x < 0)
    normal = np.flatnonzero(image_x >= 0)
    rr = exposure.raw_ref
    if rr is None or rr.shape != exposure.sci.shape[:3] + (extra.size,):
        raise FileFormatError(
            f"exposure {exposure.name!r} has no 'RAWREF' of shape "
            f"{exposure.sci.shape[:3] + (extra.size,)} (the interleaved reference and "
            f"reference-output samples of {detector.name!r}), got "
            f"{None if rr is None else rr.shape}")
    out = np.empty(exposure.sci.shape[:3] + (detector.raw_nx,), dtype=np.uint16)
    copy_columns(out, exposure.sci, column_runs(normal, image_x[normal]))
    copy_columns(out, rr, column_runs(extra, np.arange(extra.size)))
    return out


def read_exposure_header(path):
    """The primary header and ``READS`` table of an exposure file, without its data
    (``SCI`` is neither read nor required: the read times need only these).

    Returns
    -------
    header : astropy.io.fits.Header
    reads : astropy.table.Table

    Raises
    ------
    noise.errors.FileFormatError
        As :func:`read_exposure`.
    """
    path = input_path(path, "exposure")
    with open_fits(path, "exposure") as hdul:
        _check_exposure(hdul, path, sci=False)
        return hdul[0].header.copy(), Table.read(hdul["READS"])


def _check_exposure(hdul, path, *, sci=True):
    """Raise unless ``hdul`` is a complete exposure: a 4-D ``SCI`` image (if ``sci``)
    and a ``READS`` table (the data are not read)."""
    check_file_kind(hdul, path, "exposure")
    names = [h.name for h in hdul]
    for need in ("SCI", "READS") if sci else ("READS",):
        if need not in names:
            raise FileFormatError(
                f"exposure file {path!r} has no {need!r} extension (found {names})")
    if not isinstance(hdul["READS"], fits.BinTableHDU):
        raise FileFormatError(f"exposure file {path!r}: 'READS' is not a table")
    if sci and (not isinstance(hdul["SCI"], (fits.ImageHDU, fits.PrimaryHDU))
                or hdul["SCI"].header.get("NAXIS") != 4):
        raise FileFormatError(
            f"exposure file {path!r}: 'SCI' must be a 4-D image (nints, ngroups, ny, "
            f"nx), got NAXIS={hdul['SCI'].header.get('NAXIS')}")


def read_truth(path):
    """Load a truth file as a dict of arrays/tables keyed by extension name.

    Returns
    -------
    dict
        ``'header'`` (the primary header) and one entry per extension: ndarray for
        images, :class:`astropy.table.Table` for tables.

    Raises
    ------
    noise.errors.FileFormatError
        One line naming the file: missing, a directory, empty, truncated, corrupt or
        not FITS, another kind of scenesim file (exposure, slopes, noise-only), or no
        ``RATE`` image.
    """
    path = input_path(path, "truth file")
    out = {}
    with open_fits(path, "truth file") as hdul:
        check_file_kind(hdul, path, "truth")
        names = [h.name for h in hdul]
        if "RATE" not in names or hdul["RATE"].data is None:
            raise FileFormatError(
                f"truth file {path!r} has no 'RATE' image (found {names})")
        out["header"] = hdul[0].header.copy()
        for h in hdul[1:]:
            if isinstance(h, fits.BinTableHDU):
                out[h.name] = Table(h.data)
            else:
                out[h.name] = np.asarray(h.data)
    return out
