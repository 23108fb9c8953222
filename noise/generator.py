"""Frame-by-frame HxRG noise generator (Rauscher 2015), streamed in bounded memory.

Each read frame is assembled from the components of :mod:`noise.params`, driven by the
clock of :mod:`noise.clock`:

* time-line components (correlated pink, uncorrelated pink, ACN) are sampled once per
  pixel time on each output's time line, overheads included, and placed in the image in
  that output's scan order (so correlated pink appears mirrored on reversed outputs);
* picture-frame noise is a 1/f series sampled once per row (shared by all outputs)
  times the template;
* pedestal is one offset per frame; kTC + bias one reset level per integration; white
  noise one sample per pixel per read (reference pixels scaled by ``ref_ratio``);
* random telegraph noise is a two-state Markov process per RTN pixel, stepped frame
  slot by frame slot from the stationary distribution at slot 0 (one uniform per RTN
  pixel per slot, skipped slots included), so a frame's state does not depend on
  which frames were requested.

The exposure time line (see ``docs/CONVENTIONS.md``): each integration is one reset
frame slot followed by its ``nreads`` read slots; slot ``s`` starts at ``s * t_frame``.
All 1/f series run continuously through every slot, overheads included, but samples
of frames nobody asks for are never synthesised at the fine rate (see
:mod:`noise.pink`).

How a frame is computed (cost)
------------------------------
The random-number floor of a frame (``scenesim.bench.floor_seconds``) is one float32
normal per pixel plus one per kept 1/f sample (about 14 million for a full-frame H2RG
with 4 outputs, 9 of them for the 1/f series).  Beyond the draws, a frame costs the
overlap-save FFTs of the 1/f series (~5 ns per sample) and a few passes over each row
chunk while it is in cache.  The work runs in the worker threads as independent tasks,
in bands of ``Layout.band_rows`` rows with one barrier per band:

* the 1/f lines of band ``k + 1`` (one task per :class:`~noise.pink.PinkSeries`:
  white-noise groups drawn straight into the FFT layout, coarse levels, FFTs,
  written scaled into a band buffer; an ACN pair is written interleaved, so it is one
  full-rate line; the uncorrelated series of up to ``Layout.series_per_task`` outputs,
  and the ACN pairs of half as many, are one object each, so their draws and FFTs are
  batched into larger calls), together with
* the rows of band ``k``, per 64-row white-noise stream: the white noise is drawn
  straight into the output frame and scaled in place by per-row sigma vectors (the
  sigma map has only a few distinct rows), then the per-integration reset level, the
  picture-frame term, the pedestal and, per output, the sum of its lines (made in scan
  order, added once, mirrored for reversed outputs) and the RTN pixels are added.  The
  frame is written once; with ``dn_gain`` the rows are converted to uint16 DN in the
  same task.

The lines of the next frame's first band are made with the rows of this frame's last
band (:meth:`NoiseGenerator.frames`), so the threads have row tasks to fill their gaps
at every barrier; the band buffer sets alternate across frames as within one.

A long run of large frames (``Layout.fork_min_pixels`` pixels in all, 16.8 million by
default: four 2048^2 frames) on two or more threads, in a process running no other
thread, makes its 1/f lines in forked helper processes instead (:class:`_ForkedLines`:
the series groups dealt to up to ``threads`` helpers, each writing its lines band by
band, up to two bands ahead, into shared memory), and the parent assembles the rows
from them on its threads.  In one interpreter, every hand-over of the GIL
between the line and row tasks costs a futex wake-up: 88 H2RG frames written as the
``noise`` benchmark writes them took 4.87-5.47 s (median 4.91) with the helpers
against 5.11-6.25 s (median 5.40) on the thread pool, five alternating pairs on two
cores (BENCHMARKS.md, 2026-11-27).  Same bytes.

Small frames (fewer than ``Layout.pool_min_pixels`` pixels: windows, time series) are made
without the thread pool, ``K`` requested frames at a time (``K * ny * nx <=
batch_pixels``, ``K <= batch_frames``), because there the per-frame Python overhead
(band planning, one :meth:`PinkSeries.plan` per series, a dozen small numpy calls) was
comparable to the arithmetic.  The batch path draws the same streams (white per
``(slot, chunk)``, pedestal per block of slots, kTC per integration and chunk, RTN per
slot) and takes each 1/f series once per group of nearly consecutive slots (one
contiguous range of its time line, the reset slot between integrations included), then
applies the same float32 operations to every pixel in the same order as
:meth:`NoiseGenerator.frame`, vectorised over the ``(K, ny, nx)`` block: its frames are
bit-identical (tested).  The white draws of a batch go through one Box-Muller transform
(:func:`noise.fast.normal.standard_normal_rows`, bit-identical to one call per stream).
With two or more threads, the 1/f lines and reset levels are made ahead by a forked
helper process (:mod:`noise.fast.producer`): threads lost to GIL hand-overs between the many
small calls of the frame assembly and the line synthesis.  Frames are copied out of
the batch buffer one at a time, so ``reuse`` keeps its meaning.

On a detector with one active output, correlated and uncorrelated pink land on the
same pixels through the same clock; their sum is one Gaussian 1/f process of amplitude
``hypot(c_pink, u_pink)`` and is synthesised as one series (the same law for a third
less work).

Interleaved reference samples and the reference output
-------------------------------------------------------
On a detector with :class:`noise.clock.Interleave` (IRS2) the 1/f lines run
through every slot of the longer rows, and each image pixel takes its line sample at
its own slot (:meth:`noise.clock.Detector.normal_slots`), so the interleaved samples
sit in the gaps of the time line that the normal pixels skip.  :meth:`NoiseGenerator.raw_frame`
(and ``frames(..., raw=True)``) also gives those samples, and the reference output's
(``ref_output``), in the raw layout of :meth:`noise.clock.Detector.raw_columns`:

* an interleaved sample of output ``o`` at slot ``t`` gets the correlated pink, the
  uncorrelated pink and the ACN of output ``o`` at ``t`` (the same line samples its
  neighbours in time see), the frame's pedestal, white noise of ``rd_noise[o] *
  ref_ratio`` and a kTC reset level shared by each pair of reads (one reference pixel
  read twice, as jwst's IRS2 code reads them);
* the reference output gets the correlated pink at its slot (the one series every
  output shares), its own uncorrelated pink and ACN (stream keys of an output numbered
  ``n_out_active``, amplitudes the mean of the science outputs'), the pedestal and
  white noise of ``mean(rd_noise) * ref_ratio``; it reads no pixel, so no kTC;
* the constant ``bias_offset`` is added to every sample; the picture-frame and bias
  templates, and RTN, are maps of the image's pixels and are not applied to them.

The image pixels are unchanged by asking for the raw frame (the extra samples draw
from their own streams, ``NOISE_COMPONENTS['raw']``); on detectors without interleave
or reference output every frame is as before.

Randomness: every component, output, chunk and block has its own stream,
``SeedSequence(entropy, spawn_key=prefix + (component, ...))``, so the frames do not
depend on the chunking, on the number of threads, or on which other components are
switched on (a zero amplitude skips a component entirely without shifting any draw;
the one exception is the merged pink of a single-output detector, whose one series
takes the correlated-pink stream whatever the two amplitudes).
"""

import functools
import math
import numbers
import os
import weakref
from concurrent.futures import Executor, ThreadPoolExecutor
from dataclasses import dataclass

import numpy as np

from noise.validate import check_choice, check_float, check_int, describe
from noise.adc import ADC
from noise.clock import Detector, column_runs, copy_columns, frame_slot
from noise.errors import ParameterError, ParameterTypeError
from noise.params import NoiseParams
from noise.pink import PinkSeries
from noise.fast.memory import available_memory
from noise.fast.producer import ForkedProducer, available as producer_available
from noise.streams import (NOISE_COMPONENTS, KeyedStreams, detector_uniform, generator,
                           root_seed)
from noise.fast.normal import standard_normal, standard_normal_rows
from noise.template import template_for

__all__ = ["NoiseGenerator", "Layout"]

_WHITE_ROWS = 64      # rows per white-noise / reset-level stream (fixed: chunk-independent)
_SUB_ROWS = 64        # rows processed at once (one stream chunk; fits in L2 cache;
                      # _small_batch relies on _SUB_ROWS == _WHITE_ROWS)
_NSETS = 2            # band buffer sets (the lines of band k+1 while the rows of k run)
_PED_BLOCK = 1024          # pedestal: slots per stream
_AHEAD = 2                # small frames: batches whose 1/f lines are made ahead
_FORK_MIN_BATCHES = 4     # ... by a forked process, if at least this many batches
_FORK_DEPTH = 3           # large frames: band results per 1/f line helper (2 ahead)

#: Most reads per integration, and integrations, of one :meth:`NoiseGenerator.frames`
#: call: 2**20 (as ``scenesim.detector.readout.MAX_READS``); and most frames in all,
#: 2**22 (48 days of 1 s frames; their order is listed up front).
MAX_FRAMES = 2 ** 20
MAX_FRAMES_TOTAL = 2 ** 22


@dataclass(frozen=True)
class Layout:
    """How a generator cuts its work into pieces.  The frames never depend on it (the
    streams are keyed by what is drawn, not by the pieces): it trades speed only.

    Parameters
    ----------
    pool_min_pixels : int
        Frames of at least this many pixels are made one at a time on the thread
        pool, in bands; smaller ones (windows, time series) in batches.
    band_rows : int
        Rows per band of a large frame (a multiple of 64).
    batch_pixels, batch_frames : int
        Small frames are made ``K`` at a time, ``K * ny * nx <= batch_pixels`` and
        ``K <= batch_frames``.
    series_per_task : int
        The uncorrelated 1/f series of up to this many outputs (ACN: of up to half as
        many outputs, two series each) are synthesised together, one task per band:
        batched draws and FFTs are larger numpy calls, which hold the GIL less and
        cost less per sample (a 32-output H4RG: 8 per task made its 1/f lines 1.2x
        faster on one thread and 1.3x on two than one per task).
    fork_min_pixels : int
        On two or more threads, the 1/f lines of a run of large frames whose frames
        hold at least this many pixels in all are made by forked helper processes
        (:class:`_ForkedLines`), when the process runs a single thread; shorter runs
        (forking costs tens of ms) and processes running other threads make them on
        the thread pool.
    """

    pool_min_pixels: int = 1 << 16
    band_rows: int = 512
    batch_pixels: int = 1 << 17
    batch_frames: int = 64
    series_per_task: int = 8
    fork_min_pixels: int = 1 << 24

    def __post_init__(self):
        for name in ("pool_min_pixels", "batch_pixels", "batch_frames",
                     "series_per_task", "fork_min_pixels"):
            check_int(name, getattr(self, name),
                      minimum=0 if name[0] in "pf" else 1)
        check_int("band_rows", self.band_rows, minimum=_WHITE_ROWS)
        if self.band_rows % _WHITE_ROWS:
            raise ParameterError(f"'band_rows' must be a multiple of {_WHITE_ROWS}, got "
                                 f"{self.band_rows!r}")


def _call(task):
    return task()


def _index_list(name, values, upper):
    """Sorted unique ints in ``[0, upper)`` from ``values``, or a ParameterError."""
    try:
        items = list(values)
    except TypeError as exc:
        raise ParameterError(
            f"{name!r} must be an iterable of integers in [0, {upper - 1}], got "
            f"{values!r}") from exc
    bad = [v for v in items
           if isinstance(v, bool) or not isinstance(v, numbers.Integral)
           or not 0 <= int(v) < upper]
    if bad:
        raise ParameterError(
            f"{name!r} must be integers in [0, {upper - 1}], got {bad[0]!r} "
            f"(in {items!r})")
    if not items:
        raise ParameterError(
            f"{name!r} is empty: no frames would be produced; pass None for all of "
            f"[0, {upper - 1}] or at least one index")
    return sorted({int(v) for v in items})


class NoiseGenerator:
    """Make empty HxRG ramps frame by frame.

    Parameters
    ----------
    detector : Detector, optional
        Geometry and clock (default: full-frame H2RG).
    params : NoiseParams, optional
        Amplitudes (default: the paper's NIRSpec values).
    rng : int, SeedSequence, Generator or None
        Root of every random stream.
    threads : int, optional
        Worker threads (default: all cores).  Results do not depend on it.
    layout : Layout, optional
        How the work is cut into pieces (default :class:`Layout()`).  Results do not
        depend on it.

    Notes
    -----
    On a detector with a single active output (most windows), correlated and
    uncorrelated pink reach the same pixels through the same clock, so only their sum
    is observable; it is one Gaussian 1/f process with amplitude
    ``hypot(c_pink, u_pink)`` (both series use the same filters), and is synthesised
    as one series: the same law at two thirds of the 1/f cost of such a window.
    :meth:`timeline` then offers only 'pink', their sum.

    Examples
    --------
    >>> gen = NoiseGenerator(rng=1)                       # doctest: +SKIP
    >>> for i, k, frame in gen.frames(nreads=5): ...      # doctest: +SKIP
    """

    def __init__(self, detector=None, params=None, *, rng=None, threads=None,
                 layout=None):
        self.layout = layout if layout is not None else Layout()
        if not isinstance(self.layout, Layout):
            raise ParameterTypeError(
                f"'layout' must be a noise.generator.Layout, got {describe(layout)}")
        self.detector = detector if detector is not None else Detector()
        self.params = params if params is not None else NoiseParams()
        if not isinstance(self.detector, Detector):
            raise ParameterTypeError(
                f"'detector' must be a noise.Detector, got {describe(detector)}")
        if not isinstance(self.params, NoiseParams):
            raise ParameterTypeError(
                f"'params' must be a noise.NoiseParams, got {describe(params)}")
        self.entropy, self.key = root_seed(rng)
        # white noise of (slot, row chunk): the chunks of a frame hashed together
        self._white_streams = KeyedStreams(self.entropy,
                                           [self.key + (NOISE_COMPONENTS["white"],)])
        self.threads = check_int("threads", threads, minimum=1) if threads is not None \
            else (os.cpu_count() or 1)
        self._validate()
        self._setup()

    # ------------------------------------------------------------------ setup
    def _validate(self):
        # per-output values, f_min below every Nyquist, ACN's even columns
        self.params.check_detector(self.detector)
        self.params = self.params.for_detector(self.detector)
        self.params.warn_precision(self.detector)

    def _stream(self, *key):
        return generator(self.entropy, self.key + key)

    def _setup(self):
        det, p = self.detector, self.params
        nout = det.n_out_active
        L = det.frame_samples
        kw = dict(f_min=p.f_min, spectrum=p.pink_spectrum, entropy=self.entropy)
        self._L = L
        # the correlated series; the per-output series below keep their own stream
        # keys, whatever group they are synthesised in; PinkSeries.plan makes the tasks
        self._common = None
        u_amps = p.per_output("u_pink", nout) if p.enabled("u_pink") else np.zeros(nout)
        # one active output: correlated and uncorrelated pink land on the same pixels
        # through the same clock, and their sum is one Gaussian 1/f process of
        # amplitude hypot(c_pink, u_pink) (same filters): synthesised as one series
        self._merged = nout == 1 and p.c_pink > 0 and u_amps[0] > 0 \
            and not det.ref_output   # the reference output needs c_pink on its own
        if p.c_pink > 0:
            amp = math.hypot(p.c_pink, u_amps[0]) if self._merged else p.c_pink
            self._common = PinkSeries(1 / det.dt, L, [amp],
                                      seed_keys=[self.key + (NOISE_COMPONENTS["c_pink"],)], **kw)
        # per output: its uncorrelated series' amplitude, and its ACN pair's (two
        # half-rate series, even and odd samples); 0 where off
        self._u_amps = u_amps if p.enabled("u_pink") and not self._merged \
            else np.zeros(nout)
        self._acn_amps = p.per_output("acn", nout) if p.enabled("acn") else np.zeros(nout)
        # the frames' series: the outputs in groups (Layout.series_per_task), each group
        # one PinkSeries whose series keep their own output's keys (same values as one
        # series per output: a series' draws depend only on its key, and the FFTs of a
        # batch are computed row by row)
        self._kw = kw
        per = self.layout.series_per_task
        self._u_groups, self._acn_groups = [], []
        for name, groups, amps, size in (("u_pink", self._u_groups, self._u_amps, per),
                                         ("acn", self._acn_groups, self._acn_amps,
                                          max(1, per // 2))):
            on = [o for o in range(nout) if amps[o] > 0]
            for a in range(0, len(on), size):
                outs = tuple(on[a:a + size])
                groups.append((self._output_series(name, outs), outs))
        self._singles = {}          # (component, output) -> PinkSeries, for timeline
        # the reference output's own series: keys of an output numbered n_out_active
        self._ref_u = self._ref_acn = None
        if det.ref_output:
            if p.enabled("u_pink"):
                self._ref_u = PinkSeries(
                    1 / det.dt, L, [float(np.mean(u_amps))],
                    seed_keys=[self.key + (NOISE_COMPONENTS["u_pink"], nout)], **kw)
            if p.enabled("acn"):
                amp = float(np.mean(p.per_output("acn", nout)))
                self._ref_acn = PinkSeries(
                    0.5 / det.dt, L // 2, [amp, amp],
                    seed_keys=[self.key + (NOISE_COMPONENTS["acn"], nout, 0),
                               self.key + (NOISE_COMPONENTS["acn"], nout, 1)], **kw)
        # interleaved samples: image pixels take their line samples at their own slots
        self._gather = det.normal_slots() if det.interleave is not None else None
        self._pf = None
        self._template = None
        if p.pca0 > 0 or p.bias_amp > 0:
            self._template = template_for(det, p.pca0_file)
        if p.pca0 > 0:
            self._pf = PinkSeries(1 / det.row_time, det.ny + det.nfoh, [p.pca0],
                                  seed_keys=[self.key + (NOISE_COMPONENTS["pca0"],)], **kw)
        # white-noise sigma (e-) per output and reference ratio, stored as runs of rows
        # sharing one sigma row vector (a handful of runs instead of a full map)
        self._sig_runs = []
        if p.enabled("rd_noise"):
            rd = p.per_output("rd_noise", nout)[det.output_of_column()].astype(np.float32)
            ref = det.reference_mask()
            # rows differ only where the reference mask does (the sigma of a pixel is
            # rd of its output, times ref_ratio on reference pixels)
            starts = np.flatnonzero(np.any(ref[1:] != ref[:-1], axis=1)) + 1
            bounds = [0] + starts.tolist() + [det.ny]
            self._sig_runs = [
                (a, b, np.where(ref[a], rd * np.float32(p.ref_ratio), rd).astype(np.float32))
                for a, b in zip(bounds[:-1], bounds[1:])]
        # per-integration reset level: a map if kTC or the bias pattern is on
        self._level_map = p.ktc > 0 or p.bias_amp > 0
        self._chunks = [(c0, min(c0 + _WHITE_ROWS, det.ny))
                        for c0 in range(0, det.ny, _WHITE_ROWS)]
        # random telegraph pixels (flat indices, sorted)
        self._rtn_idx = None
        if p.rtn_fraction > 0 and p.rtn_amp > 0:
            regular = ~det.reference_mask()
            # drawn for the full array and cut: a pixel is a telegraph pixel in a
            # window as in the full frame (a probe: 7 of ~210 in common)
            pick = detector_uniform(self._stream(NOISE_COMPONENTS["rtn"], 0),
                                    det) < p.rtn_fraction
            self._rtn_idx = np.flatnonzero(pick & regular)
            if not self._rtn_idx.size:
                self._rtn_idx = None
            self._rtn_state = None
            self._rtn_slot = None
        self._reset_int = None
        self._reset_level = None
        self._reset_int_raw = None
        self._reset_level_raw = None
        self._lines = None
        self._ahead = None              # (slot, buffer set) of lines made ahead
        self._ped_block = None

    def _line_buffers(self):
        """Band buffers of the 1/f time lines (``_NSETS`` sets) and their image views.

        Returns ``(jobs, sets)``: ``jobs`` lists ``(series, samples per row, samples
        per frame, owners)``, one full-rate line per owner (an output, or None: the
        correlated line, added to every output), the lines of all jobs in that order;
        each of the ``sets`` is ``(outs, views)`` with one destination per job for
        :meth:`PinkSeries.plan` (:meth:`_dest`) and, per output, the ``(rows,
        ncols_out)`` views of the lines that output adds, in scan order (correlated,
        uncorrelated, ACN).
        """
        if self._lines is not None:
            return self._lines
        jobs = self._line_jobs()
        nlines = sum(len(owners) for *_, owners in jobs)
        # one allocation for every buffer (large enough for huge pages: fewer faults)
        store = np.zeros((_NSETS, max(nlines, 1), self._band_line_size()),
                         dtype=np.float32)
        sets = []
        for set_store in store:
            parts, r = [], 0
            for *_, owners in jobs:
                parts.append(set_store[r:r + len(owners)])
                r += len(owners)
            sets.append(self._line_set(jobs, parts))
        self._lines = (jobs, sets)
        return self._lines

    def _line_jobs(self):
        """``(series, samples per row, samples per frame, owners)`` of each group of 1/f
        series that makes full-rate lines (see :meth:`_line_buffers`)."""
        L, rs = self._L, self.detector.row_samples
        jobs = []
        if self._common is not None:
            jobs.append((self._common, rs, L, (None,)))
        jobs += [(series, rs, L, outs) for series, outs in self._u_groups]
        jobs += [(series, rs // 2, L // 2, outs) for series, outs in self._acn_groups]
        return jobs

    def _bands(self):
        """``(first row, end row)`` of each band of a large frame."""
        band, ny = self.layout.band_rows, self.detector.ny
        return [(ra, min(ra + band, ny)) for ra in range(0, ny, band)]

    def _band_line_size(self):
        """Samples of one full-rate line of a band."""
        return min(self.layout.band_rows, self.detector.ny) * self.detector.row_samples

    def _line_set(self, jobs, parts):
        """``(outs, views)`` of one band buffer set whose job ``jobs[j]`` (of
        :meth:`_line_jobs`) writes the lines ``parts[j]`` (one row of
        :meth:`_band_line_size` samples per owner)."""
        det = self.detector
        ncol, rs = det.ncols_out, det.row_samples
        rows = min(self.layout.band_rows, det.ny)
        outs, views = [], [[] for _ in range(det.n_out_active)]
        for (series, per_row, _, owners), lines in zip(jobs, parts):
            outs.append(self._dest(lines, per_row, rows * per_row))
            for o, line in zip(owners, lines):
                view = line.reshape(rows, rs)
                view = view[:, :ncol] if self._gather is None else view
                for out in (range(det.n_out_active) if o is None else [o]):
                    views[out].append(view)
        # each output's lines in scan order: correlated, uncorrelated, ACN (jobs order)
        return outs, views

    def _dest(self, lines, per_row, n):
        """:meth:`PinkSeries.plan`'s destination for ``n`` samples per series in
        ``lines`` (k, >= n full-rate samples): ``(k, n)``, or for ACN pairs (half-rate
        ``per_row``) the ``(k, 2, n)`` even/odd view of each line."""
        if per_row == self.detector.row_samples:
            return lines[:, :n]
        pairs = lines[:, :2 * n].view()
        pairs.shape = (len(lines), n, 2)        # splits the last axis: always a view
        return pairs.transpose(0, 2, 1)

    # ------------------------------------------------------------- components
    @property
    def has_reset_level(self):
        p = self.params
        return p.ktc > 0 or p.bias_amp > 0 or p.bias_offset != 0

    def _level_task(self, lvl, integration, c0, c1):
        p = self.params
        blk = lvl[c0:c1]
        if p.ktc > 0:
            standard_normal(self._stream(NOISE_COMPONENTS["ktc"], integration, c0 // _WHITE_ROWS),
                            blk)
            blk *= np.float32(p.ktc)
        else:
            blk.fill(0.0)
        if p.bias_amp > 0:
            blk += np.float32(p.bias_amp) * self._template[c0:c1]
        if p.bias_offset != 0:
            blk += np.float32(p.bias_offset)

    def _make_reset_level(self, integration, pool):
        lvl = np.empty(self.detector.shape, dtype=np.float32)
        self._run(pool, [functools.partial(self._level_task, lvl, integration, c0, c1)
                         for c0, c1 in self._chunks])
        return lvl

    def reset_level(self, integration):
        """kTC + bias reset level of ``integration``, shape (ny, nx), float32, e-."""
        lvl = self._make_reset_level(integration, None)
        return lvl

    def pedestal(self, slot):
        """Pedestal offset of frame slot ``slot`` (e-).

        The offsets of slots ``[b P, (b + 1) P)`` (``P = _PED_BLOCK``) are ``P``
        float64 standard normals from the stream ``(pedestal, b)``, times the sigma: one
        stream per block of slots rather than per slot (a stream costs ~12 us to set
        up, a draw 0.01 us); the last block is kept.
        """
        if self.params.pedestal <= 0:
            return 0.0
        b = slot // _PED_BLOCK
        if self._ped_block is None or self._ped_block[0] != b:
            z = self._stream(NOISE_COMPONENTS["pedestal"], b).standard_normal(_PED_BLOCK)
            self._ped_block = (b, self.params.pedestal * z)
        return float(self._ped_block[1][slot % _PED_BLOCK])

    def timeline(self, component, output, start, n):
        """Raw time-line samples of a 1/f component, e-, float32.

        Parameters
        ----------
        component : {'c_pink', 'u_pink', 'pink', 'acn', 'pca0'}
            'pink' is the sum of the correlated and uncorrelated pink of ``output``.
            On a detector with one active output, with both on, only 'pink' exists:
            the two are synthesised as one series (see :meth:`__init__` notes).
        output : int
            Output index (ignored for 'c_pink' and 'pca0').
        start, n : int
            Absolute sample range on that series' own time line (pixel rate; half rate
            for each ACN parity, which returns shape (2, n); row rate for 'pca0').

        Raises
        ------
        noise.errors.ParameterError
            An unknown or disabled component, an output out of range, a negative or
            non-integer ``start`` or ``n``.
        """
        component = check_choice("component", component,
                                 ("c_pink", "u_pink", "pink", "acn", "pca0"))
        if component in ("u_pink", "pink", "acn"):          # (the others ignore it)
            output = check_int("output", output, minimum=0,
                               maximum=self.detector.n_out_active - 1)
        start = check_int("start", start, minimum=0)
        n = check_int("n", n, minimum=0)
        u_pink = self._single("u_pink", output)
        if component == "pink" and (self._common is not None or u_pink is not None):
            if self._merged:
                return self._common.get(start, n)[0]
            parts = [s.get(start, n)[0] for s in (self._common, u_pink) if s is not None]
            return parts[0] if len(parts) == 1 else parts[0] + parts[1]
        if self._merged and component in ("c_pink", "u_pink"):
            raise ParameterError(
                f"'component' {component!r}: with one active output, c_pink and u_pink "
                f"are synthesised as one series; ask for 'pink' (their sum)")
        if component == "c_pink" and self._common is not None:
            return self._common.get(start, n)[0]
        if component == "u_pink" and u_pink is not None:
            return u_pink.get(start, n)[0]
        acn = self._single("acn", output) if component == "acn" else None
        if acn is not None:
            return acn.get(start, n)
        if component == "pca0" and self._pf is not None:
            return self._pf.get(start, n)[0]
        raise ParameterError(
            f"'component' {component!r} (output {output}) is not enabled; enabled 1/f "
            f"components are those with amplitude > 0 among c_pink, u_pink, pink, acn, "
            f"pca0")

    def _single(self, component, output):
        """The 'u_pink' series or the 'acn' pair of ``output`` alone (None if off or
        no such output): the same keys, hence the same values, as its group's rows in
        the frames; kept for :meth:`timeline`, which then computes only that output."""
        amps = self._u_amps if component == "u_pink" else self._acn_amps
        if not (isinstance(output, numbers.Integral) and 0 <= output < len(amps)) \
                or not amps[output] > 0:
            return None
        if (component, output) not in self._singles:
            self._singles[component, output] = self._output_series(component, (output,))
        return self._singles[component, output]

    def _output_series(self, component, outs):
        """One PinkSeries of the 'u_pink' series (or the 'acn' pairs: even, odd) of
        the outputs ``outs``, in that order, each with its own output's keys."""
        det, key = self.detector, NOISE_COMPONENTS[component]
        if component == "u_pink":
            return PinkSeries(1 / det.dt, self._L, [self._u_amps[o] for o in outs],
                              seed_keys=[self.key + (key, o) for o in outs], **self._kw)
        return PinkSeries(0.5 / det.dt, self._L // 2,
                          [self._acn_amps[o] for o in outs for _ in (0, 1)],
                          seed_keys=[self.key + (key, o, parity)
                                     for o in outs for parity in (0, 1)], **self._kw)

    # ------------------------------------------------------------- raw samples
    @functools.cached_property
    def _raw_layout(self):
        """``(extra, normal, image_x, per_output)``: raw columns that are not image
        pixels and those that are (with their image columns), and per output
        (-1: the reference output) the extra columns' positions and slots."""
        det = self.detector
        output, slot, image_x = det.raw_columns()
        extra = np.flatnonzero(image_x < 0)
        normal = np.flatnonzero(image_x >= 0)
        per_output = []
        for o in np.unique(output[extra]).tolist():
            pos = np.flatnonzero(output[extra] == o)
            per_output.append((o, pos, slot[extra[pos]]))
        return extra, normal, image_x[normal], per_output

    @functools.cached_property
    def _raw_runs(self):
        """Column runs (:func:`noise.clock.column_runs`) placing the image's columns and the
        extra samples' columns in the raw frame."""
        extra, normal, image_x, _ = self._raw_layout
        return (column_runs(normal, image_x),
                column_runs(extra, np.arange(extra.size)))

    def _frame_line(self, parts, start=None):
        """The sum of the time lines ``parts`` of one frame slot, (ny + nfoh,
        row_samples) float32, added in turn to a copy of ``start`` (a flat line of the
        slot) or to zeros; a part is a full-rate line or an ACN pair (2, L / 2), even
        and odd samples."""
        det = self.detector
        line = np.zeros(self._L, dtype=np.float32) if start is None else start.copy()
        for part in parts:
            if part.ndim == 2:                           # ACN: even, odd samples
                line[0::2] += part[0]
                line[1::2] += part[1]
            else:
                line += part
        return line.reshape(det.ny + det.nfoh, det.row_samples)

    def _slot_lines(self, slot, wanted):
        """Per output of ``wanted`` (-1: the reference output), the list of its own
        1/f lines over frame slot ``slot`` (uncorrelated, then the ACN pair); a group
        is computed once, and only if it holds a wanted output."""
        L = self._L
        lines = {o: [] for o in wanted}
        for groups, n, pair in ((self._u_groups, L, False),
                                (self._acn_groups, L // 2, True)):
            for series, outs in groups:
                if wanted.isdisjoint(outs):
                    continue
                y = series.get(slot * n, n)
                for i, o in enumerate(outs):
                    if o in wanted:
                        lines[o].append(y[2 * i:2 * i + 2] if pair else y[i])
        if -1 in wanted and self._ref_u is not None:
            lines[-1].append(self._ref_u.get(slot * L, L)[0])
        if -1 in wanted and self._ref_acn is not None:
            lines[-1].append(self._ref_acn.get(slot * (L // 2), L // 2))
        return lines

    def extra_samples(self, slot, integration):
        """Noise of the raw samples that are not image pixels (interleaved reference
        samples and the reference output; module notes), frame slot ``slot`` of
        ``integration``: shape (ny, n), float32, e-, in the order of the raw columns
        that hold them (:meth:`noise.clock.Detector.raw_columns`, ``image_x < 0``)."""
        det, p = self.detector, self.params
        extra, _, _, per_output = self._raw_layout
        ny = det.ny
        out = np.zeros((ny, extra.size), dtype=np.float32)
        if p.enabled("rd_noise"):
            rd = p.per_output("rd_noise", det.n_out_active)
            sigma = np.empty(extra.size, dtype=np.float32)
            for o, pos, _ in per_output:
                sigma[pos] = (np.mean(rd) if o < 0 else rd[o]) * p.ref_ratio
            standard_normal(self._stream(NOISE_COMPONENTS["raw"], 0, slot), out)
            out *= sigma
        if p.ktc > 0 and det.interleave is not None:
            if self._reset_int_raw != integration:
                # one level per reference pixel: each pair of reads shares it
                npair = (extra.size + 1) // 2
                z = self._stream(NOISE_COMPONENTS["raw"], 1, integration) \
                    .standard_normal((ny, npair), dtype=np.float32)
                lvl = np.zeros((ny, extra.size), dtype=np.float32)
                for o, pos, slots in per_output:
                    if o < 0:
                        continue
                    order = np.argsort(slots)       # time order within the row
                    pair = np.empty(pos.size, dtype=np.int64)
                    pair[order] = np.arange(pos.size) // 2
                    lvl[:, pos] = np.float32(p.ktc) * z[:, pos[0] // 2 + pair]
                self._reset_level_raw = lvl
                self._reset_int_raw = integration
            out += self._reset_level_raw
        scalar = np.float32(self.pedestal(slot) + p.bias_offset)
        if scalar:
            out += scalar
        # the correlated line is shared by every output: made once, then each
        # output's lines are added to it in the order the image's pixels get them
        common = self._frame_line([self._common.get(slot * self._L, self._L)[0]]) \
            .reshape(-1) if self._common is not None else None
        own = self._slot_lines(slot, {o for o, *_ in per_output})
        for o, pos, slots in per_output:
            if common is None and not own[o]:
                continue
            line = self._frame_line(own[o], start=common)
            out[:, pos] += line[:ny][:, slots]
        return out

    def raw_frame(self, slot, integration, image=None):
        """Every sample written in frame slot ``slot`` of ``integration``, in the raw
        layout (:meth:`noise.clock.Detector.raw_columns`), shape ``raw_shape``,
        float32, e-: the image pixels (``image``, the float32 e- frame of
        :meth:`frame` of that slot; made if None) and :meth:`extra_samples`."""
        det = self.detector
        if image is None:
            image = self.frame(slot, integration)
        image_runs, extra_runs = self._raw_runs
        raw = np.empty(det.raw_shape, dtype=np.float32)
        copy_columns(raw, image, image_runs)
        copy_columns(raw, self.extra_samples(slot, integration), extra_runs)
        return raw

    def _advance_rtn(self, slot):
        """Set the random-telegraph state to that of absolute frame slot ``slot``.

        The state is a function of the slot alone, whatever frames were asked for
        before: slot 0 draws from the stationary distribution, and every later slot
        takes one frame's Markov step from the one before with its own uniforms
        (stream ``(rtn, 2, slot)``).  Slots nobody asks for are stepped through (a
        uniform per telegraph pixel each); a request earlier than the last one
        starts again from slot 0.
        """
        p, det = self.params, self.detector
        n = self._rtn_idx.size
        if self._rtn_slot is not None and self._rtn_slot == slot:
            return
        if self._rtn_slot is None or slot < self._rtn_slot:
            self._rtn_state, self._rtn_slot = None, -1
        p_high = p.rtn_tau_high / (p.rtn_tau_low + p.rtn_tau_high)
        decay = math.exp(-det.frame_time * (1 / p.rtn_tau_low + 1 / p.rtn_tau_high))
        # P(high at the next slot | high now) and (| low now), over one frame
        stay_high, turn_high = p_high + (1 - p_high) * decay, p_high * (1 - decay)
        for s in range(self._rtn_slot + 1, slot + 1):
            z = self._stream(NOISE_COMPONENTS["rtn"], 2, s).random(n)
            if self._rtn_state is None:
                self._rtn_state = z < p_high
            else:
                self._rtn_state = z < np.where(self._rtn_state, stay_high, turn_high)
        self._rtn_slot = slot

    # ---------------------------------------------------------------- frames
    @staticmethod
    def _run(pool, tasks):
        """Run independent tasks, on ``pool`` if given (results do not depend on it)."""
        if pool is None or len(tasks) < 2:
            for task in tasks:
                task()
        else:
            list(pool.map(_call, tasks))

    def _rows_task(self, out, rng, c0, c1, scalar, pf, views, r_base, adc):
        """Rows ``c0:c1`` of a frame: white noise, reset level, offsets, time lines, RTN.

        ``rng`` is the white noise's stream of these rows (key ``(white, slot,
        c0 // _WHITE_ROWS)``; None without white noise).  ``views`` place the 1/f lines
        of the band starting at row ``r_base``.  ``out`` is the float32 frame (e-), or,
        with an ``adc`` (:class:`noise.adc.ADC`), the uint16 DN frame (the float32 rows
        are then made in a scratch buffer and digitised by it).
        """
        det, p = self.detector, self.params
        ncol, nx = det.ncols_out, det.nx
        level = self._reset_level if self._level_map else None
        tmp_buf = np.empty((_SUB_ROWS, ncol), dtype=np.float32)
        if pf is not None:
            pf_buf = np.empty((_SUB_ROWS, nx), dtype=np.float32)
        if adc is not None:
            scratch = np.empty((_SUB_ROWS, nx), dtype=np.float32)
            dn = np.empty((_SUB_ROWS, nx), dtype=np.float64)
        for a in range(c0, c1, _SUB_ROWS):
            b = min(a + _SUB_ROWS, c1)
            blk = out[a:b] if adc is None else scratch[:b - a]
            if rng is not None:
                standard_normal(rng, blk)
                for r0, r1, vec in self._sig_runs:
                    lo, hi = max(r0, a), min(r1, b)
                    if lo < hi:
                        np.multiply(blk[lo - a:hi - a], vec, out=blk[lo - a:hi - a])
                if level is not None:
                    blk += level[a:b]
            elif level is not None:
                np.copyto(blk, level[a:b])
            else:
                blk.fill(0.0)
            if pf is not None:
                blk += np.multiply(self._template[a:b], pf[a:b, None], out=pf_buf[:b - a])
            if scalar:
                blk += scalar
            for o, out_views in enumerate(views):
                if not out_views:
                    continue
                lines = [view[a - r_base:b - r_base] for view in out_views]
                if self._gather is not None:      # the normal pixels' slots only
                    lines = [line[:, self._gather] for line in lines]
                if len(lines) > 1:            # sum the lines in scan order, then add once
                    tmp = np.add(lines[0], lines[1], out=tmp_buf[:b - a])
                    for line in lines[2:]:
                        np.add(tmp, line, out=tmp)
                else:
                    tmp = lines[0]
                sec = blk[:, o * ncol:(o + 1) * ncol]
                np.add(sec, tmp[:, ::-1] if det.output_reversed(o) else tmp, out=sec)
            if self._rtn_idx is not None:
                lo, hi = np.searchsorted(self._rtn_idx, (a * nx, b * nx))
                if lo < hi:
                    blk.ravel()[self._rtn_idx[lo:hi] - a * nx] += \
                        np.float32(p.rtn_amp) * self._rtn_state[lo:hi]
            if adc is not None:
                adc.to_dn(blk, out=out[a:b], scratch=dn[:b - a])

    def frame(self, slot, integration, pool=None, *, dn_gain=None, out=None):
        """Noise frame of absolute frame slot ``slot`` in ``integration``.

        The frame is made in bands of rows: the rows of band ``k`` are assembled while
        the 1/f lines of band ``k + 1`` are made (two sets of band buffers alternate),
        one barrier per band.

        Parameters
        ----------
        slot : int
            Absolute frame slot on the exposure time line (see ``docs/CONVENTIONS.md``).
        integration : int
            Integration the slot belongs to (selects the reset level).
        pool : concurrent.futures.Executor, optional
            Worker threads; the frame does not depend on it.
        dn_gain : float, optional, keyword-only
            If given (e-/DN, > 0), return the frame in uint16 DN, digitised by
            :class:`noise.adc.ADC` (16 bits) in the worker threads.
        out : ndarray, optional, keyword-only
            C-contiguous array of shape (ny, nx) and the returned dtype to write the
            frame into (saves allocating, and the kernel zeroing, a fresh frame).

        Returns
        -------
        ndarray, shape (ny, nx)
            float32 e-, or uint16 DN with ``dn_gain``.

        Raises
        ------
        noise.errors.ParameterError
            A negative or non-integer ``slot`` or ``integration``, a ``pool`` that is
            not an Executor, ``dn_gain`` not > 0, or an ``out`` that is not a writable
            C-contiguous array of the frame's shape and dtype.
        """
        slot = check_int("slot", slot, minimum=0)
        integration = check_int("integration", integration, minimum=0)
        if pool is not None and not isinstance(pool, Executor):
            raise ParameterTypeError(f"'pool' must be a concurrent.futures.Executor or "
                                     f"None, got {describe(pool)}")
        if dn_gain is not None:
            dn_gain = check_float("dn_gain", dn_gain, minimum=0.0, strict_min=True)
        if out is not None and not (isinstance(out, np.ndarray) and out.flags.writeable):
            raise ParameterTypeError(f"'out' must be a writable numpy array or None, got "
                                     f"{describe(out)}")
        return self._frame(slot, integration, pool, dn_gain, out, None)

    def _frame(self, slot, integration, pool, dn_gain, out, next_slot):
        """:meth:`frame`; with ``next_slot``, the 1/f lines of that slot's first band
        are made too, with this frame's last rows (they fill the threads' gaps at the
        frame's last barrier; the next frame then starts at its second band)."""
        img, bands, rows = self._frame_start(slot, integration, pool, dn_gain, out)
        jobs, sets = self._line_buffers()

        # band k's lines go to buffer set (first + k) % _NSETS: consecutive bands, in
        # this frame and across frames, alternate (the next frame's first band is
        # made while this frame's last band is assembled)
        ahead = self._ahead
        first = ahead[1] if ahead is not None and ahead[0] == slot else 0

        def lines(k, slot=slot, first=first):
            """Tasks making the 1/f lines of band ``k`` (ACN pairs, the largest, first)."""
            ra, rb = bands[k]
            tasks = []
            for (series, per_row, nfr, _), out in zip(jobs, sets[(first + k) % _NSETS][0]):
                n = (rb - ra) * per_row
                task = series.plan(slot * nfr + ra * per_row, n, out[..., :n])
                tasks.append((-series.nseries, len(tasks), task))
            return [task for *_, task in sorted(tasks)]

        # the rows of band k are assembled while the lines of band k + 1 are made (the
        # larger line tasks first, so the row chunks fill the gaps)
        self._ahead = made = None
        if ahead is None or ahead[0] != slot:
            self._run(pool, lines(0))
        for k in range(len(bands)):
            if k + 1 < len(bands):
                extra = lines(k + 1)
            elif next_slot is not None:          # the next frame's first band
                made = (next_slot, (first + k + 1) % _NSETS)
                extra = lines(0, *made)
            else:
                extra = []
            self._run(pool, extra + rows(k, sets[(first + k) % _NSETS][1]))
        self._ahead = made                       # only once its tasks have all run
        return img

    def _frame_forked(self, slot, integration, pool, dn_gain, out, forked, n):
        """:meth:`frame` of the ``n``-th frame of a run whose 1/f lines are made by
        ``forked`` (:class:`_ForkedLines`): each band's rows are assembled from the
        helpers' lines, on ``pool``."""
        img, bands, rows = self._frame_start(slot, integration, pool, dn_gain, out)
        for k in range(len(bands)):
            j = n * len(bands) + k
            views = forked.get(j)
            self._run(pool, rows(k, views))
            forked.release(j)
        return img

    def _frame_start(self, slot, integration, pool, dn_gain, out):
        """What every band of frame ``slot`` shares: the frame array, its bands and
        ``rows(k, views)``, the row tasks of band ``k`` given the band's 1/f line
        views (see :meth:`_line_set`)."""
        det, p = self.detector, self.params
        if self._level_map and self._reset_int != integration:
            self._reset_level = self._make_reset_level(integration, pool)
            self._reset_int = integration
        scalar = np.float32(self.pedestal(slot)
                            + (0.0 if self._level_map else p.bias_offset))
        pf = None
        if self._pf is not None:
            pf = self._pf.get(slot * (det.ny + det.nfoh), det.ny)[0]
        if self._rtn_idx is not None:
            self._advance_rtn(slot)
        bands = self._bands()
        dtype = np.float32 if dn_gain is None else np.uint16
        if out is not None and (out.shape != det.shape or out.dtype != dtype
                                or not out.flags.c_contiguous):
            raise ParameterError(f"'out' must be a C-contiguous {np.dtype(dtype).name} "
                                 f"array of shape {det.shape}, got {out.dtype} "
                                 f"{out.shape}")
        img = np.empty(det.shape, dtype=dtype) if out is None else out
        adc = None if dn_gain is None else ADC(dn_gain)

        rngs = (self._white_streams.generators(slot, np.arange(-(-det.ny // _WHITE_ROWS)))
                if self._sig_runs else None)

        def rows(k, views):
            ra, rb = bands[k]
            return [functools.partial(self._rows_task, img,
                                      rngs[c0 // _WHITE_ROWS] if rngs else None, c0,
                                      min(c0 + _WHITE_ROWS, rb), scalar, pf, views, ra,
                                      adc)
                    for c0 in range(ra, rb, _WHITE_ROWS)]

        return img, bands, rows

    def frames(self, nreads, reads=None, *, nints=1, integrations=None, dn_gain=None,
               reuse=False, raw=False):
        """Iterate over ``(integration, read, frame)`` of the requested reads in time order.

        Every argument is checked when this is called, before any frame is made.

        Parameters
        ----------
        nreads : int
            Read frames per integration (the time line has ``1 + nreads`` slots each),
            >= 1.
        reads : iterable of int, optional
            Read indices (0-based, from reset) to materialise, each in
            ``[0, nreads - 1]``; default all.  Others are skipped (no white draws; 1/f
            series still run through them).
        nints : int
            Integrations, >= 1.
        integrations : iterable of int, optional
            Subset of integrations to produce, each in ``[0, nints - 1]`` (default all).
        dn_gain : float, optional
            Gain in e-/DN (> 0).  If given, frames are uint16 DN, exactly
            ``noise.adc.to_dn(frame, dn_gain)`` of the float32 e- frames, but
            converted in the worker threads while the rows are in cache.  Like
            ``to_dn`` it clips at codes 0 and 65535 without a check of the range
            (:func:`noise.write_noise_fits` and scenes refuse a gain and bias that
            clip the model's noise: :meth:`noise.params.NoiseParams.check_adc`).
        reuse : int or bool, keyword-only
            If ``n >= 1`` (True: 1), frames are written into ``n`` arrays in turn, so a
            yielded frame is overwritten ``n`` frames later: for consumers that are done
            with a frame by then (the charge engine: 1; the FITS writer, which writes
            one frame while the next is made: 2).  Saves a fresh frame per read (and
            the kernel's zeroing of its pages).  Default 0: a new array per read.
        raw : bool or 'split', keyword-only
            True: yield raw frames (:meth:`raw_frame`, shape ``detector.raw_shape``):
            the image pixels and the interleaved reference and reference-output
            samples; a new array per read (``reuse`` then applies to the image
            frames made inside).  ``'split'``: yield the raw frame's two parts as
            ``(image, extra)`` instead, the image frame (ny, nx) and
            :meth:`extra_samples` (ny, n_extra) in the order of the raw columns
            that hold them, without assembling the raw layout (the charge engine
            adds charge to the image and digitises both).  Only for detectors that
            write such samples.

        Returns
        -------
        iterator of (int, int, ndarray (ny, nx))
            float32 e-, or uint16 DN with ``dn_gain``.
        """
        nreads = check_int("nreads", nreads, minimum=1, maximum=MAX_FRAMES)
        nints = check_int("nints", nints, minimum=1, maximum=MAX_FRAMES)
        if nreads * nints > MAX_FRAMES_TOTAL:
            raise ParameterError(
                f"'nreads' x 'nints' = {nreads} x {nints} frames: at most "
                f"{MAX_FRAMES_TOTAL} frames per call (their order is listed up front)")
        reads = list(range(nreads)) if reads is None else _index_list("reads", reads,
                                                                      nreads)
        ints = list(range(nints)) if integrations is None else \
            _index_list("integrations", integrations, nints)
        if dn_gain is not None:
            dn_gain = check_float("dn_gain", dn_gain, minimum=0.0, strict_min=True)
        nbuf = int(reuse) if isinstance(reuse, bool) else check_int("reuse", reuse,
                                                                      minimum=0)
        if not isinstance(raw, bool) and raw != "split":
            raise ParameterTypeError(f"'raw' must be True, False or 'split', got "
                                     f"{describe(raw)}")
        if raw and not self.detector.has_raw_samples:
            raise ParameterError(
                f"'raw'=True: detector {self.detector.name!r} writes no samples "
                f"besides its image pixels (no 'interleave', no 'ref_output')")
        # the helpers are forked now, before the caller starts any thread; not for
        # interleaved raw samples, which read every output's series of the slot again
        # (the reference output has its own series: only the correlated one is read
        # again, a line per frame)
        forked = None
        if not raw or self.detector.interleave is None:
            forked = self._fork_lines([frame_slot(i, k, nreads)
                                       for i in ints for k in reads])
        if raw:
            return self._raw_frames(nreads, reads, ints, dn_gain, nbuf,
                                    split=raw == "split", forked=forked)
        return self._frames(nreads, reads, ints, dn_gain, nbuf, forked=forked)

    def _fork_lines(self, slots):
        """A :class:`_ForkedLines` making the 1/f lines of the large frames ``slots``,
        or None where the thread pool makes them (see :attr:`Layout.fork_min_pixels`).
        """
        det = self.detector
        pixels = det.ny * det.nx
        if (self.threads < 2 or pixels < self.layout.pool_min_pixels
                or len(slots) * pixels < self.layout.fork_min_pixels
                or not self._line_jobs() or not producer_available()):
            return None
        try:
            return _ForkedLines(self, slots)
        except OSError:                    # no fork here (process limit, memory)
            return None

    def _raw_frames(self, nreads, reads, ints, dn_gain, nbuf, split=False, forked=None):
        adc = None if dn_gain is None else ADC(dn_gain)
        self._reset_int_raw = None
        # no lines made ahead: the extra samples read the slot's 1/f series again
        for i, k, img in self._frames(nreads, reads, ints, None, nbuf, ahead=False,
                                      forked=forked):
            slot = frame_slot(i, k, nreads)
            if split:
                extra = self.extra_samples(slot, i)
                yield i, k, ((img, extra) if adc is None
                             else (adc.to_dn(img), adc.to_dn(extra)))
            else:
                raw = self.raw_frame(slot, i, image=img)
                yield i, k, (raw if adc is None else adc.to_dn(raw))

    def _frames(self, nreads, reads, ints, dn_gain, nbuf, ahead=True, forked=None):
        self._rtn_state = self._rtn_slot = None
        self._reset_int = None
        # small frames (windows) run inline: dispatching their tiny tasks to threads
        # costs more than it saves (results do not depend on it); they are made a
        # batch at a time (same values as frame(), see _small_batch)
        big = self.detector.ny * self.detector.nx >= self.layout.pool_min_pixels
        if not big:
            yield from self._frames_small(nreads, reads, ints, dn_gain, nbuf)
            return
        # with forked helpers making the lines, the threads still assemble the rows
        # (the parent's other work, the charge engine's, shares the cores too:
        # roman_wfi 13.1-13.4 s against 13.2-14.6 with the rows on one thread)
        pool = ThreadPoolExecutor(self.threads) if self.threads > 1 else None
        order = [(i, k) for i in ints for k in reads]
        bufs = []
        try:
            for n, (i, k) in enumerate(order):
                slot = frame_slot(i, k, nreads)
                buf = bufs[n % nbuf] if nbuf and len(bufs) == nbuf else None
                if forked is not None:
                    img = self._frame_forked(slot, i, pool, dn_gain, buf, forked, n)
                else:
                    nxt = frame_slot(*order[n + 1], nreads) \
                        if ahead and n + 1 < len(order) else None
                    img = self._frame(slot, i, pool, dn_gain, buf, nxt)
                if nbuf and buf is None:
                    bufs.append(img)
                yield i, k, img
        finally:
            self._ahead = None
            if forked is not None:
                forked.close()
            if pool is not None:
                pool.shutdown()

    # ------------------------------------------------------- small frames, batched
    def _frames_small(self, nreads, reads, ints, dn_gain, nbuf):
        """:meth:`_frames` for frames of fewer than ``Layout.pool_min_pixels`` pixels.

        The requested frames are made ``K`` at a time (``K * ny * nx <=
        batch_pixels``) by :meth:`_small_batch` into one internal float32 buffer,
        then copied out one by one into a fresh array (``nbuf == 0``) or into the
        ``nbuf`` rotating arrays, so ``reuse`` means exactly what it does for large
        frames.  The copy (a few us per frame) is far cheaper than the per-frame
        Python overhead the batch removes.

        With more than one thread, the 1/f lines and the reset levels of the batches
        are made ahead by a forked helper process (:mod:`noise.fast.producer`; Linux, and
        only while a single thread runs, else here), while this process draws the
        white noise, assembles the frames and its consumer uses them (a worker thread
        lost to GIL hand-overs what it gained; drawing the white noise in the helper
        too left it the slower of the two: timeseries bench ratio 2.03-2.07 against
        1.73-1.79).  The draws depend only on their indices, so the frames do not
        depend on the path.
        """
        det = self.detector
        order = [(i, k, frame_slot(i, k, nreads)) for i in ints for k in reads]
        lay = self.layout
        K = max(1, min(lay.batch_frames, lay.batch_pixels // (det.ny * det.nx), len(order)))
        batches = [order[j0:j0 + K] for j0 in range(0, len(order), K)]
        work = np.empty((K,) + det.shape, dtype=np.float32)
        scratch = np.empty_like(work)
        if dn_gain is not None:
            adc = ADC(dn_gain)
            dn = np.empty(work.shape, dtype=np.uint16)
            d64 = np.empty(work.shape, dtype=np.float64)
        dtype = np.float32 if dn_gain is None else np.uint16
        jobs = self._line_buffers()[0]
        groups = [self._small_groups([s for *_, s in batch]) for batch in batches]
        need = max(sum(span for *_, span in g) for g in groups) * self._L if jobs else 0
        # integrations whose reset level batch j needs (in order)
        levels = [list(dict.fromkeys(i for i, *_ in batch)) if self._level_map else []
                  for batch in batches]
        nlines = sum(len(owners) for *_, owners in jobs)
        shapes = [(nlines, need), (max(len(v) for v in levels),) + det.shape]

        def make(j, outs):
            """The 1/f lines and reset levels of batch ``j``."""
            lines, lvl = outs
            for task in self._small_line_tasks(groups[j], lines):
                task()
            for q, i in enumerate(levels[j]):
                for c0, c1 in self._chunks:
                    self._level_task(lvl[q], i, c0, c1)

        producer = None
        if self.threads > 1 and (jobs or self._level_map) \
                and len(batches) >= _FORK_MIN_BATCHES and producer_available():
            producer = ForkedProducer(make, len(batches), shapes, _AHEAD + 1)
        else:
            own = [np.empty(shape, dtype=np.float32) for shape in shapes]
        bufs, n = [], 0
        try:
            for j, batch in enumerate(batches):
                m = len(batch)
                self._small_white([s for *_, s in batch], work[:m])
                if producer is not None:
                    if j:
                        producer.release(j - 1)  # its frames have all been used
                    lines, lvl = producer.get(j)
                else:
                    make(j, own)
                    lines, lvl = own
                img = self._small_batch(batch, work[:m], scratch[:m],
                                        (groups[j], lines) if jobs else None,
                                        dict(zip(levels[j], lvl)))
                if dn_gain is not None:
                    img = adc.to_dn(img, out=dn[:m], scratch=d64[:m])
                for (i, k, _), src in zip(batch, img):
                    if nbuf:
                        if len(bufs) < nbuf:
                            bufs.append(np.empty(det.shape, dtype=dtype))
                        frame = bufs[n % nbuf]
                        np.copyto(frame, src)
                    else:
                        frame = src.copy()
                    n += 1
                    yield i, k, frame
        finally:
            if producer is not None:
                producer.close()

    def _small_white(self, slots, out):
        """White noise of ``slots`` into ``out`` (m, ny, nx), unit sigma, float32.

        One stream per (slot, chunk), drawn as :meth:`frame` draws it (one
        :func:`standard_normal` call per chunk, as ``_SUB_ROWS == _WHITE_ROWS``), the
        transforms of all the frames at once (:func:`standard_normal_rows`); the
        streams' seeds are hashed together (:class:`noise.streams.KeyedStreams`: the
        same generators as ``SeedSequence`` builds one by one).
        """
        if not self._sig_runs:
            return
        m, nx = len(slots), self.detector.nx
        for c0, c1 in self._chunks:
            gens = self._white_streams.generators(np.asarray(slots), c0 // _WHITE_ROWS)
            if len(self._chunks) == 1:
                standard_normal_rows(gens, out.reshape(m, -1))
            else:
                dst = np.empty((m, (c1 - c0) * nx), dtype=np.float32)
                standard_normal_rows(gens, dst)
                out[:, c0:c1] = dst.reshape(m, c1 - c0, nx)

    @staticmethod
    def _small_groups(slots):
        """Groups of nearly consecutive slots (gaps of at most one slot, the reset slot
        between integrations), each fetched as one range of every 1/f series.

        Returns a list of ``(g0, g1, s0, span)``: batch positions ``g0:g1``, first slot
        and number of slots covered.
        """
        slots = np.asarray(slots)
        cut = np.flatnonzero(np.diff(slots) > 2) + 1
        return [(g0, g1, int(slots[g0]), int(slots[g1 - 1]) - int(slots[g0]) + 1)
                for g0, g1 in zip([0] + cut.tolist(), cut.tolist() + [slots.size])]

    def _small_line_tasks(self, groups, store):
        """Tasks (one per 1/f series object) writing the lines of ``groups`` into
        ``store``.

        ``store`` has one row per line of :meth:`_line_buffers` (its jobs' lines in
        order); group ``q`` occupies ``span_q * frame_samples`` samples after those of
        the groups before it (an ACN pair interleaved even/odd, so it is one full-rate
        line).  A job's task calls :meth:`PinkSeries.plan` and runs the result for
        each group in turn.
        """
        jobs = self._line_buffers()[0]
        L = self._L

        def task(series, per_row, nfr, lines):
            off = 0
            for *_, s0, span in groups:
                n = span * nfr
                series.plan(s0 * nfr, n,
                            self._dest(lines[:, off:off + span * L], per_row, n))()
                off += span * L

        tasks, r = [], 0
        for series, per_row, nfr, owners in jobs:
            tasks.append(functools.partial(task, series, per_row, nfr,
                                           store[r:r + len(owners)]))
            r += len(owners)
        return tasks

    def _small_batch(self, batch, img, scratch, lines, levels):
        """Frames ``batch`` (list of ``(integration, read, slot)`` in time order) into
        ``img``, shape (m, ny, nx), float32, e-; returns ``img``.  On entry ``img``
        holds the batch's unit white draws (:meth:`_small_white`) if white noise is on.

        Bit-identical to :meth:`frame` of each slot: every pixel goes through the same
        float32 operations in the same order (white draw from the same
        ``(slot, chunk)`` stream, times sigma, + reset level, + template * pf,
        + pedestal/offset scalar, + the sum of its output's 1/f lines in scan order,
        + RTN), only vectorised over the frames of the batch.  The 1/f series are
        fetched once per group of nearly consecutive slots (:meth:`_small_groups`;
        the time line of slot ``s`` starts at ``s * frame_samples``, so a group is one
        contiguous range).  The sample values do not depend on how the range is
        requested (see :mod:`noise.pink`).  ``scratch`` is a float32 buffer of
        ``img``'s shape; ``lines`` is ``(groups, store)`` with the batch's lines
        already made by :meth:`_small_line_tasks`, or None if no 1/f line is on;
        ``levels`` maps each integration of the batch to its reset level (when kTC or
        the bias pattern is on), made by :meth:`_level_task`.
        """
        det, p = self.detector, self.params
        ny = det.ny
        m = len(batch)
        slots = np.array([s for *_, s in batch])
        # white noise (drawn into img by _small_white), times sigma
        if self._sig_runs:
            for r0, r1, vec in self._sig_runs:
                np.multiply(img[:, r0:r1], vec, out=img[:, r0:r1])
        # reset level, per run of frames of one integration
        if self._level_map:
            self._small_levels(batch, img, levels)
        elif not self._sig_runs:
            img.fill(0.0)
        groups = self._small_groups(slots)
        # picture frame: template times the row series of each frame
        if self._pf is not None:
            npf = ny + det.nfoh
            pf = np.empty((m, ny), dtype=np.float32)
            for g0, g1, s0, span in groups:
                y = self._pf.get(s0 * npf, span * npf)[0].reshape(span, npf)
                pf[g0:g1] = y[slots[g0:g1] - s0, :ny]
            img += np.multiply(self._template, pf[:, :, None], out=scratch)
        # pedestal + constant offset (frame() skips a zero scalar: so do we)
        scalar = np.array([self.pedestal(s) + (0.0 if self._level_map else p.bias_offset)
                           for s in slots.tolist()], dtype=np.float32)
        nonzero = np.flatnonzero(scalar)
        if nonzero.size == m:
            img += scalar[:, None, None]
        else:
            for j in nonzero.tolist():
                img[j] += scalar[j]
        if lines is not None:
            self._small_add_lines(img, scratch, slots, groups, lines[1])
        # random telegraph pixels, advanced over the requested slots in order
        if self._rtn_idx is not None:
            for j, slot in enumerate(slots.tolist()):
                self._advance_rtn(slot)
                img[j].reshape(-1)[self._rtn_idx] += \
                    np.float32(p.rtn_amp) * self._rtn_state
        return img

    def _small_levels(self, batch, img, levels):
        """Add (or, without white noise, set) each frame's reset level in ``img``,
        per run of frames of one integration."""
        m = len(batch)
        j0 = 0
        while j0 < m:
            i = batch[j0][0]
            j1 = j0 + 1
            while j1 < m and batch[j1][0] == i:
                j1 += 1
            if self._sig_runs:
                np.add(img[j0:j1], levels[i], out=img[j0:j1])
            else:
                img[j0:j1] = levels[i]
            j0 = j1

    def _small_add_lines(self, img, scratch, slots, groups, lines):
        """Add the 1/f time lines (made per group by :meth:`_small_line_tasks` into
        ``lines``) to the frames ``img``: summed per output in scan order per run of
        consecutive slots, added once (mirrored on reversed outputs)."""
        det = self.detector
        ny, ncol, rs, L = det.ny, det.ncols_out, det.row_samples, self._L
        m = len(slots)
        owners = [o for *_, job_owners in self._line_buffers()[0] for o in job_owners]
        tmp_buf = scratch.reshape(-1)[:m * ny * ncol].reshape(m, ny, ncol)
        off = 0
        for g0, g1, s0, span in groups:
            store = lines[:, off * L:(off + span) * L]
            off += span
            rel = slots[g0:g1] - s0
            brk = np.flatnonzero(np.diff(rel) != 1) + 1
            for q0, q1 in zip([0] + brk.tolist(), brk.tolist() + [g1 - g0]):
                a, b = int(rel[q0]), int(rel[q1 - 1]) + 1
                for o in range(det.n_out_active):
                    views = [line.reshape(span, -1, rs)[a:b, :ny, :ncol]
                             if self._gather is None else
                             line.reshape(span, -1, rs)[a:b, :ny][..., self._gather]
                             for line, owner in zip(store, owners)
                             if owner is None or owner == o]
                    if not views:
                        continue
                    if len(views) > 1:
                        tmp = np.add(views[0], views[1], out=tmp_buf[:b - a])
                        for view in views[2:]:
                            np.add(tmp, view, out=tmp)
                    else:
                        tmp = views[0]
                    sec = img[g0 + q0:g0 + q1, :, o * ncol:(o + 1) * ncol]
                    np.add(sec, tmp[..., ::-1] if det.output_reversed(o) else tmp, out=sec)

    def cube(self, nframes, *, nints=1):
        """All frames at once, shape (nints, nframes, ny, nx), float32, e-.

        Convenience for small arrays; memory grows with the cube, use :meth:`frames`
        (or :func:`noise.write_noise_fits`) to stream long ramps.

        Parameters
        ----------
        nframes : int
            Read frames per integration, >= 1.
        nints : int
            Integrations, >= 1.

        Raises
        ------
        noise.errors.ParameterError
            Bad counts, or a cube larger than the memory available now (it would be
            paged out or end in a MemoryError: stream it with :meth:`frames`).
        """
        nframes = check_int("nframes", nframes, minimum=1, maximum=MAX_FRAMES)
        nints = check_int("nints", nints, minimum=1, maximum=MAX_FRAMES)
        det = self.detector
        need = 4.0 * nints * nframes * det.ny * det.nx
        avail = available_memory()
        if avail is not None and need > avail:
            raise ParameterError(
                f"cube of 'nints' x 'nframes' = {nints} x {nframes} frames of "
                f"{det.ny}x{det.nx}: {need / 2 ** 30:.3g} GiB, more than the "
                f"{avail / 2 ** 30:.3g} GiB of memory available; stream the frames "
                f"with frames() or write them with noise.write_noise_fits")
        out = np.empty((nints, nframes) + det.shape, dtype=np.float32)
        for i, k, frame in self.frames(nframes, nints=nints):
            out[i, k] = frame
        return out


class _ForkedLines:
    """The 1/f lines of a run of large frames, made band by band by forked helpers.

    Why: made on the thread pool, the line tasks and the row tasks of a band share
    one interpreter, and every hand-over of the GIL between the cores costs a futex
    wake-up (a run of 88 H2RG frames on two threads: 27-38 thousand voluntary
    context switches, 6-8 thousand with the helpers; the timings are in the module
    notes).  In forked processes the line synthesis (most of a noise frame's work:
    the draws and FFTs of every 1/f series) shares nothing with the parent but the
    result buffers.

    The series groups of :meth:`NoiseGenerator._line_jobs` are dealt to up to
    ``threads`` helpers, the largest first, each to the helper with the fewest lines
    so far.  Helper ``h`` is a :class:`noise.fast.producer.ForkedProducer` whose
    result ``j = n * nbands + k`` is band ``k`` of the ``n``-th frame of the run: its
    groups' lines, written exactly as the thread pool writes them
    (``PinkSeries.plan`` into :meth:`NoiseGenerator._line_set`'s destinations), so
    the frames are the same bytes.  The helpers run up to ``_FORK_DEPTH - 1`` bands
    ahead of the parent.  Each works on its own copy of its series (the parent's
    objects are never advanced; a sample depends only on its index, see
    :mod:`noise.pink`).
    """

    def __init__(self, gen, slots):
        jobs = gen._line_jobs()
        self.bands = gen._bands()
        nb = len(self.bands)
        self.nhelpers = min(gen.threads, len(jobs))
        parts, load = [[] for _ in range(self.nhelpers)], [0] * self.nhelpers
        for j in sorted(range(len(jobs)), key=lambda j: -len(jobs[j][3])):
            h = load.index(min(load))
            parts[h].append(j)
            load[h] += len(jobs[j][3])
        parts = [sorted(part) for part in parts]
        size = gen._band_line_size()
        self._producers = []
        self._views = []
        finalizer = weakref.finalize(self, _close_all, self._producers)
        try:
            for part in parts:
                nlines = sum(len(jobs[j][3]) for j in part)
                self._producers.append(ForkedProducer(
                    functools.partial(_make_band_lines, gen, jobs, part, slots,
                                      self.bands),
                    len(slots) * nb, [(nlines, size)], _FORK_DEPTH))
            # the row tasks' views of each result slot, in the parent
            for d in range(_FORK_DEPTH):
                lines = [None] * len(jobs)
                for part, producer in zip(parts, self._producers):
                    store, r = producer.slot(d)[0], 0
                    for j in part:
                        lines[j] = store[r:r + len(jobs[j][3])]
                        r += len(jobs[j][3])
                self._views.append(gen._line_set(jobs, lines)[1])
        except BaseException:
            finalizer()
            raise
        self._finalizer = finalizer

    def get(self, j):
        """Band result ``j`` (in order): per output, the views of its lines."""
        for producer in self._producers:
            producer.get(j)
        return self._views[j % _FORK_DEPTH]

    def release(self, j):
        """The rows of band result ``j`` are made: its slots may be reused."""
        for producer in self._producers:
            producer.release(j)

    def close(self):
        """Stop and reap the helpers (idempotent)."""
        self._finalizer()


def _close_all(producers):
    for producer in producers:
        producer.close()


def _make_band_lines(gen, jobs, part, slots, bands, j, outs):
    """In a helper of :class:`_ForkedLines`: band result ``j`` of the groups
    ``part`` (indices into ``jobs``) into its slot ``outs``."""
    n, k = divmod(j, len(bands))
    ra, rb = bands[k]
    store, r = outs[0], 0
    for idx in part:
        series, per_row, nfr, owners = jobs[idx]
        lines = store[r:r + len(owners)]
        r += len(owners)
        m = (rb - ra) * per_row
        series.plan(slots[n] * nfr + ra * per_row, m,
                    gen._dest(lines, per_row, m)[..., :m])()
