"""Cosmic-ray hits: when, where and how much charge.

Physics and defaults
--------------------
Energetic ions cross the detector at a rate ``rate`` per cm^2 per second and leave
ionisation charge along their path.  Hits are a Poisson process in time and uniform
over the array, so over ``[t_start, t_stop)`` on an array of ``ny x nx`` pixels of
pitch ``p`` micrometres::

    N ~ Poisson(rate * A * (t_stop - t_start)),   A = ny * nx * (p * 1e-4)**2  cm^2

with hit times independent and uniform in ``[t_start, t_stop)`` and hit pixels
uniform over the array.  Defaults, for a shielded HxRG near Sun-Earth L2:

* ``rate = 5 /cm^2/s``.  Rauscher & Fixsen (2025, PASP 137, 095003) measured 4.3
  falling to 2.3 ions cm^-2 s^-1 on JWST NIRSpec between solar minimum and maximum
  (expected up to ~6 near the next minimum); the JWST exposure time calculator uses 8.
* Charge per hit: log-normal with mean ``charge_mean = 5200 e-`` (the same paper: a
  typical hit deposits ~6 keV, ~5200 charges, in 5.4 um cut-off HgCdTe) and standard
  deviation ``charge_sigma = 5200 e-`` (an assumed wide spread standing in for the
  Landau tail and the spread of path lengths).  The log-normal parameters follow from
  the mean ``m`` and standard deviation ``s``: ``sigma_ln**2 = ln(1 + (s/m)**2)``,
  ``mu_ln = ln m - sigma_ln**2 / 2``.  Alternatively ``charge_distribution='table'``
  draws from a histogram (``charge_edges``, ``charge_weights``): a bin by its weight,
  then a charge uniform within the bin (inverse transform of the piecewise-linear
  cumulative distribution).
* Footprint: a small square kernel of charge fractions centred on the hit pixel
  (default 3 x 3: 0.80 centre, 0.04 to each edge neighbour, 0.01 to each diagonal,
  a charge-diffusion shape; the JWST ETC counts 9 affected pixels and the 2025 paper
  ~7).  Oblique tracks and "snowballs" are not modelled.  The total charge of a hit
  (rounded to whole electrons) is split among the kernel pixels by a multinomial draw
  -- each electron lands independently in a kernel pixel with the kernel
  probability -- so deposits are whole electrons and the kernel conserves the charge
  exactly; the kernel is the mean split.

Charge that the kernel puts off the array is dropped, and reference pixels collect no
charge (deposits there are dropped); both amounts are recorded in the table metadata.
Cosmic-ray charge adds to the pixel's integrating node: a read at a time after the
hit sees it, a read before does not (DESIGN.md section 2(c)); that bookkeeping belongs
to the charge engine, which receives the hit times here.
"""

import math
from dataclasses import dataclass

import numpy as np
from astropy.table import Table

from noise.validate import (check_choice, check_float, check_int, check_mask, check_rng,
                            check_shape)
from noise.errors import ParameterError

__all__ = ["CosmicRayModel", "draw_cosmic_rays", "MAX_EVENTS"]

#: Most hits drawn at once (expected number, ``rate * area * time``): drawing takes
#: ~0.7 kB per hit (offsets, multinomial split and table of its 9 deposits), so 1e10
#: hits is 7 TB, beyond any machine; numpy's Poisson sampler itself stops at 9.2e18.
MAX_EVENTS = 1e10

_DEFAULT_FOOTPRINT = ((0.01, 0.04, 0.01),
                      (0.04, 0.80, 0.04),
                      (0.01, 0.04, 0.01))




@dataclass(frozen=True)
class CosmicRayModel:
    """Frozen settings of the cosmic-ray environment and of a hit's charge.

    Parameters
    ----------
    rate : float
        Hits per cm^2 per second (>= 0; 0 disables cosmic rays).
    charge_distribution : {'lognormal', 'table'}
        How the total charge of a hit is drawn.
    charge_mean, charge_sigma : float
        Mean and standard deviation of the log-normal total charge, e- (> 0, >= 0).
        ``charge_sigma = 0`` gives every hit ``charge_mean``.
    charge_edges : tuple of float or None
        ``'table'`` only: histogram bin edges, e- (strictly increasing, >= 0, at least 2).
    charge_weights : tuple of float or None
        ``'table'`` only: relative frequency per bin (>= 0, positive sum; one fewer
        than the edges).
    footprint : tuple of tuple of float
        Square kernel of odd size (``[dy][dx]``, centre = hit pixel) of charge
        fractions (>= 0, summing to 1 within 1e-6; stored exactly normalised).
    """

    rate: float = 5.0
    charge_distribution: str = "lognormal"
    charge_mean: float = 5200.0
    charge_sigma: float = 5200.0
    charge_edges: tuple | None = None
    charge_weights: tuple | None = None
    footprint: tuple = _DEFAULT_FOOTPRINT

    def __post_init__(self):
        check_float("rate", self.rate, minimum=0.0)
        check_choice("charge_distribution", self.charge_distribution,
                     ("lognormal", "table"))
        check_float("charge_mean", self.charge_mean, minimum=0.0, strict_min=True)
        check_float("charge_sigma", self.charge_sigma, minimum=0.0)
        if self.charge_distribution == "table":
            if self.charge_edges is None or self.charge_weights is None:
                raise ParameterError(
                    "charge_distribution='table' needs 'charge_edges' and "
                    "'charge_weights'")
            edges = np.asarray(self.charge_edges, dtype=float)
            weights = np.asarray(self.charge_weights, dtype=float)
            if edges.ndim != 1 or edges.size < 2 or not np.all(np.isfinite(edges)) \
                    or edges[0] < 0 or np.any(np.diff(edges) <= 0):
                raise ParameterError(
                    f"'charge_edges' must be >= 2 finite, strictly increasing values "
                    f">= 0 (e-), got {self.charge_edges!r}")
            if weights.shape != (edges.size - 1,) or not np.all(np.isfinite(weights)) \
                    or np.any(weights < 0) or weights.sum() <= 0:
                raise ParameterError(
                    f"'charge_weights' must be {edges.size - 1} finite values >= 0 with "
                    f"a positive sum, got {self.charge_weights!r}")
            object.__setattr__(self, "charge_edges", tuple(edges.tolist()))
            object.__setattr__(self, "charge_weights", tuple(weights.tolist()))
        elif self.charge_edges is not None or self.charge_weights is not None:
            raise ParameterError(
                "'charge_edges'/'charge_weights' are only used with "
                "charge_distribution='table'")
        try:
            kern = np.array(self.footprint, dtype=float)
        except (TypeError, ValueError) as exc:
            raise ParameterError(
                f"'footprint' must be a square table of numbers, got {self.footprint!r}"
            ) from exc
        if kern.ndim != 2 or kern.shape[0] != kern.shape[1] or kern.shape[0] % 2 != 1:
            raise ParameterError(
                f"'footprint' must be a square kernel of odd size, got shape {kern.shape}")
        if not np.all(np.isfinite(kern)) or np.any(kern < 0) \
                or abs(kern.sum() - 1.0) > 1e-6:
            raise ParameterError(
                f"'footprint' fractions must be >= 0 and sum to 1, got sum "
                f"{kern.sum()!r}")
        kern = kern / kern.sum()
        object.__setattr__(self, "footprint", tuple(tuple(row) for row in kern.tolist()))

    def draw_charge(self, n, *, rng):
        """Draw ``n`` total hit charges.

        Parameters
        ----------
        n : int
            Number of hits (>= 0).
        rng : numpy.random.Generator, int, SeedSequence or None

        Returns
        -------
        ndarray, shape (n,), int64, e-
            Whole electrons (the continuous draw rounded to the nearest integer).
        """
        n = check_int("n", n, minimum=0)
        rng = check_rng("rng", rng)
        if self.charge_distribution == "lognormal":
            s2 = math.log1p((self.charge_sigma / self.charge_mean) ** 2)
            mu = math.log(self.charge_mean) - 0.5 * s2
            q = rng.lognormal(mu, math.sqrt(s2), size=n)
        else:
            edges = np.asarray(self.charge_edges)
            weights = np.asarray(self.charge_weights)
            b = rng.choice(weights.size, size=n, p=weights / weights.sum())
            q = edges[b] + rng.random(n) * (edges[b + 1] - edges[b])
        return np.rint(q).astype(np.int64)


def _split_charge(model, total, rng):
    """Footprint offsets ``dy``, ``dx`` (flattened kernel order) and the multinomial
    split of each hit's whole-electron ``total`` over them, shape (n, kernel size)."""
    kern = np.asarray(model.footprint)
    half = kern.shape[0] // 2
    dy, dx = np.mgrid[-half:half + 1, -half:half + 1]
    dy, dx = dy.ravel(), dx.ravel()
    if not total.size:
        return dy, dx, np.zeros((0, dy.size), int)
    return dy, dx, rng.multinomial(total, kern.ravel())


def draw_cosmic_rays(model, shape, pixel_pitch_um, t_start, t_stop, *, rng,
                     refmask=None):
    """Draw the cosmic-ray deposits of one time span.

    Parameters
    ----------
    model : CosmicRayModel
    shape : tuple of int
        ``(ny, nx)`` of the read-out image.
    pixel_pitch_um : float
        Pixel pitch, micrometres (> 0).
    t_start, t_stop : float
        Time span, seconds (``t_stop >= t_start``).
    rng : numpy.random.Generator, int, SeedSequence or None
    refmask : ndarray of bool, shape (ny, nx), or None
        True for reference pixels (no charge collected there).

    Returns
    -------
    astropy.table.Table
        One row per (event, pixel) with non-zero charge, sorted by ``TIME``:
        ``EVENT`` (int64, 0-based, numbered in time order), ``TIME`` (float64, s),
        ``X``, ``Y`` (int64, pixel column and row), ``CHARGE`` (int64, e-).
        ``meta``: ``NEVENTS`` (hits drawn, including those that left no charge on
        regular pixels), ``RATE`` (cm^-2 s^-1), ``AREA`` (cm^2), ``TSTART``, ``TSTOP``
        (s), ``QOFFARR`` (e- that fell off the array), ``QREFPIX`` (e- dropped on
        reference pixels).

    Raises
    ------
    ParameterError
        Bad model, shape, pitch, times or refmask (checked before drawing).
    """
    if not isinstance(model, CosmicRayModel):
        raise ParameterError(
            f"'model' must be a CosmicRayModel, got {type(model).__name__}")
    ny, nx = check_shape("shape", shape)
    pitch = check_float("pixel_pitch_um", pixel_pitch_um, minimum=0.0, strict_min=True)
    t_start = check_float("t_start", t_start)
    t_stop = check_float("t_stop", t_stop)
    if t_stop < t_start:
        raise ParameterError(
            f"'t_stop' ({t_stop!r} s) must be >= 't_start' ({t_start!r} s)")
    if refmask is not None:
        refmask = check_mask("refmask", refmask, (ny, nx))

    try:
        area = ny * nx * (pitch * 1e-4) ** 2
    except OverflowError:                 # a pitch beyond 1e150 um
        area = math.inf
    expected = model.rate * area * (t_stop - t_start) if model.rate else 0.0
    if not expected <= MAX_EVENTS:
        raise ParameterError(
            f"'rate' = {model.rate!r} /cm^2/s over {area:.3g} cm^2 and "
            f"{t_stop - t_start:.6g} s gives {expected:.3g} expected hits; at most "
            f"{MAX_EVENTS:.3g} can be drawn (~0.7 kB each)")
    rng = check_rng("rng", rng)
    n = int(rng.poisson(expected))
    times = np.sort(rng.uniform(t_start, t_stop, size=n))
    hy = rng.integers(0, ny, size=n)
    hx = rng.integers(0, nx, size=n)
    total = model.draw_charge(n, rng=rng)
    dy, dx, split = _split_charge(model, total, rng)

    ys = hy[:, None] + dy[None, :]
    xs = hx[:, None] + dx[None, :]
    event = np.broadcast_to(np.arange(n)[:, None], ys.shape)
    on = (ys >= 0) & (ys < ny) & (xs >= 0) & (xs < nx)
    q_off = int(split[~on].sum())
    keep = on & (split > 0)
    if refmask is not None:
        ref = np.zeros_like(on)
        ref[on] = refmask[ys[on], xs[on]]
        q_ref = int(split[ref].sum())
        keep &= ~ref
    else:
        q_ref = 0

    table = Table()
    table["EVENT"] = event[keep].astype(np.int64)
    table["TIME"] = np.broadcast_to(times[:, None], ys.shape)[keep]
    table["X"] = xs[keep].astype(np.int64)
    table["Y"] = ys[keep].astype(np.int64)
    table["CHARGE"] = split[keep].astype(np.int64)
    table["TIME"].unit = "s"
    table["X"].unit = "pix"
    table["Y"].unit = "pix"
    table["CHARGE"].unit = "electron"
    table.meta.update({
        "NEVENTS": n, "RATE": model.rate, "AREA": area, "TSTART": t_start,
        "TSTOP": t_stop, "QOFFARR": q_off, "QREFPIX": q_ref,
    })
    return table
