"""The ramp fitter's stress matrix: seeded ramps at the edges of its regime.

Runnable as ``python -m scenesim.validate.stress --out docs/STRESS.md``; the tests
(``tests/validate/test_stress.py``) check the acceptance thresholds on a seeded
subset.

What it does
------------
Each *cell* is one readout (RAPID, BRIGHT2, MEDIUM8, DEEP8 with ``ngroups`` groups,
or the illustrative Roman-like table of :mod:`scenesim.detector.readout`), one true
rate (e-/s), one read noise (e- **per read**, not CDS) and one cosmic-ray pattern
(none; one hit in the first, middle or last group; two hits).  ``side x side``
pixels of constant-rate ramps are simulated here, independently of the simulator:
Poisson charge between consecutive reads at their exact times from reset, Gaussian
read noise per read, reads averaged into resultants, in float64 (a hit adds its
charge to every read after its time).  They are fitted with
:func:`scenesim.rampfit.fit_ramps` (GLS, electrons in, jump threshold 5 sigma where
the cell has hits, default variance rate) and graded against the truth:

* ``bias``: mean of ``(slope - rate) / sqrt(V_opt)`` for ramps without hits
  (``V_opt`` = :func:`scenesim.rampfit.optimal_variance` of the full ramp at the
  true rate), of ``(slope - rate) / sqrt(V_reported)`` with hits (the usable ramp is
  shorter there);
* ``std_opt``: ``std(slope - rate) / sqrt(V_opt)`` (no hits);
* ``chi2_rep``: ``mean((slope - rate)^2 / V_reported)``, the calibration of the
  reported errors;
* ``lost``: fraction of pixels flagged ``DO_NOT_USE``;
* ``caught``: fraction of hit pixels with ``JUMP_DET`` (two hits: with two or more
  flagged differences).

Hit amplitudes are given in units of ``sigma_d``, the largest standard deviation of
a resultant difference at the cell's rate, so that "a 20 sigma hit" means the same
for every readout.  A hit in group ``g`` arrives at a uniform time between the last
read of group ``g - 1`` and the last read of group ``g`` (for the first group,
between the first read of group 0 and the last read of group 1, so that it lies in
the ramp), so it lands in the group or in the gap before it.

Standard errors (``side = 64``, 4096 pixels): ``bias`` 0.016, ``std_opt`` 0.011,
``chi2_rep`` ~0.022 for Gaussian errors (larger in the photon-counting cells, where
the errors are not Gaussian).
"""

import argparse
import sys
import time
import zlib
from dataclasses import dataclass

import numpy as np

from scenesim.detector.dq import DO_NOT_USE, JUMP_DET
from scenesim.detector.readout import ROMAN_LIKE_TABLE, Readout
from scenesim.rampfit import fit_ramps, optimal_variance

__all__ = ["Cell", "READOUTS", "default_cells", "measure_cell", "readout_times",
           "run_matrix", "simulate_ramps", "markdown", "main"]

#: Frame times (s): H2RG full frame (JWST patterns) and the Roman-like table.
T_JWST = 10.737
T_ROMAN = 3.04

#: Readouts of the matrix: name -> (pattern or None for the Roman-like table).
READOUTS = ("RAPID", "BRIGHT2", "MEDIUM8", "DEEP8", "ROMAN")

#: Jump patterns: where the hits are.
JUMPS = ("none", "first", "middle", "last", "two")


@dataclass(frozen=True)
class Cell:
    """One cell of the matrix.

    Attributes
    ----------
    readout : str
        One of :data:`READOUTS`.
    ngroups : int
        Groups (resultants) of a JWST pattern; ignored for ``'ROMAN'`` (9).
    rate : float
        True rate, e-/s (>= 0).
    read_noise : float
        e- per read (not CDS).
    jumps : str
        One of :data:`JUMPS`.
    amplitude : float
        Hit charge in units of ``sigma_d`` (module notes).
    """

    readout: str
    ngroups: int
    rate: float
    read_noise: float
    jumps: str = "none"
    amplitude: float = 20.0

    @property
    def label(self):
        """Readable name, e.g. ``'MEDIUM8x5'`` or ``'ROMAN9'``."""
        return "ROMAN9" if self.readout == "ROMAN" else f"{self.readout}x{self.ngroups}"

    def key(self):
        """Stable integer key of the cell (its random stream)."""
        return zlib.crc32(repr(self).encode())


def readout_times(readout, ngroups):
    """Read times (list of 1-D arrays, s from reset) of a matrix readout."""
    if readout == "ROMAN":
        return Readout.from_ma_table(ROMAN_LIKE_TABLE).read_times(T_ROMAN)
    return Readout.named(readout, ngroups).read_times(T_JWST)


def simulate_ramps(times, rate, read_noise, shape, *, rng, hits=None):
    """Resultants (e-, float64) of constant-rate ramps, independent of the simulator.

    Parameters
    ----------
    times : list of 1-D ndarray, s from reset
    rate : float, e-/s
    read_noise : float, e- per read
    shape : tuple of int, the image shape
    rng : numpy.random.Generator, keyword-only
    hits : list of (time, charge) arrays of ``shape``, optional
        Each adds ``charge`` (e-) to every read after ``time`` (s).

    Returns
    -------
    ndarray, shape (nres,) + shape, float64, e-
    """
    nres = len(times)
    out = np.zeros((nres,) + tuple(shape))
    q = np.zeros(shape)
    prev = 0.0
    for r, tr in enumerate(times):
        for t in tr:
            q += rng.poisson(rate * (t - prev), size=shape)
            read = q + read_noise * rng.standard_normal(shape)
            for th, amp in hits or ():
                read += np.where(th < t, amp, 0.0)
            out[r] += read
            prev = t
        out[r] /= len(tr)
    return out


def _sigma_d(times, rate, read_noise):
    """Largest standard deviation (e-) of a resultant difference at ``rate``."""
    n = np.array([len(t) for t in times], float)
    tb = np.array([t.mean() for t in times])
    tau = np.array([np.minimum.outer(t, t).mean() for t in times])
    var = read_noise ** 2 * (1 / n[:-1] + 1 / n[1:]) + rate * (
        tau[:-1] + tau[1:] - 2 * tb[:-1])
    return float(np.sqrt(var.max()))


def _hit_window(times, where):
    """(start, end) of the hit times (s) of a position (module notes)."""
    nres = len(times)
    if where == "first":
        return times[0][0], times[1][-1]
    g = nres // 2 if where == "middle" else nres - 1
    return times[g - 1][-1], times[g][-1]


def _hits(cell, times, shape, rng):
    """The hits of a cell: list of (time, charge) arrays."""
    if cell.jumps == "none":
        return None
    amp = cell.amplitude * _sigma_d(times, cell.rate, cell.read_noise)
    if cell.jumps == "two":
        # first and last thirds of the ramp: separated by at least one difference
        nres = len(times)
        out = []
        for lo, hi in ((0, nres // 3), (nres - 1 - nres // 3, nres - 1)):
            t = rng.uniform(times[lo][-1], times[max(hi, lo + 1)][-1], shape)
            out.append((t, np.full(shape, amp)))
        return out
    a, b = _hit_window(times, cell.jumps)
    return [(rng.uniform(a, b, shape), np.full(shape, amp))]


def measure_cell(cell, *, side=64, rng=None, threads=1):
    """Simulate and fit one cell; return its metrics.

    Parameters
    ----------
    cell : Cell
    side : int, keyword-only
        Pixels per side of the simulated image.
    rng : Generator | int | SeedSequence | None, keyword-only
    threads : int, keyword-only
        Threads of the fit.

    Returns
    -------
    dict
        ``cell``, ``npix``, ``bias``, ``std_opt`` (NaN with hits), ``chi2_rep``,
        ``lost``, ``caught`` (NaN without hits), ``seconds``.
    """
    rng = np.random.default_rng(rng)
    times = readout_times(cell.readout, cell.ngroups)
    shape = (side, side)
    t0 = time.perf_counter()
    hits = _hits(cell, times, shape, rng)
    res = simulate_ramps(times, cell.rate, cell.read_noise, shape, rng=rng, hits=hits)
    thr = None if hits is None else 5.0
    g = fit_ramps(res, times, read_noise=cell.read_noise, jump_threshold=thr,
                  threads=threads)
    e = g.slope.astype(float) - cell.rate
    var = g.var.astype(float)
    live = (g.dq & DO_NOT_USE) == 0
    el, vl = e[live], var[live]
    out = dict(cell=cell, npix=e.size, lost=float(np.mean(~live)),
               chi2_rep=float(np.mean(el ** 2 / vl)) if el.size else np.nan,
               caught=np.nan, std_opt=np.nan)
    if hits is None:
        vopt = optimal_variance(cell.rate, times, cell.read_noise)
        out["bias"] = float(np.mean(el) / np.sqrt(vopt))
        out["std_opt"] = float(np.std(el) / np.sqrt(vopt))
    else:
        out["bias"] = float(np.mean(el / np.sqrt(vl))) if el.size else np.nan
        need = 2 if cell.jumps == "two" else 1
        flagged = (g.dq & JUMP_DET) > 0
        out["caught"] = float(np.mean(flagged & (g.n_jumps >= need)))
    out["seconds"] = time.perf_counter() - t0
    return out


#: Default axes of the matrix.
RATES = (0.0, 1e-3, 0.1, 10.0, 1e3, 1e5, 1e7)
READ_NOISES = (0.1, 1.0, 10.0, 100.0)
NOJUMP_READOUTS = (("RAPID", 2), ("RAPID", 10), ("RAPID", 100), ("RAPID", 1000),
                   ("BRIGHT2", 10), ("MEDIUM8", 5), ("DEEP8", 5), ("ROMAN", 9))
JUMP_READOUTS = (("RAPID", 10), ("BRIGHT2", 10), ("MEDIUM8", 5), ("DEEP8", 5),
                 ("ROMAN", 9))


def default_cells():
    """The cells of the documented matrix (``docs/STRESS.md``)."""
    cells = [Cell(ro, ng, rate, rn) for ro, ng in NOJUMP_READOUTS for rate in RATES
             for rn in READ_NOISES]
    for ro, ng in JUMP_READOUTS:
        for where in ("first", "middle", "last", "two"):
            for rate in (1.0, 100.0):
                for amp in (20.0, 200.0):
                    cells.append(Cell(ro, ng, rate, 10.0, where, amp))
    return cells


def run_matrix(cells=None, *, side=64, rng=None, threads=1, progress=None):
    """Measure every cell; each draws from its own stream keyed by the cell.

    Parameters
    ----------
    cells : sequence of Cell, optional
        Default :func:`default_cells`.
    side : int, keyword-only
    rng : int | SeedSequence | None, keyword-only
        Root seed; cell ``c`` uses ``SeedSequence([root entropy, c.key()])``, so
        results do not depend on which other cells run or in which order.
    threads : int, keyword-only
    progress : callable or None
        Called with each result.

    Returns
    -------
    list of dict (see :func:`measure_cell`)
    """
    root = rng if isinstance(rng, np.random.SeedSequence) else \
        np.random.SeedSequence(rng)
    out = []
    for cell in default_cells() if cells is None else cells:
        ss = np.random.SeedSequence([root.entropy, cell.key()])
        r = measure_cell(cell, side=side, rng=np.random.default_rng(ss),
                         threads=threads)
        out.append(r)
        if progress is not None:
            progress(r)
    return out


def _fmt(x, spec):
    return "-" if x is None or not np.isfinite(x) else format(x, spec)


def markdown(results, *, side, seed, command):
    """The matrix as a markdown document (``docs/STRESS.md``)."""
    lines = [
        "# The ramp fitter's stress matrix",
        "",
        f"Generated by `{command}` (seed {seed}, {side} x {side} pixels per cell);",
        "the definitions are in the docstring of `scenesim/validate/stress.py`, the",
        "acceptance tests in `tests/validate/test_stress.py`. Read noise is per read",
        "(e-), rates in e-/s; GLS fit, default variance rate, jump threshold 5 sigma",
        "where the cell has hits.",
        "",
        f"Standard errors at {side * side} pixels: bias "
        f"{1 / side:.3f}, std_opt {1 / (side * np.sqrt(2)):.3f}, chi2_rep "
        f"{np.sqrt(2) / side:.3f} (Gaussian errors).",
        "",
        "## Without cosmic rays",
        "",
        "Each entry: bias (sigma of the optimum) / std_opt / chi2_rep.",
        "",
    ]
    nojump = [r for r in results if r["cell"].jumps == "none"]
    rns = sorted({r["cell"].read_noise for r in nojump})
    labels = []
    for r in nojump:
        if r["cell"].label not in labels:
            labels.append(r["cell"].label)
    for lab in labels:
        rows = [r for r in nojump if r["cell"].label == lab]
        lines += [f"### {lab}", "",
                  "| rate e-/s | " + " | ".join(f"rn {rn:g} e-" for rn in rns) + " |",
                  "|---|" + "---|" * len(rns)]
        for rate in sorted({r["cell"].rate for r in rows}):
            ent = []
            for rn in rns:
                m = [r for r in rows if r["cell"].rate == rate and
                     r["cell"].read_noise == rn]
                if not m:
                    ent.append("")
                    continue
                r = m[0]
                ent.append(f"{_fmt(r['bias'], '+.3f')} / {_fmt(r['std_opt'], '.3f')}"
                           f" / {_fmt(r['chi2_rep'], '.2f')}"
                           + (f" (lost {r['lost']:.3f})" if r["lost"] > 0 else ""))
            lines.append(f"| {rate:g} | " + " | ".join(ent) + " |")
        lines.append("")
    jumps = [r for r in results if r["cell"].jumps != "none"]
    if jumps:
        lines += [
            "## With cosmic rays",
            "",
            "Read noise 10 e-. Hit amplitude in sigma_d (the largest standard "
            "deviation of a resultant difference at the rate); bias in sigma of the "
            "reported error; caught: fraction of pixels with every hit flagged "
            "(two hits: two or more flagged differences).",
            "",
            "| readout | hits | rate e-/s | amplitude | lost | caught | bias | "
            "chi2_rep |",
            "|---|---|---|---|---|---|---|---|",
        ]
        for r in jumps:
            c = r["cell"]
            lines.append(
                f"| {c.label} | {c.jumps} | {c.rate:g} | {c.amplitude:g} | "
                f"{r['lost']:.3f} | {_fmt(r['caught'], '.4f')} | "
                f"{_fmt(r['bias'], '+.3f')} | {_fmt(r['chi2_rep'], '.2f')} |")
        lines.append("")
    return "\n".join(lines)


def main(argv=None):
    """Command line: ``python -m scenesim.validate.stress [--out FILE]``."""
    p = argparse.ArgumentParser(prog="python -m scenesim.validate.stress",
                                description=__doc__.splitlines()[0])
    p.add_argument("--out", help="markdown file to write (default: print)")
    p.add_argument("--side", type=int, default=64, help="pixels per side (64)")
    p.add_argument("--seed", type=int, default=2024, help="root seed (2024)")
    p.add_argument("--threads", type=int, default=1)
    args = p.parse_args(argv)

    def progress(r):
        c = r["cell"]
        print(f"[stress] {c.label} rate {c.rate:g} rn {c.read_noise:g} {c.jumps} "
              f"{c.amplitude:g}: bias {r['bias']:+.3f} std_opt {r['std_opt']:.3f} "
              f"chi2 {r['chi2_rep']:.3f} lost {r['lost']:.3f} caught "
              f"{r['caught']:.4f} ({r['seconds']:.1f} s)", file=sys.stderr,
              flush=True)

    results = run_matrix(side=args.side, rng=args.seed, threads=args.threads,
                         progress=progress)
    cmd = "python -m scenesim.validate.stress --out docs/STRESS.md"
    if args.side != 64 or args.seed != 2024:
        cmd += f" --side {args.side} --seed {args.seed}"
    text = markdown(results, side=args.side, seed=args.seed, command=cmd)
    if args.out:
        with open(args.out, "w") as fh:
            fh.write(text)
    else:
        print(text)
    return 0


if __name__ == "__main__":
    sys.exit(main())
