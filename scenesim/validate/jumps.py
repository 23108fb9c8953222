"""Jump detection graded against the injected cosmic rays.

Jumps: a pixel is *hit* when a cosmic ray that a read saw (``SEEN``) deposited more
than ``cr_sigma`` (10) times the noise of a difference of two consecutive reads at
the pixel's true rate, ``sqrt(2 read_noise^2 + rate t_frame)`` (a bright pixel's shot
noise hides a deposit read noise alone would not), *inside* the pixel's usable ramp of an integration: after
the first read of the first resultant and not after the last read of the last
unsaturated resultant (truth ``SATGROUP``), in clock time (frame slot ``s`` of the
readout, ``s * TFRAME + t_pix`` with the pixel's read time in the frame from the
detector cards of the truth header).  A deposit before the first read is in every
read (an offset, not a jump: no ramp-based method can see it; on the cosmic-ray
scene these were the 1.3 % of "missed" hits), and one after the last usable read in
none.  Without detector cards or readout every seen deposit counts (a note says so).
Completeness = fraction of hit pixels flagged ``JUMP_DET``; false-positive rate =
fraction of *clean* pixels flagged ``JUMP_DET``: pixels without any deposit (of any
size, seen or not) and, when the truth header says IPC was applied, without a
deposit among their 8 neighbours (the 3 x 3 IPC kernel moves a fraction of a
neighbour's charge, hence of its jump, into them).

"""

import math

import numpy as np

from noise.clock import detector_from_header, frame_slot
from noise.errors import FileFormatError, ParameterError

from scenesim.detector.dq import JUMP_DET

__all__ = ['ramp_windows', 'jump_stats']


def ramp_windows(truth, readout, t_frame):
    """Clock-time bounds of every pixel's usable ramp in each integration.

    Returns ``(t_first, t_last)``, functions of pixel ``(y, x)`` arrays giving
    (nints, n) clock times (s) of the first read of the first resultant and of the
    last read of the last unsaturated resultant (``SATGROUP``; NaN when fewer than
    two resultants are unsaturated), or None when the truth lacks the detector
    cards.  Clock time of frame slot ``s``: ``s * t_frame + t_pix``.
    """
    try:
        det = detector_from_header(truth["header"])
    except (FileFormatError, ParameterError, KeyError, ValueError):
        return None
    tpix = det.pixel_time()
    if tpix.shape != truth.get("RATE", np.zeros(det.shape)).shape:
        return None
    nints = readout.nints
    nreads = readout.nreads
    first_read = readout.resultants[0][0]
    last_reads = np.array([r[-1] for r in readout.resultants])
    satg = truth.get("SATGROUP")
    if satg is not None:
        satg = np.asarray(satg)
        if satg.ndim == 2:
            satg = satg[None]
        if satg.shape != (nints,) + det.shape:
            satg = None
    ng = len(readout.resultants)

    def bounds(y, x):
        i = np.arange(nints)[:, None]
        tp = tpix[y, x][None, :]
        t0 = frame_slot(i, first_read, nreads) * t_frame + tp
        g_end = np.full((nints, y.size), ng - 1)
        if satg is not None:
            s = satg[:, y, x].astype(np.int64)
            g_end = np.where(s >= 0, s - 1, ng - 1)
        t1 = frame_slot(i, last_reads[np.clip(g_end, 0, ng - 1)], nreads) * t_frame + tp
        return t0, np.where(g_end >= 1, t1, np.nan)

    return bounds


def jump_stats(dq, crs, shape, read_noise, cr_sigma, regular, *, windows=None,
               ipc=False, rate=None, t_read=None):
    """Completeness and false-positive rate of the jump flags (module notes).

    A deposit is detectable (a *hit*) when its charge exceeds ``cr_sigma`` times the
    noise of a difference of two consecutive reads at the pixel's true rate,
    ``sqrt(2 read_noise^2 + rate t_read)`` (read noise alone when ``rate`` or
    ``t_read`` is None): on a bright pixel the shot noise of the difference hides a
    deposit that read noise alone would not.
    """
    ny, nx = shape
    var_diff = 2.0 * read_noise ** 2
    if rate is not None and t_read is not None:
        var_diff = var_diff + np.clip(np.asarray(rate, dtype=np.float64), 0.0, None) * t_read
    thr_map = cr_sigma * np.sqrt(np.broadcast_to(var_diff, shape))
    x = np.asarray(crs["X"], dtype=np.int64)
    y = np.asarray(crs["Y"], dtype=np.int64)
    q = np.asarray(crs["CHARGE"], dtype=np.float64)
    seen = np.asarray(crs["SEEN"], dtype=bool)
    on = (x >= 0) & (x < nx) & (y >= 0) & (y < ny)
    flat = y[on] * nx + x[on]
    any_dep = np.bincount(flat, minlength=ny * nx).reshape(shape) > 0
    thr = np.full(q.shape, np.inf)
    thr[on] = thr_map[y[on], x[on]]
    big = on & seen & (q > thr)
    if windows is not None and "TIME" in crs.colnames:
        t = np.asarray(crs["TIME"], dtype=np.float64)[big]
        t0, t1 = windows(y[big], x[big])
        with np.errstate(invalid="ignore"):
            inside = ((t[None] > t0) & (t[None] <= t1)).any(axis=0)
        idx = np.flatnonzero(big)
        big[idx[~inside]] = False
    hit = np.bincount(y[big] * nx + x[big], minlength=ny * nx).reshape(shape) > 0
    flagged = (dq & JUMP_DET) != 0
    hit &= regular
    near = any_dep
    if ipc:                     # the 3 x 3 IPC kernel moves charge to the 8 neighbours
        pad = np.pad(any_dep, 1)
        near = np.zeros_like(any_dep)
        for dy in range(3):
            for dx in range(3):
                near |= pad[dy:dy + ny, dx:dx + nx]
    clean = regular & ~near
    n_hit, n_clean = int(hit.sum()), int(clean.sum())
    return {"n_hit": n_hit,
            "completeness": float(flagged[hit].mean()) if n_hit else float("nan"),
            "n_clean": n_clean,
            "false_positive": float(flagged[clean].mean()) if n_clean else float("nan"),
            "threshold_e": float(cr_sigma * math.sqrt(2.0) * read_noise),
            "threshold_rule": ("read noise and shot noise" if np.ndim(var_diff)
                               else "read noise")}
