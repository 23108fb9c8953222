"""Frame-by-frame HxRG noise generator (Rauscher 2015), streamed in bounded memory.

Each read frame is assembled from the components of :mod:`noise.params`, driven by the
clock of :mod:`noise.detector`:

* time-line components (correlated pink, uncorrelated pink, ACN) are sampled once per
  pixel time on each output's time line, overheads included, and placed in the image in
  that output's scan order (so correlated pink appears mirrored on reversed outputs);
* picture-frame noise is a 1/f series sampled once per row (shared by all outputs)
  times the template;
* pedestal is one offset per frame; kTC + bias one reset level per integration; white
  noise one sample per pixel per read (reference pixels scaled by ``ref_ratio``);
* random telegraph noise is a two-state Markov process per RTN pixel, advanced exactly
  over the time between the reads that are actually requested.

The exposure time line (see ``docs/CONVENTIONS.md``): each integration is one reset
frame slot followed by its ``nreads`` read slots; slot ``s`` starts at ``s * t_frame``.
All 1/f series run continuously through every slot, overheads included, but samples
of frames nobody asks for are never synthesised at the fine rate (see
:mod:`noise.pink`).

Randomness: every component, output, chunk and block has its own stream,
``SeedSequence(entropy, spawn_key=prefix + (component, ...))``, so the frames do not
depend on the chunking, on the number of threads, or on which other components are
switched on (a zero amplitude skips a component entirely without shifting any draw).
"""

import os
from concurrent.futures import ThreadPoolExecutor

import numpy as np

from .detector import Detector
from .errors import ParameterError
from .params import NoiseParams
from .pink import PinkSeries
from .template import template_for

__all__ = ["NoiseGenerator", "COMPONENTS", "root_seed"]

#: Component names and their stream identifiers.
COMPONENTS = {"white": 1, "c_pink": 2, "u_pink": 3, "acn": 4, "pca0": 5, "pedestal": 6,
              "ktc": 7, "rtn": 8}
_WHITE_ROWS = 32      # rows per white-noise / reset-level stream (fixed: chunk-independent)


def root_seed(rng):
    """Return ``(entropy, spawn_key)`` of the root ``SeedSequence`` for ``rng``.

    ``rng`` may be an int, a ``SeedSequence``, a ``Generator`` (its seed sequence is
    used) or ``None`` (fresh OS entropy, recorded so the run can be repeated).
    """
    if isinstance(rng, np.random.Generator):
        ss = rng.bit_generator.seed_seq
    elif isinstance(rng, np.random.SeedSequence):
        ss = rng
    elif rng is None or isinstance(rng, (int, np.integer)):
        if rng is not None and rng < 0:
            raise ParameterError(f"'rng' seed must be >= 0, got {rng!r}")
        ss = np.random.SeedSequence(None if rng is None else int(rng))
    else:
        raise ParameterError(
            f"'rng' must be an int, SeedSequence, Generator or None, got {rng!r}")
    return ss.entropy, tuple(ss.spawn_key)


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

    Examples
    --------
    >>> gen = NoiseGenerator(rng=1)                       # doctest: +SKIP
    >>> for i, k, frame in gen.frames(nreads=5): ...      # doctest: +SKIP
    """

    def __init__(self, detector=None, params=None, *, rng=None, threads=None):
        self.detector = detector if detector is not None else Detector()
        self.params = params if params is not None else NoiseParams()
        if not isinstance(self.detector, Detector):
            raise ParameterError(f"'detector' must be a noise.Detector, got {detector!r}")
        if not isinstance(self.params, NoiseParams):
            raise ParameterError(f"'params' must be a noise.NoiseParams, got {params!r}")
        self.entropy, self.key = root_seed(rng)
        self.threads = int(threads) if threads is not None else (os.cpu_count() or 1)
        if self.threads < 1:
            raise ParameterError(f"'threads' must be >= 1, got {threads!r}")
        self._validate()
        self._setup()

    # ------------------------------------------------------------------ setup
    def _validate(self):
        det, p = self.detector, self.params
        nout = det.n_out_active
        for name in ("rd_noise", "u_pink", "acn"):
            p.per_output(name, nout)
        if p.enabled("acn"):
            if det.ncols_out % 2:
                raise ParameterError(
                    f"ACN needs an even number of columns per output; got "
                    f"{det.ncols_out} columns per output ({det.nx} columns / {nout} "
                    f"outputs); set 'acn' to 0 or change 'naxis1'/'n_out'/the subarray")
            if det.row_samples % 2:
                raise ParameterError(
                    f"ACN needs an even row length (columns per output + 'nroh'); got "
                    f"{det.ncols_out} + {det.nroh}; make 'nroh' even or set 'acn' to 0")

    def _stream(self, *key):
        ss = np.random.SeedSequence(self.entropy, spawn_key=self.key + key)
        return np.random.Generator(np.random.PCG64(ss))

    def _setup(self):
        det, p = self.detector, self.params
        nout = det.n_out_active
        L = det.frame_samples
        kw = dict(f_min=p.f_min, spectrum=p.pink_spectrum, entropy=self.entropy)
        self._L = L
        # one series object per output (and one for the correlated series) so that
        # outputs can be generated in parallel threads; each keeps its own stream key
        self._common = None
        if p.c_pink > 0:
            self._common = PinkSeries(1 / det.dt, L, [p.c_pink],
                                      seed_keys=[self.key + (COMPONENTS["c_pink"],)], **kw)
        self._u_pink = [None] * nout
        if p.enabled("u_pink"):
            for o, amp in enumerate(p.per_output("u_pink", nout)):
                if amp > 0:
                    self._u_pink[o] = PinkSeries(
                        1 / det.dt, L, [amp],
                        seed_keys=[self.key + (COMPONENTS["u_pink"], o)], **kw)
        # ACN: two half-rate series (even, odd samples) per output
        self._acn = [None] * nout
        if p.enabled("acn"):
            for o, amp in enumerate(p.per_output("acn", nout)):
                if amp > 0:
                    self._acn[o] = PinkSeries(
                        0.5 / det.dt, L // 2, [amp, amp],
                        seed_keys=[self.key + (COMPONENTS["acn"], o, 0),
                                   self.key + (COMPONENTS["acn"], o, 1)], **kw)
        self._pf = None
        self._template = None
        if p.pca0 > 0 or p.bias_amp > 0:
            self._template = template_for(det, p.pca0_file)
        if p.pca0 > 0:
            self._pf = PinkSeries(1 / det.row_time, det.ny + det.nfoh, [p.pca0],
                                  seed_keys=[self.key + (COMPONENTS["pca0"],)], **kw)
        # white-noise sigma map (e-), per output and reference ratio
        self._sigma = None
        if p.enabled("rd_noise"):
            rd = p.per_output("rd_noise", nout)[det.output_of_column()]
            sig = np.broadcast_to(rd[None, :], det.shape).astype(np.float32)
            self._sigma = np.where(det.reference_mask(), sig * np.float32(p.ref_ratio),
                                   sig).astype(np.float32)
        # random telegraph pixels
        self._rtn_idx = None
        if p.rtn_fraction > 0 and p.rtn_amp > 0:
            regular = ~det.reference_mask()
            pick = self._stream(COMPONENTS["rtn"], 0).random(det.shape) < p.rtn_fraction
            self._rtn_idx = np.flatnonzero(pick & regular)
            self._rtn_state = None
            self._rtn_slot = None
        self._reset_int = None
        self._reset_level = None

    # ------------------------------------------------------------- components
    @property
    def has_reset_level(self):
        p = self.params
        return p.ktc > 0 or p.bias_amp > 0 or p.bias_offset != 0

    def reset_level(self, integration):
        """kTC + bias reset level of ``integration``, shape (ny, nx), float32, e-."""
        det, p = self.detector, self.params
        lvl = np.full(det.shape, p.bias_offset, dtype=np.float32)
        if p.bias_amp > 0:
            lvl += np.float32(p.bias_amp) * self._template
        if p.ktc > 0:
            for c0 in range(0, det.ny, _WHITE_ROWS):
                rows = slice(c0, min(c0 + _WHITE_ROWS, det.ny))
                z = self._stream(COMPONENTS["ktc"], integration, c0 // _WHITE_ROWS)
                lvl[rows] += np.float32(p.ktc) * z.standard_normal(
                    (rows.stop - rows.start, det.nx), dtype=np.float32)
        return lvl

    def pedestal(self, slot):
        """Pedestal offset of frame slot ``slot`` (e-)."""
        if self.params.pedestal <= 0:
            return 0.0
        return float(self.params.pedestal
                     * self._stream(COMPONENTS["pedestal"], slot).standard_normal())

    def timeline(self, component, output, start, n):
        """Raw time-line samples of a 1/f component, e-, float32.

        Parameters
        ----------
        component : {'c_pink', 'u_pink', 'acn', 'pca0'}
        output : int
            Output index (ignored for 'c_pink' and 'pca0').
        start, n : int
            Absolute sample range on that series' own time line (pixel rate; half rate
            for each ACN parity, which returns shape (2, n); row rate for 'pca0').
        """
        if component == "c_pink" and self._common is not None:
            return self._common.get(start, n)[0]
        if component == "u_pink" and self._u_pink[output] is not None:
            return self._u_pink[output].get(start, n)[0]
        if component == "acn" and self._acn[output] is not None:
            return self._acn[output].get(start, n)
        if component == "pca0" and self._pf is not None:
            return self._pf.get(start, n)[0]
        raise ParameterError(
            f"'component' {component!r} (output {output}) is not enabled; enabled 1/f "
            f"components are those with amplitude > 0 among c_pink, u_pink, acn, pca0")

    def _advance_rtn(self, slot):
        p, det = self.params, self.detector
        n = self._rtn_idx.size
        z = self._stream(COMPONENTS["rtn"], 2, slot).random(n)
        p_high = p.rtn_tau_high / (p.rtn_tau_low + p.rtn_tau_high)
        if self._rtn_state is None:
            self._rtn_state = z < p_high
        else:
            if slot <= self._rtn_slot:
                raise ParameterError(
                    f"frames must be requested in increasing time order; slot {slot} "
                    f"after {self._rtn_slot}")
            dt = (slot - self._rtn_slot) * det.frame_time
            decay = np.exp(-dt * (1 / p.rtn_tau_low + 1 / p.rtn_tau_high))
            prob_high = np.where(self._rtn_state, p_high + (1 - p_high) * decay,
                                 p_high * (1 - decay))
            self._rtn_state = z < prob_high
        self._rtn_slot = slot

    # ---------------------------------------------------------------- frames
    def frame(self, slot, integration, pool=None):
        """Noise frame of absolute frame slot ``slot`` in ``integration``.

        Returns
        -------
        ndarray, shape (ny, nx), float32, e-
        """
        det, p = self.detector, self.params
        ny, nx = det.shape
        if self.has_reset_level and self._reset_int != integration:
            self._reset_level = self.reset_level(integration)
            self._reset_int = integration
        ped = np.float32(self.pedestal(slot))
        pf = None
        if self._pf is not None:
            pf = self._pf.get(slot * (ny + det.nfoh), ny)[0]
        img = np.empty(det.shape, dtype=np.float32)
        L = self._L

        def rows_task(c0):
            rows = slice(c0, min(c0 + _WHITE_ROWS, ny))
            blk = img[rows]
            if self._sigma is not None:
                self._stream(COMPONENTS["white"], slot, c0 // _WHITE_ROWS).standard_normal(
                    out=blk, dtype=np.float32)
                blk *= self._sigma[rows]
            else:
                blk[...] = 0.0
            if self._reset_level is not None:
                blk += self._reset_level[rows]
            if ped:
                blk += ped
            if pf is not None:
                blk += self._template[rows] * pf[rows, None]

        def line_task(o):
            """Time line of output o (-1: the correlated series), or None."""
            if o < 0:
                return self._common.get(slot * L, L)[0]
            tl = None
            if self._u_pink[o] is not None:
                tl = self._u_pink[o].get(slot * L, L)[0]
            if self._acn[o] is not None:
                ab = self._acn[o].get(slot * (L // 2), L // 2)
                if tl is None:
                    tl = np.empty(L, dtype=np.float32)
                    tl[0::2] = ab[0]
                    tl[1::2] = ab[1]
                else:
                    tl[0::2] += ab[0]
                    tl[1::2] += ab[1]
            return tl

        ncol = det.ncols_out
        nout = det.n_out_active
        lines = ([-1] if self._common is not None else []) + [
            o for o in range(nout) if self._u_pink[o] is not None or self._acn[o] is not None]
        row_chunks = range(0, ny, _WHITE_ROWS)
        if pool is not None:
            futs = [pool.submit(line_task, o) for o in lines]
            ngroup = 2 * self.threads
            groups = [row_chunks[i::ngroup] for i in range(ngroup)]
            list(pool.map(lambda grp: [rows_task(c0) for c0 in grp], groups))
            tls = {o: f.result() for o, f in zip(lines, futs)}
        else:
            for c0 in row_chunks:
                rows_task(c0)
            tls = {o: line_task(o) for o in lines}
        common = tls.get(-1)

        def add_task(o):
            tl = tls.get(o)
            if tl is None:
                tl = common
            elif common is not None:
                tl += common
            if tl is None:
                return
            sec = tl.reshape(ny + det.nfoh, det.row_samples)[:ny, :ncol]
            if det.output_reversed(o):
                sec = sec[:, ::-1]
            img[:, o * ncol:(o + 1) * ncol] += sec

        if pool is not None:
            list(pool.map(add_task, range(nout)))
        else:
            for o in range(nout):
                add_task(o)
        if self._rtn_idx is not None and self._rtn_idx.size:
            self._advance_rtn(slot)
            img.ravel()[self._rtn_idx] += np.float32(p.rtn_amp) * self._rtn_state
        return img

    def frames(self, nreads, reads=None, *, nints=1, integrations=None):
        """Yield ``(integration, read, frame)`` for the requested reads, in time order.

        Parameters
        ----------
        nreads : int
            Read frames per integration (the time line has ``1 + nreads`` slots each).
        reads : iterable of int, optional
            Read indices (0-based, from reset) to materialise; default all.  Others
            are skipped (no white draws; 1/f series still run through them).
        nints : int
            Integrations.
        integrations : iterable of int, optional
            Subset of integrations to produce (default all).

        Yields
        ------
        (int, int, ndarray (ny, nx) float32 e-)
        """
        nreads = int(nreads)
        if nreads < 1:
            raise ParameterError(f"'nreads' must be >= 1, got {nreads!r}")
        reads = list(range(nreads)) if reads is None else sorted(set(int(r) for r in reads))
        if reads and (reads[0] < 0 or reads[-1] >= nreads):
            raise ParameterError(
                f"'reads' must lie in [0, {nreads - 1}], got {reads[0]}..{reads[-1]}")
        ints = range(int(nints)) if integrations is None else sorted(integrations)
        self._rtn_state = self._rtn_slot = None
        self._reset_int = None
        pool = ThreadPoolExecutor(self.threads) if self.threads > 1 else None
        try:
            for i in ints:
                for k in reads:
                    slot = i * (1 + nreads) + 1 + k
                    yield i, k, self.frame(slot, i, pool)
        finally:
            if pool is not None:
                pool.shutdown()

    def cube(self, nframes, *, nints=1):
        """All frames at once, shape (nints, nframes, ny, nx), float32, e-.

        Convenience for small arrays; memory grows with the cube, use :meth:`frames`
        (or :func:`noise.write_noise_fits`) to stream long ramps.
        """
        det = self.detector
        out = np.empty((int(nints), int(nframes)) + det.shape, dtype=np.float32)
        for i, k, frame in self.frames(nframes, nints=nints):
            out[i, k] = frame
        return out
