"""Weigh numba for the engine's per-read pass (issue 16): numpy against one fused loop.

The pass is what ``ChargeEngine`` does to every pixel of every read after the draws
(``_pointwise`` without full well or non-linearity, then ``_digitise`` at gain 1):
the accumulated charge (float64) to the float32 read, the noise frame added, the ADC
code ``clip(rint(.), 0, 65535)`` added into the resultant's uint32 code sum.  numpy
makes six passes over memory; the numba loop (``nogil``) makes one.  The outputs are
checked bit for bit, then both are timed on one and two threads over the row blocks
of an H4RG read (8 blocks, as the engine cuts it for two threads), in back-to-back
pairs, with numba's import and first-call (JIT) time.

numba is not a dependency of scenesim; to run this::

    pip install --target /tmp/nbenv --no-deps numba llvmlite
    PYTHONPATH=/tmp/nbenv python tests/tools/numba_digitise.py

Every number printed is measured in that run.
"""

import sys
import time
from concurrent.futures import ThreadPoolExecutor

import numpy as np

from noise.adc import ADC

__all__ = ["main"]


_ADC = ADC(1.0)           # the engine's 16-bit ADC at gain 1


def _numpy_pass(acc, noise, q, dn, top):
    # ChargeEngine._pointwise (no full well, linear), then _digitise for a later read
    np.copyto(q, acc, casting="unsafe")
    codes = _ADC.codes(np.add(q, noise))
    np.add(dn, codes, out=dn, casting="unsafe")


def _compile():
    t0 = time.perf_counter()
    import numba
    t1 = time.perf_counter()

    @numba.njit(nogil=True)
    def fused(acc, noise, q, dn, top):
        ny, nx = acc.shape
        for i in range(ny):
            for j in range(nx):
                v = np.float32(acc[i, j])
                q[i, j] = v
                c = np.rint(v + noise[i, j])
                if c < 0:
                    c = np.float32(0)
                elif c > top:
                    c = top
                dn[i, j] += np.uint32(c)

    z = np.zeros((2, 2))
    fused(z, z.astype(np.float32), z.astype(np.float32), z.astype(np.uint32),
          np.float32(65535))
    return fused, t1 - t0, time.perf_counter() - t1


def main(size=4096, blocks=8, repeats=10, pairs=3):
    try:
        fused, t_import, t_jit = _compile()
    except ImportError:
        print("numba is not installed: nothing measured (see the module notes)")
        return 1
    print(f"import numba {t_import:.2f} s, first call (JIT, no cache) {t_jit:.2f} s")
    g = np.random.default_rng(1)
    acc = g.uniform(0, 300, (size, size))
    acc[0, :5] = [-5000.0, 1e9, 0.5, 1.5, 2.5]       # clipping and ties to even
    noise = g.normal(1000, 10, (size, size)).astype(np.float32)
    top = np.float32(65535)
    rows = size // blocks
    cuts = [slice(a, a + rows) for a in range(0, size, rows)]

    def run(fn, threads):
        q = np.empty((size, size), np.float32)
        dn = np.zeros((size, size), np.uint32)

        def one(b):
            fn(acc[b], noise[b], q[b], dn[b], top)

        with ThreadPoolExecutor(threads) as pool:
            t0 = time.perf_counter()
            for _ in range(repeats):
                if threads > 1:
                    list(pool.map(one, cuts))
                else:
                    for b in cuts:
                        one(b)
            return (time.perf_counter() - t0) / repeats, q, dn

    _, qa, da = run(_numpy_pass, 1)
    _, qb, db = run(fused, 1)
    same = np.array_equal(qa, qb) and np.array_equal(da, db)
    print(f"outputs bit-identical: {same}")
    for _ in range(pairs):
        for threads in (1, 2):
            tn, _, _ = run(_numpy_pass, threads)
            tf, _, _ = run(fused, threads)
            print(f"{threads} thread(s): numpy {tn * 1e3:.1f} ms, numba {tf * 1e3:.1f} ms "
                  f"per {size}^2 read (numpy / numba {tn / tf:.2f})")
    return 0 if same else 2


if __name__ == "__main__":
    sys.exit(main())
