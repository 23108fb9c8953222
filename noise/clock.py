"""Detector geometry and the one clock that drives everything.

An HxRG is read through ``n_out`` video outputs that clock simultaneously, one pixel
per ``dt`` seconds each (Rauscher 2015, Sec. 4 and Fig. 5).  Per output a frame is
``(ny + nfoh)`` rows of ``(ncols_out + nroh)`` pixel times, where ``nroh`` is the
new-row overhead (pixel times) and ``nfoh`` the new-frame overhead (rows).  The fast
scan direction alternates between outputs (output 0 left to right, output 1 right to
left, ...); ``reverse_scan=True`` flips all of them.  Rows are read from ``y = 0``
upward.

From this follows the read time of every pixel within a frame::

    t(y, x) = (y * (ncols_out + nroh) + x_fast) * dt

where ``x_fast`` is the position of column ``x`` in its output's scan order.  The same
clock places each noise sample in the image (in each output's true time order, the
overhead samples included) and decides when a pixel is read, hence how much charge it
has collected.  For a full-frame H2RG with 4 outputs, ``nroh = 12`` and ``nfoh = 1``::

    t_frame = (512 + 12) * (2048 + 1) * 10 us = 10.73676 s.

Unlike the original NG program, ``dt`` is used everywhere (frequencies, times).

The exposure time line
----------------------
Frames follow each other without gaps.  Each integration is one reset frame slot
followed by its ``nreads`` read slots (reads counted from 0 after the reset), so read
``k`` of integration ``i`` sits in absolute frame slot::

    s = i * (1 + nreads) + 1 + k                       (frame_slot)

and slot ``s`` starts at ``s * t_frame``: pixel ``(y, x)`` of it is read at
``s * t_frame + t(y, x)``.  An exposure of ``nints`` integrations spans
``nints * (1 + nreads)`` slots (:func:`exposure_slots`).  The noise time lines run
through every slot (resets and unused reads included); the charge engine reads the
clock at the same slots.  These two functions are the only place the formula lives.

Subarrays
---------
``window``: a box of ``nx * ny`` pixels read through a single output, so a frame is
``(ny + nfoh) * (nx + nroh) * dt``.  ``stripe``: full-width rows ``y0 .. y0+ny-1`` read
through all outputs, so a frame is ``(ny + nfoh) * (naxis1 / n_out + nroh) * dt``.
Reference pixels of a subarray are those of the full array that fall inside it.

Interleaved reference samples (IRS2) and a reference output
-------------------------------------------------------------------------
NIRSpec's IRS2 mode (Rauscher et al. 2017, PASP 129, 105003; the jwst
pipeline's ``jwst.refpix.irs2_subtract_reference``) makes every output step out to
reference pixels while it reads a row.  :class:`Interleave` describes it: per output
row, ``normal / 2`` normal pixels, then blocks of ``jump`` idle pixel times, ``reference``
reference samples, ``jump`` idle pixel times and ``normal`` normal pixels, the last
block ending after ``normal / 2`` normal pixels.  The interleaved samples take time
slots, so with ``B = ncols_out / normal`` blocks a row is::

    row_samples = ncols_out + B * (reference + 2 * jump) + nroh

pixel times.  NIRSpec (jwst 3.0: ``scipix_n = 16``, ``refpix_r = 4``, one pixel time of
jump overhead either side, ``pad = 8`` of new-row overhead): ``512 + 32 * 6 + 8 = 712``
pixel times per row, 640 samples written per output row (512 normal, 128 reference)
and, with one row of new-frame overhead, ``t_frame = 712 * 2049 * 10 us = 14.58888 s``
(jwst's comment: 14.5889 s).  Normal pixel ``j`` (fast-scan order) of a row is read at
slot ``j + (reference + 2 jump) * floor((j + normal/2) / normal)`` of the row; the
``m``-th interleaved sample at ``m + (normal + 2 jump) * floor(m / reference) + normal/2
+ jump`` (:meth:`Detector.normal_slots`, :meth:`Detector.reference_slots`).

``ref_output = True`` adds a reference output clocked in step with the science
outputs: it writes one sample at every slot where a science output writes one (NIRSpec's
"fifth output"; Roman's amp 33 would be the same).

The *raw* frame is every written sample, in the layout of the jwst pipeline's IRS2
code (detector orientation): the reference output's block first, then one block
per science output, each of ``raw_ncols_out = ncols_out + B * reference`` columns in
column order (a reversed output's block mirrored); the reference output's block is laid
out mirrored with respect to output 0's (jwst flips sections 0, 2 and 4 to bring every
section into time order).  NIRSpec full frame: ``(1 + 4) * 640 = 3200`` columns by 2048
rows.  :meth:`Detector.raw_columns` says what each raw column holds.
"""

import dataclasses
import difflib
from dataclasses import dataclass
from functools import cached_property

import numpy as np

from noise.validate import (check_bool, check_float, check_instance, check_int, check_str,
                            describe)
from noise.errors import FileFormatError, ParameterError, ParameterTypeError

__all__ = ["Subarray", "Interleave", "Detector", "PRESETS", "preset", "detector_from_header",
           "frame_slot", "exposure_slots", "column_runs", "copy_columns"]


def column_runs(dst, src):
    """The column copy ``out[..., dst] = a[..., src]`` as runs of slices.

    Between the image and the raw layout (:meth:`Detector.raw_columns`) columns move
    in a few blocks (one per output, or one per group of normal samples between
    interleaved ones), each in order or mirrored.  Copied as slices these cost a few
    ms per 4096 x 4096 frame; numpy's column gather ``out[:, dst] = a[:, src]`` took
    ~160 ms, on the thread every other one waits for.

    Parameters
    ----------
    dst, src : 1-D sequences of int, same length
        Paired column indices (``dst`` without repeats).

    Returns
    -------
    list of (int, int, int, int)
        ``(d0, s0, n, step)``: ``out[..., d0:d0 + n] = a[..., s0:s0 + n * step:step]``
        with ``step`` +1 or -1; :func:`copy_columns` applies them.
    """
    dst, src = np.asarray(dst, dtype=np.int64), np.asarray(src, dtype=np.int64)
    order = np.argsort(dst, kind="stable")
    dst, src = dst[order].tolist(), src[order].tolist()
    runs, k = [], 0
    while k < len(dst):
        step = 1
        if k + 1 < len(dst) and dst[k + 1] == dst[k] + 1 and src[k + 1] - src[k] == -1:
            step = -1
        e = k + 1
        while e < len(dst) and dst[e] == dst[e - 1] + 1 and src[e] - src[e - 1] == step:
            e += 1
        runs.append((dst[k], src[k], e - k, step))
        k = e
    return runs


def copy_columns(out, a, runs):
    """``out[..., dst] = a[..., src]`` over the runs of :func:`column_runs` (the last
    axis; any leading axes; values cast to ``out``'s dtype).  Returns ``out``."""
    for d0, s0, n, step in runs:
        stop = s0 + n * step
        out[..., d0:d0 + n] = a[..., s0:(stop if stop >= 0 else None):step]
    return out


def frame_slot(integration, read, nreads):
    """Absolute frame slot of read ``read`` (0-based, from reset) of ``integration``.

    ``integration * (1 + nreads) + 1 + read``: each integration is a reset slot and
    ``nreads`` read slots.  Works elementwise on integer arrays.
    """
    return integration * (1 + nreads) + 1 + read


def exposure_slots(nints, nreads):
    """Frame slots spanned by ``nints`` integrations of ``nreads`` reads (resets
    included): ``nints * (1 + nreads)``."""
    return nints * (1 + nreads)


@dataclass(frozen=True)
class Subarray:
    """A readout window on the detector, in full-frame pixel coordinates (0-based).

    Parameters
    ----------
    kind : {'window', 'stripe'}
        ``'window'`` is read through one output; ``'stripe'`` spans the full width and
        is read through all outputs.
    x0, y0 : int
        Lower-left corner (column, row) on the full array.
    nx, ny : int
        Size in columns and rows.  For a stripe ``x0 = 0`` and ``nx = naxis1``.
    name : str
        Free label written to file headers (e.g. ``'SUB64'``).
    """

    kind: str
    x0: int
    y0: int
    nx: int
    ny: int
    name: str = ""

    def __post_init__(self):
        if not isinstance(self.kind, str) or self.kind not in ("window", "stripe"):
            cls = ParameterError if isinstance(self.kind, str) else ParameterTypeError
            raise cls(f"'subarray.kind' must be 'window' or 'stripe', got "
                      f"{describe(self.kind)}")
        for field in ("x0", "y0"):
            check_int(f"subarray.{field}", getattr(self, field), minimum=0)
        for field in ("nx", "ny"):
            check_int(f"subarray.{field}", getattr(self, field), minimum=1)
        check_str("subarray.name", self.name, label=True)


@dataclass(frozen=True)
class Interleave:
    """Interleaved reference sampling (IRS2) of every output row.

    Parameters
    ----------
    normal : int
        Normal pixels read between two excursions to the reference pixels (even,
        >= 2); a row starts and ends with ``normal // 2`` of them.  jwst's
        ``NRS_NORM`` (``scipix_n``), 16 for NIRSpec.
    reference : int
        Reference samples per excursion (even, >= 2: pairs of reads of one reference
        pixel).  jwst's ``NRS_REF`` (``refpix_r``), 4 for NIRSpec.
    jump : int
        Idle pixel times stepping out to the reference pixels, and again stepping
        back (>= 0); 1 for NIRSpec (jwst: the ``+ 2`` of ``scipix_n + refpix_r + 2``).
    """

    normal: int = 16
    reference: int = 4
    jump: int = 1

    def __post_init__(self):
        check_int("interleave.normal", self.normal, minimum=2)
        check_int("interleave.reference", self.reference, minimum=2)
        check_int("interleave.jump", self.jump, minimum=0)
        for field in ("normal", "reference"):
            if getattr(self, field) % 2:
                raise ParameterError(
                    f"'interleave.{field}' must be even, got {getattr(self, field)!r} "
                    f"(a row starts with normal/2 normal pixels; reference samples "
                    f"are pairs of reads)")

    @property
    def period(self):
        """Pixel times from one excursion to the next: ``normal + reference + 2 jump``."""
        return self.normal + self.reference + 2 * self.jump


def _as_interleave(value):
    """``value`` as an :class:`Interleave` (from a mapping or a sequence of up to three
    ints), or None."""
    if value is None or isinstance(value, Interleave):
        return value
    try:
        if isinstance(value, dict):
            unknown = set(value) - {"normal", "reference", "jump"}
            if unknown:
                raise ParameterError(
                    f"'interleave' has unknown keys {sorted(unknown)}; allowed: "
                    f"'normal', 'reference', 'jump'")
            return Interleave(**value)
        if isinstance(value, (list, tuple)) and 1 <= len(value) <= 3:
            return Interleave(*value)
    except TypeError:
        pass
    raise ParameterTypeError(
        f"'interleave' must be a noise.clock.Interleave, a table "
        f"{{normal, reference, jump}}, a list [normal, reference, jump] or none, got "
        f"{describe(value)}")


@dataclass(frozen=True)
class Detector:
    """Frozen description of an HxRG array and how it is clocked.

    Parameters
    ----------
    name : str
        Label, e.g. ``'H2RG'``.
    naxis1, naxis2 : int
        Full-array columns and rows (pixels), reference pixels included.
    n_out : int
        Number of video outputs of the full array; must divide ``naxis1``.
    nroh : int
        New-row overhead, in pixel times (>= 0).
    nfoh : int
        New-frame overhead, in rows (>= 0).
    dt : float
        Pixel dwell time per output, seconds (1e-5 s = 100 kHz).
    ref_border : int
        Width of the reference-pixel border on all four sides (4 for HxRGs, 0 for none).
    reverse_scan : bool
        Reverse every output's fast-scan direction.
    pixel_pitch : float
        Pixel pitch in micrometres (used for cosmic-ray rates per cm^2).
    subarray : Subarray or None
        Readout window; ``None`` for full frame.
    interleave : Interleave or None
        Interleaved reference sampling (IRS2) in every output row (module
        notes); ``None``: traditional clocking.  Also given as a table or list.
    ref_output : bool
        A reference output read in step with the science outputs (module notes).
    """

    name: str = "H2RG"
    naxis1: int = 2048
    naxis2: int = 2048
    n_out: int = 4
    nroh: int = 12
    nfoh: int = 1
    dt: float = 1e-5
    ref_border: int = 4
    reverse_scan: bool = False
    pixel_pitch: float = 18.0
    subarray: Subarray | None = None
    interleave: Interleave | None = None
    ref_output: bool = False

    def __post_init__(self):
        object.__setattr__(self, "interleave", _as_interleave(self.interleave))
        check_bool("ref_output", self.ref_output)
        # stored as Python numbers (a float16 dt made the frame time inf)
        for name, low in (("naxis1", 1), ("naxis2", 1), ("n_out", 1), ("nroh", 0),
                          ("nfoh", 0), ("ref_border", 0)):
            object.__setattr__(self, name, check_int(name, getattr(self, name),
                                                     minimum=low))
        for name in ("dt", "pixel_pitch"):
            object.__setattr__(self, name, check_float(name, getattr(self, name),
                                                       minimum=0.0, strict_min=True))
        check_str("name", self.name, label=True)
        check_bool("reverse_scan", self.reverse_scan)
        check_instance("subarray", self.subarray, Subarray, "a noise.clock.Subarray",
                       allow_none=True)
        if self.naxis1 % self.n_out:
            raise ParameterError(
                f"'n_out'={self.n_out} must divide 'naxis1'={self.naxis1} "
                f"(each output reads the same number of columns)")
        if 2 * self.ref_border >= min(self.naxis1, self.naxis2):
            raise ParameterError(
                f"'ref_border'={self.ref_border} leaves no regular pixels on a "
                f"{self.naxis2}x{self.naxis1} array")
        sub = self.subarray
        if sub is not None:
            if sub.x0 + sub.nx > self.naxis1 or sub.y0 + sub.ny > self.naxis2:
                raise ParameterError(
                    f"'subarray' {sub.kind} x0={sub.x0}, y0={sub.y0}, nx={sub.nx}, "
                    f"ny={sub.ny} extends outside the {self.naxis2}x{self.naxis1} "
                    f"detector (x0+nx <= {self.naxis1} and y0+ny <= {self.naxis2} "
                    f"required)")
            if sub.kind == "stripe" and (sub.x0 != 0 or sub.nx != self.naxis1):
                raise ParameterError(
                    f"a 'stripe' subarray spans the full width: x0=0 and "
                    f"nx={self.naxis1} required, got x0={sub.x0}, nx={sub.nx}")
        extra = self.interleave is not None or self.ref_output
        if extra and sub is not None and sub.kind == "window":
            what = "'interleave'" if self.interleave is not None else "'ref_output'"
            raise ParameterError(
                f"{what} needs every output reading full rows (full frame or a "
                f"'stripe' subarray), got a 'window' subarray {sub.nx}x{sub.ny} read "
                f"through one output")
        il = self.interleave
        if il is not None and (self.naxis1 // self.n_out) % il.normal:
            raise ParameterError(
                f"'interleave.normal'={il.normal} must divide the columns per output, "
                f"'naxis1'/'n_out' = {self.naxis1}/{self.n_out} = "
                f"{self.naxis1 // self.n_out} (a whole number of excursions per row)")

    # ------------------------------------------------------------------ builders
    def window(self, x0, y0, nx, ny, name=""):
        """Return a copy read out as a window of ``nx * ny`` pixels through one output."""
        return dataclasses.replace(self, subarray=Subarray("window", x0, y0, nx, ny, name))

    def stripe(self, y0, ny, name=""):
        """Return a copy read out as a full-width stripe through all outputs."""
        return dataclasses.replace(
            self, subarray=Subarray("stripe", 0, y0, self.naxis1, ny, name))

    def full_frame(self):
        """Return a copy with no subarray."""
        return dataclasses.replace(self, subarray=None)

    # -------------------------------------------------------------- geometry
    @property
    def nx(self):
        """Columns read out (pixels)."""
        return self.naxis1 if self.subarray is None else self.subarray.nx

    @property
    def ny(self):
        """Rows read out (pixels)."""
        return self.naxis2 if self.subarray is None else self.subarray.ny

    @property
    def shape(self):
        """Image shape ``(ny, nx)`` as read out."""
        return (self.ny, self.nx)

    @property
    def x0(self):
        """Full-frame column of the first column read out."""
        return 0 if self.subarray is None else self.subarray.x0

    @property
    def y0(self):
        """Full-frame row of the first row read out."""
        return 0 if self.subarray is None else self.subarray.y0

    @property
    def n_out_active(self):
        """Outputs used by this readout (1 for a window)."""
        if self.subarray is not None and self.subarray.kind == "window":
            return 1
        return self.n_out

    @property
    def ncols_out(self):
        """Columns per active output."""
        return self.nx // self.n_out_active

    @property
    def n_excursions(self):
        """Excursions to the interleaved reference pixels per output row (0 without
        interleave)."""
        il = self.interleave
        return 0 if il is None else self.ncols_out // il.normal

    @property
    def raw_ncols_out(self):
        """Samples written per output row: normal pixels plus interleaved ones."""
        il = self.interleave
        return self.ncols_out + (0 if il is None else self.n_excursions * il.reference)

    @property
    def n_raw_outputs(self):
        """Outputs writing samples: the active science outputs, plus the reference
        output if any."""
        return self.n_out_active + int(self.ref_output)

    @property
    def raw_nx(self):
        """Columns of the raw frame (every written sample; module notes)."""
        return self.n_raw_outputs * self.raw_ncols_out

    @property
    def raw_shape(self):
        """Raw frame shape ``(ny, raw_nx)``."""
        return (self.ny, self.raw_nx)

    @property
    def has_raw_samples(self):
        """True if samples other than the image's pixels are written (interleaved
        reference samples or a reference output)."""
        return self.interleave is not None or self.ref_output

    @property
    def row_samples(self):
        """Pixel times per row per output, overheads (row, and the interleaved
        samples with their jumps) included."""
        il = self.interleave
        if il is None:
            return self.ncols_out + self.nroh
        return (self.ncols_out + self.n_excursions * (il.reference + 2 * il.jump)
                + self.nroh)

    def normal_slots(self):
        """Slot in the row (pixel times from the row's start) of each normal pixel,
        in fast-scan order, shape (ncols_out,), int64."""
        j = np.arange(self.ncols_out)
        il = self.interleave
        if il is None:
            return j
        return j + (il.reference + 2 * il.jump) * ((j + il.normal // 2) // il.normal)

    def reference_slots(self):
        """Slot in the row of each interleaved reference sample, in time order, shape
        (n_excursions * reference,), int64 (empty without interleave)."""
        il = self.interleave
        if il is None:
            return np.zeros(0, dtype=np.int64)
        m = np.arange(self.n_excursions * il.reference)
        return m + (il.normal + 2 * il.jump) * (m // il.reference) + il.normal // 2 + il.jump

    def raw_slots(self):
        """Slots in the row of the samples an output writes, in time order, shape
        (raw_ncols_out,): normal and interleaved together."""
        return np.sort(np.concatenate([self.normal_slots(), self.reference_slots()]))

    def raw_columns(self):
        """What each column of the raw frame holds (module notes).

        Returns
        -------
        output : ndarray (raw_nx,), int
            Science output (0-based), or -1 for the reference output.
        slot : ndarray (raw_nx,), int
            Slot of the sample in its output's row (pixel times from the row start).
        image_x : ndarray (raw_nx,), int
            Image column of a normal pixel; -1 for a reference sample (interleaved
            or reference output).
        """
        rn, ncol = self.raw_ncols_out, self.ncols_out
        slots = self.raw_slots()
        is_normal = np.isin(slots, self.normal_slots())
        # fast-scan index of each normal sample among the normal ones
        fast_normal = np.cumsum(is_normal) - 1
        outs = ([-1] if self.ref_output else []) + list(range(self.n_out_active))
        output, slot, image_x = [], [], []
        for o in outs:
            rev = (not self.output_reversed(0)) if o < 0 else self.output_reversed(o)
            f = np.arange(rn)[::-1] if rev else np.arange(rn)  # fast index per column
            output.append(np.full(rn, o))
            slot.append(slots[f])
            if o < 0:
                image_x.append(np.full(rn, -1))
            else:
                j = fast_normal[f]
                local = (ncol - 1 - j) if self.output_reversed(o) else j
                image_x.append(np.where(is_normal[f], o * ncol + local, -1))
        return np.concatenate(output), np.concatenate(slot), np.concatenate(image_x)

    def raw_sample_index(self):
        """Index of each raw sample in its output's frame time line, shape
        (ny, raw_nx), int64: ``y * row_samples + slot``."""
        _, slot, _ = self.raw_columns()
        return np.arange(self.ny)[:, None] * self.row_samples + slot[None, :]

    @property
    def frame_samples(self):
        """Pixel times per frame per output, overheads included."""
        return (self.ny + self.nfoh) * self.row_samples

    @property
    def row_time(self):
        """Time to clock one row, overhead included (s)."""
        return self.row_samples * self.dt

    @property
    def frame_time(self):
        """Time to clock one frame, overheads included (s)."""
        return self.frame_samples * self.dt

    @property
    def subarray_name(self):
        """``'FULL'`` or the subarray's name (or kind and size)."""
        sub = self.subarray
        if sub is None:
            return "FULL"
        return sub.name or f"{sub.kind.upper()}{sub.ny}x{sub.nx}"

    def output_reversed(self, output):
        """True if ``output`` (0-based, active outputs) scans right to left."""
        return bool((output % 2 == 1) != self.reverse_scan)

    @cached_property
    def _sample_index(self):
        if self.frame_samples >= 2 ** 31:
            raise ParameterError(
                f"a frame of {self.frame_samples} pixel times per output ('naxis2' or "
                f"the subarray's 'ny' + 'nfoh', times the columns per output + 'nroh') "
                f"is beyond the clock's int32 sample index (< 2**31); use more outputs "
                f"('n_out') or a smaller array")
        ncol = self.ncols_out
        col = np.arange(self.nx)
        out = col // ncol
        local = col % ncol
        rev = (out % 2 == 1) != self.reverse_scan
        fast = np.where(rev, ncol - 1 - local, local)
        if self.interleave is not None:            # interleaved samples take slots
            fast = self.normal_slots()[fast]
        # int32 (half the memory of int64 at 4096^2); samples per frame stay < 2**31
        idx = (np.arange(self.ny, dtype=np.int32)[:, None] * np.int32(self.row_samples)
               + fast[None, :].astype(np.int32))
        idx.setflags(write=False)
        return idx

    def pixel_sample_index(self):
        """Index of each pixel's sample in its output's frame time line.

        Returns
        -------
        ndarray, shape (ny, nx), int32 (read-only, cached)
            ``y * row_samples + slot``, ``slot = x_fast`` without interleave
            (:meth:`normal_slots` with it).
        """
        return self._sample_index

    def pixel_time(self):
        """Read time of each pixel from the start of its frame.

        Returns
        -------
        ndarray, shape (ny, nx), float64, seconds
        """
        return self._sample_index * self.dt

    def output_of_column(self):
        """Active output index of each column, shape (nx,), int."""
        return np.arange(self.nx) // self.ncols_out

    def reference_mask(self):
        """True for reference pixels of the read-out image, shape (ny, nx), bool.

        Reference pixels are the ``ref_border``-wide border of the full array.
        """
        b = self.ref_border
        ys = np.arange(self.y0, self.y0 + self.ny)
        xs = np.arange(self.x0, self.x0 + self.nx)
        ry = (ys < b) | (ys >= self.naxis2 - b)
        rx = (xs < b) | (xs >= self.naxis1 - b)
        return ry[:, None] | rx[None, :]

    def to_header_cards(self):
        """``(key, value, comment)`` FITS cards describing the detector and clock."""
        return [
            ("DETECTOR", self.name, "detector type"),
            ("DETNAX1", self.naxis1, "[pix] full-array columns"),
            ("DETNAX2", self.naxis2, "[pix] full-array rows"),
            ("NOUTPUTS", self.n_out_active, "video outputs used"),
            ("NOUTFULL", self.n_out, "video outputs of the full array"),
            ("NROH", self.nroh, "[pix times] new-row overhead"),
            ("NFOH", self.nfoh, "[rows] new-frame overhead"),
            ("PIXDWELL", self.dt, "[s] pixel dwell time per output"),
            ("REFBORD", self.ref_border, "[pix] reference-pixel border width"),
            ("REVSCAN", bool(self.reverse_scan), "fast-scan directions reversed"),
            ("PIXPITCH", self.pixel_pitch, "[um] pixel pitch"),
            ("SUBARRAY", self.subarray_name, "readout window"),
            ("SUBKIND", "full" if self.subarray is None else self.subarray.kind,
             "full, window or stripe"),
            ("SUBSTRT1", self.x0 + 1, "first column (1-based, full frame)"),
            ("SUBSTRT2", self.y0 + 1, "first row (1-based, full frame)"),
            ("SUBSIZE1", self.nx, "[pix] columns read"),
            ("SUBSIZE2", self.ny, "[pix] rows read"),
            ("TFRAME", self.frame_time, "[s] frame time"),
        ] + self._raw_cards()

    def _raw_cards(self):
        """IRS2/reference-output cards, only when the detector has them (so other
        headers are unchanged)."""
        cards = []
        il = self.interleave
        if il is not None:
            cards += [("NRS_NORM", il.normal, "IRS2: normal pixels between excursions"),
                      ("NRS_REF", il.reference, "IRS2: reference samples per excursion"),
                      ("NRS_JUMP", il.jump, "[pix times] IRS2 jump overhead, each way")]
        if self.ref_output:
            cards.append(("REFOUT", True, "reference output read in step"))
        return cards


def detector_from_header(header):
    """Rebuild the :class:`Detector` recorded by :meth:`Detector.to_header_cards`.

    The full-array size is ``DETNAX1``/``DETNAX2``; files written before those names
    (``NAXIS1D``/``NAXIS2D``, which astropy cannot write back: they look like
    ``NAXISn`` cards) are read too.

    Raises
    ------
    noise.errors.FileFormatError
        A detector card is missing, or the cards describe no valid detector.
    """
    def get(*keys):
        for key in keys:
            if key in header:
                return header[key]
        raise KeyError(keys[0])

    try:
        det = Detector(
            name=str(get("DETECTOR")), naxis1=int(get("DETNAX1", "NAXIS1D")),
            naxis2=int(get("DETNAX2", "NAXIS2D")), n_out=int(get("NOUTFULL")),
            nroh=int(get("NROH")), nfoh=int(get("NFOH")),
            dt=float(get("PIXDWELL")), ref_border=int(get("REFBORD")),
            reverse_scan=bool(get("REVSCAN")), pixel_pitch=float(get("PIXPITCH")))
        if "NRS_NORM" in header:
            det = dataclasses.replace(det, interleave=Interleave(
                int(get("NRS_NORM")), int(get("NRS_REF")), int(get("NRS_JUMP"))))
        if header.get("REFOUT", False):
            det = dataclasses.replace(det, ref_output=True)
        kind = str(header.get("SUBKIND", "full"))
        if kind != "full":
            det = dataclasses.replace(det, subarray=Subarray(
                kind, int(get("SUBSTRT1")) - 1, int(get("SUBSTRT2")) - 1,
                int(get("SUBSIZE1")), int(get("SUBSIZE2")), str(get("SUBARRAY"))))
    except KeyError as exc:
        raise FileFormatError(f"header lacks detector keyword {exc.args[0]!r}") from exc
    except (TypeError, ValueError) as exc:          # ParameterError is a ValueError
        raise FileFormatError(
            f"header detector cards describe no valid detector: {exc}") from exc
    return det


#: Detector presets.  Values and their sources:
#:
#: ``H1RG``: 1024x1024, 18 um pixels, 16 outputs at 100 kHz (the H1RG offers 1, 2 or
#: 16 outputs; 16 is the fast mode), JWST-like overheads nroh=12, nfoh=1, 4-pixel
#: reference border (Teledyne HxRG family; Rauscher 2015 Sec. 4).
#: ``H2RG``: 2048x2048, 18 um, 4 outputs at 100 kHz, nroh=12, nfoh=1, border 4: the
#: JWST NIRSpec/NIRCam "traditional" clocking, Rauscher 2015 Table 1 and Fig. 5;
#: frame time 10.73676 s.
#: ``H4RG-10``: 4096x4096, 10 um, 32 outputs at 200 kHz (dt=5 us), nroh=20, nfoh=1,
#: border 4: Roman-WFI-like; the overhead is chosen so the frame time,
#: (128+20)*(4096+1)*5 us = 3.032 s, is close to Roman's 3.04 s frame.
#: ``H4RG-15``: 4096x4096, 15 um, 64 outputs at 100 kHz, nroh=12, nfoh=1, border 4:
#: a ground-based configuration; frame time (64+12)*4097*10 us = 3.114 s.
#: ``NIRCAM``, ``NIRSPEC``: the H2RG clock under the JWST instrument names (JDox,
#: "NIRCam Detector Subarrays": 10 us per pixel, 12 pixel times per row, and a frame
#: of ``((ncols/4 + 12)(nrows + 1) + 1)`` pixel times with 4 outputs, ``(ncols +
#: 12)(nrows + 2)`` with 1).  The full frame is 10.73676 s, one pixel time (10 us)
#: short of JWST's ``+ 1``, which a clock of whole rows cannot add; a 1-output window
#: matches exactly with ``nfoh = 2`` (:func:`scenesim.pipelines.jwst.jwst_frame_time`).
#: ``WFI``: the Roman Wide Field Instrument's H4RG-10 as romancal times it
#: (``romancal.lib.basic_utils``, romancal 1.1): 4096x4096, 10 um, 32 outputs of 128
#: columns with alternating scan directions, ``nroh = 14`` clock cycles between rows
#: (romancal's ``npad``), border 4 (romanisim's ``nborder``), and the frame time
#: romancal and Roman WFI use, 3.04 s (``ROMAN_READ_TIME``; the L1 ``frame_time``).
#: romancal's pixel time is 4.915263 us and the rest of the 3.04 s is spent on
#: guide-window reads, one excursion every 256 rows; a whole-row clock puts that time
#: in ``nfoh = 260`` rows at the end of the frame and takes ``dt = 3.04 s / (4356 x
#: 142)`` = 4.914704 us (114 ppm shorter), so the frame is exactly 3.04 s.  Pixel read
#: times within a frame differ from romancal's by up to the guide-window time
#: (~0.18 s); resultant times, which use only the frame time, agree exactly.  The
#: WFI's 33rd output (amp33) is ``ref_output = True``, left off the preset because a
#: one-output ``window`` cannot have it; ``scenes/roman_wfi.toml`` sets it.
#: ``NIRSPEC-IRS2``: NIRSpec's H2RG in IRS2 mode as the jwst 3.0 pipeline lays it out
#: (``jwst.refpix.irs2_subtract_reference``): 16 normal pixels between excursions of 4
#: reference samples with one pixel time of jump each way, 8 pixel times of new-row
#: overhead (its ``pad``), one row of new-frame overhead and the reference output:
#: 712 pixel times per row, 3200 x 2048 raw samples, t_frame = 14.58888 s.
PRESETS = {
    "H1RG": Detector(name="H1RG", naxis1=1024, naxis2=1024, n_out=16, nroh=12, nfoh=1,
                     dt=1e-5, ref_border=4, pixel_pitch=18.0),
    "H2RG": Detector(name="H2RG", naxis1=2048, naxis2=2048, n_out=4, nroh=12, nfoh=1,
                     dt=1e-5, ref_border=4, pixel_pitch=18.0),
    "H4RG-10": Detector(name="H4RG-10", naxis1=4096, naxis2=4096, n_out=32, nroh=20,
                        nfoh=1, dt=5e-6, ref_border=4, pixel_pitch=10.0),
    "H4RG-15": Detector(name="H4RG-15", naxis1=4096, naxis2=4096, n_out=64, nroh=12,
                        nfoh=1, dt=1e-5, ref_border=4, pixel_pitch=15.0),
    "NIRCAM": Detector(name="NIRCAM", naxis1=2048, naxis2=2048, n_out=4, nroh=12, nfoh=1,
                       dt=1e-5, ref_border=4, pixel_pitch=18.0),
    "NIRSPEC": Detector(name="NIRSPEC", naxis1=2048, naxis2=2048, n_out=4, nroh=12,
                        nfoh=1, dt=1e-5, ref_border=4, pixel_pitch=18.0),
    "NIRSPEC-IRS2": Detector(name="NIRSPEC-IRS2", naxis1=2048, naxis2=2048, n_out=4,
                             nroh=8, nfoh=1, dt=1e-5, ref_border=4, pixel_pitch=18.0,
                             interleave=Interleave(16, 4, 1), ref_output=True),
    "WFI": Detector(name="WFI", naxis1=4096, naxis2=4096, n_out=32, nroh=14, nfoh=260,
                    dt=3.04 / (4356 * 142), ref_border=4, pixel_pitch=10.0),
}


def preset(preset_name, /, **changes):
    """Return the preset detector ``preset_name`` with optional field ``changes``
    (any :class:`Detector` field, ``name`` included).

    Examples
    --------
    >>> preset("H2RG", naxis1=256, naxis2=256).frame_time  # doctest: +SKIP
    """
    key = check_str("preset", preset_name).upper()
    if key not in PRESETS:
        close = difflib.get_close_matches(key, PRESETS, n=1)
        hint = f"; did you mean {close[0]!r}?" if close else ""
        raise ParameterError(
            f"'preset' must be one of {sorted(PRESETS)}, got {preset_name!r}{hint}")
    fields = [f.name for f in dataclasses.fields(Detector)]
    for k in changes:
        if k not in fields:
            close = difflib.get_close_matches(k, fields, n=1)
            hint = f"; did you mean {close[0]!r}?" if close else ""
            raise ParameterError(f"unknown detector field {k!r}: the fields are "
                                 f"{', '.join(fields)}{hint}")
    return dataclasses.replace(PRESETS[key], **changes) if changes else PRESETS[key]
