"""Time the jump test alone: ``flag_jumps`` on 2^20 pixels x 19 RAPID differences
(10 e-/s, 10 e- read noise, no hits), best of 3.  Run it from two trees in
alternation to compare them (BENCHMARKS.md, "What the physics fixes of 2026-11-27
(evening) cost")::

    for i in 1 2 3; do
        PYTHONPATH=OLD_TREE python tests/tools/jump_test_cost.py old
        PYTHONPATH=NEW_TREE python tests/tools/jump_test_cost.py new
    done
"""

import sys
import time

import numpy as np

from scenesim.rampfit import RampCovariance, flag_jumps


def main(label):
    rng = np.random.default_rng(1)
    nd, npix = 19, 1 << 20
    cov = RampCovariance([np.array([0.1 * (i + 1)]) for i in range(nd + 1)])
    d = (10 + rng.standard_normal((1, nd, npix)).astype(np.float32) * 100)
    best = []
    for _ in range(3):
        valid = np.ones((1, nd, npix), bool)
        t = time.perf_counter()
        flag_jumps(d, valid, 25.0, cov, 5.0)
        best.append(time.perf_counter() - t)
    print(f"{label}: flag_jumps {min(best):.3f} s (best of 3)")


if __name__ == "__main__":
    main(sys.argv[1] if len(sys.argv) > 1 else "this tree")
