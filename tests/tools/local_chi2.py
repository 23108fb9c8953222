"""Mean GLS ``CHI2`` of faint uniform pixels, ``variance_rate='local'`` against
``'fit'`` (docs/VALIDATION_FIT.md, "Structured neighbourhoods" notes).

0.05 e-/s, 256^2 pixels, seeds 0-2, three readouts; prints the mean chi2 per dof and
its standard error (the pixels' scatter / sqrt(n)) per seed.  Run from the
repository root: ``PYTHONPATH=$PWD python tests/tools/local_chi2.py`` (~1 min).
"""

import os
import sys

import numpy as np

sys.path.insert(0, os.path.join(os.path.dirname(__file__), ".."))
from ramp_sim import jwst_times, simulate  # noqa: E402
from scenesim.rampfit import fit_ramps  # noqa: E402

CASES = [("3 x 4 frames, 1 e-", jwst_times(3, 4), 1.0),
         ("RAPID x 10, 1 e-", jwst_times(10, 1), 1.0),
         ("3 x 4 frames, 3 e-", jwst_times(3, 4), 3.0)]

if __name__ == "__main__":
    for name, times, rn in CASES:
        for rate_kind in ("local", "fit"):
            cells = []
            for seed in range(3):
                res = simulate(np.random.default_rng(seed), 0.05, times, rn,
                               (256, 256))
                g = fit_ramps(res, times, read_noise=rn, fitter="gls",
                              variance_rate=rate_kind)
                c = g.chi2[g.dof > 0].astype(float)
                cells.append(f"{c.mean():.4f} +- {c.std() / np.sqrt(c.size):.4f}")
            print(f"{name:20s} {rate_kind:6s} " + "  ".join(cells), flush=True)
