"""Cost of fit_ramps' input pass on the fit workload's standard cube (2048 x 2048 x
20 float32): the NaN count alone (the loop before 2026-11-27, replicated here) against
``scenesim.rampfit.fitter._check_finite`` (NaN count and largest |value|), best of 5.

    PYTHONPATH=$PWD python tests/tools/finite_check_cost.py
"""
import time, numpy as np
from scenesim.rampfit.fitter import _check_finite, _ArrayRows
from scenesim.rampfit.solver import row_chunks
cube = np.random.default_rng(1).standard_normal((1, 20, 2048, 2048), dtype=np.float32)
src = _ArrayRows(cube)
bounds = row_chunks(2048, 2048, 20, rows=None, threads=2)
def old():
    nbad = np.zeros((1, 20), np.int64)
    for y0, y1 in bounds:
        bad = ~np.isfinite(src.rows(y0, y1))
        nbad += bad.sum(axis=(2, 3))
for name, fn in (("old (isfinite + count)", old), ("new (+ max/min)", lambda: _check_finite(src, None, bounds))):
    best = 1e9
    for _ in range(5):
        t = time.perf_counter(); fn(); best = min(best, time.perf_counter() - t)
    print(f"{name}: {best*1e3:.0f} ms")
