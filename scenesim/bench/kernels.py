"""What a second thread buys, kernel by kernel: ``python -m scenesim.bench.kernels``.

Why: the simulation workloads get 1.4-1.7x from one to two threads while their
limit's own work (large, GIL-free numpy calls) gets 1.8-1.9x (BENCHMARKS.md, issue 16).
This probe shows where the difference comes from: each kernel scenesim's per-read work
is made of, run by two threads at once (each doing the whole work, after a barrier)
against one thread doing it once.  ``speed-up = 2 * t(1 thread) / t(2 threads)``: 2
for work that shares nothing, 1 for work that holds the GIL throughout.

Every number printed is measured in that run; nothing is remembered.  The 1- and
2-thread runs are made in pairs, back to back, and the speed-up is the median of the
pairs' ratios: this machine's speed drifts by tens of percent within minutes
(BENCHMARKS.md), and a pair shares the machine's state.  The kernels are the real ones (scenesim's Box-Muller normals, the
overlap-save FFT sizes of :mod:`noise.pink`, stream construction, the Poisson draw of
one 65,536-pixel chunk over a uniform background with stars, and its parts).
"""

import argparse
import threading
import time

import numpy as np
import scipy.fft as sfft

from noise.errors import ParameterError, ParameterTypeError
from noise.fast import poisson as fp
from noise.fast.normal import standard_normal
from noise.streams import generator
from noise.validate import describe

__all__ = ["KERNELS", "chunk_means", "run_kernels", "main"]

_CHUNK = 65536          # pixels of one Poisson chunk of the charge engine


def chunk_means(seed=3, background=5.5, stars=3500):
    """Means (e-) of one engine chunk: a uniform background, ``stars`` pixels brighter
    (log-uniform over 5 decades above it), as the jwst workload's chunks hold."""
    rng = np.random.default_rng(seed)
    lam = np.full(_CHUNK, background)
    idx = rng.choice(_CHUNK, stars, replace=False)
    lam[idx] += 10 ** rng.uniform(-1, 5, stars)
    return lam


def _normals(n):
    def setup(g):
        out = np.empty(n, np.float32)
        return lambda: standard_normal(g, out)
    return setup


def _fft(rows, n):
    def setup(g):
        x = g.standard_normal((rows, n)).astype(np.float32)
        return lambda: sfft.irfft(sfft.rfft(x, axis=-1), n=n, axis=-1, overwrite_x=True)
    return setup


def _streams(g):
    key = [0]

    def run():
        key[0] += 1
        return generator(12345, (0, 1, 3, key[0]))
    return run


def _poisson(g):
    lam = chunk_means()
    return lambda: fp.poisson(g, lam)


def _guide_parts(g):
    lam = chunk_means()
    c = fp._dominant(lam)
    guide, _ = fp.guide_table(c)
    b = g.bit_generator.random_raw(_CHUNK // 4).view(np.uint16)
    return guide, b, lam, c


def _part(which):
    def setup(g):
        guide, b, lam, c = _guide_parts(g)
        k = np.take(guide, b)
        out = np.empty(_CHUNK, np.int64)
        other = lam[lam != c]
        return {"random_raw": lambda: g.bit_generator.random_raw(_CHUNK // 4),
                "take": lambda: np.take(guide, b),
                "nonzero": lambda: (k == 255).nonzero(),
                "copy": lambda: out.__setitem__(slice(None), k),
                "minmax": lambda: (lam.min(), lam.max()),
                "remainder": lambda: g.poisson(other)}[which]
    return setup


#: name -> (description, setup(generator) -> callable, calls per repeat)
KERNELS = {
    "normals_1m": ("Box-Muller normals, 1,048,576 per call", _normals(1 << 20), 20),
    "normals_115k": ("Box-Muller normals, 114,688 per call (one 1/f group)",
                     _normals(4 * 28672), 160),
    "normals_4k": ("Box-Muller normals, 4,096 per call", _normals(4096), 3000),
    "fft_4x32768": ("rfft + irfft of 4 x 32768 float32 (finest 1/f level)",
                    _fft(4, 32768), 80),
    "fft_1x8192": ("rfft + irfft of 1 x 8192 float32 (a coarse 1/f level)",
                   _fft(1, 8192), 1000),
    "streams": ("building one Generator(PCG64(SeedSequence(...)))",
                lambda g: _streams(g), 4000),
    "poisson": ("Poisson draw of one 65,536-pixel chunk (background + 3,500 stars)",
                _poisson, 200),
    "random_raw": ("... random_raw for the guide table", _part("random_raw"), 1000),
    "take": ("... np.take on the guide table", _part("take"), 1000),
    "nonzero": ("... nonzero of the marked buckets", _part("nonzero"), 2000),
    "copy": ("... uint8 -> int64 copy of the draws", _part("copy"), 2000),
    "minmax": ("... min / max check of the means", _part("minmax"), 1000),
    "remainder": ("... numpy's poisson for the 3,500 star pixels", _part("remainder"),
                  200),
}


def _timed(nthreads, setup, calls):
    """Wall time of ``nthreads`` threads each making ``calls`` calls (after a barrier)."""
    barrier = threading.Barrier(nthreads + 1)
    errors = []

    def work(seed):
        try:
            fn = setup(np.random.default_rng(seed))
            barrier.wait()
            for _ in range(calls):
                fn()
        except BaseException as exc:        # noqa: BLE001 (reported below)
            errors.append(exc)
            barrier.abort()

    threads = [threading.Thread(target=work, args=(s,)) for s in range(nthreads)]
    for t in threads:
        t.start()
    try:
        barrier.wait()
    except threading.BrokenBarrierError:
        pass
    t0 = time.perf_counter()
    for t in threads:
        t.join()
    if errors:
        raise errors[0]
    return time.perf_counter() - t0


def run_kernels(names=None, *, repeats=2, scale=1.0):
    """Time each kernel on 1 and on 2 threads; returns one dict per kernel.

    Parameters
    ----------
    names : sequence of str or None
        Keys of :data:`KERNELS` (default: all).
    repeats : int
        Pairs of runs (1 thread, then 2) of each kernel: the time per call is the
        best 1-thread run, the speed-up the median of the pairs' ratios.
    scale : float
        Fraction of the default calls per run (> 0; for tests).

    Returns
    -------
    list of dict
        ``name``, ``description``, ``us_per_call`` (1 thread), ``speedup``.
    """
    if names is None:
        names = list(KERNELS)
    elif not isinstance(names, (list, tuple)):
        raise ParameterTypeError(f"'names' must be a list of kernel names, got "
                                 f"{describe(names)}")
    bad = [n for n in names if not isinstance(n, str) or n not in KERNELS]
    if bad:
        raise ParameterError(f"'names' must be among {list(KERNELS)}, got {bad}")
    if isinstance(repeats, bool) or not isinstance(repeats, int) or repeats < 1:
        raise ParameterError(f"'repeats' must be an int >= 1, got {repeats!r}")
    if not isinstance(scale, (int, float)) or isinstance(scale, bool) or not scale > 0:
        raise ParameterError(f"'scale' must be a number > 0, got {scale!r}")
    rows = []
    for name in names:
        desc, setup, calls = KERNELS[name]
        calls = max(1, int(calls * scale))
        # 1 and 2 threads back to back, ``repeats`` times: the median of the paired
        # ratios (this machine's speed drifts by tens of percent within minutes)
        pairs = [(_timed(1, setup, calls), _timed(2, setup, calls))
                 for _ in range(repeats)]
        rows.append(dict(name=name, description=desc,
                         us_per_call=min(t1 for t1, _ in pairs) / calls * 1e6,
                         speedup=float(np.median([2 * t1 / t2 for t1, t2 in pairs]))))
    return rows


def main(argv=None):
    """Print the table (markdown) of :func:`run_kernels`."""
    ap = argparse.ArgumentParser(prog="python -m scenesim.bench.kernels",
                                 description=__doc__.split("\n")[0])
    ap.add_argument("names", nargs="*", help=f"kernels (default: all of {list(KERNELS)})")
    ap.add_argument("--repeats", type=int, default=5)
    args = ap.parse_args(argv)
    from noise.fast.memory import keep_freed_memory
    keep_freed_memory()
    try:
        rows = run_kernels(args.names or None, repeats=args.repeats)
    except ParameterError as exc:           # one line, before any work
        ap.error(str(exc))
    print(f"Two threads against one, each kernel ({time.strftime('%Y-%m-%d %H:%M:%S')};"
          f" median of {args.repeats} pairs)\n")
    print("| kernel | one call, 1 thread | speed-up, 2 threads |\n|---|---|---|")
    for r in rows:
        print(f"| {r['description']} | {r['us_per_call']:.1f} us | {r['speedup']:.2f} |")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
