"""Jump detection on ramps with drops and spikes (``scenesim/rampfit/jumps.py``, "Drops").

10^4 pixels per cell: four readouts (RAPID x 10, 6 groups x 4 frames, the Roman
table of ``tests/ramp_sim.py``, RAPID x 4) at 0.5 and 20 e-/s, clean ramps, one or
two hits, a drop (a step down) and a spike in one resultant of 50-500 e- at a random
read; prints the mean z^2 of the slopes, their largest |z|, the flags and the
pixels left with no degree of freedom.  Run from the repository root:
``PYTHONPATH=$PWD python tests/tools/jump_drops.py`` (~1 min).
"""
import os
import sys
sys.path.insert(0, os.path.join(os.path.dirname(__file__), ".."))
import numpy as np
from ramp_sim import simulate, jwst_times, roman_times
from scenesim.rampfit import fit_ramps
ro = {"rapid10": jwst_times(10), "g4x6": jwst_times(6, 4), "roman": roman_times(), "rapid4": jwst_times(4)}

for name, times in ro.items():
    for rate, rn in ((0.5, 10.0), (20.0, 5.0)):
        for kind in ("clean", "hit", "two", "drop", "spike"):
            rng = np.random.default_rng([len(times), int(rate), int(rn), len(kind)])
            shape = (100, 100)
            res = simulate(rng, rate, times, rn, shape)
            n = len(times)
            k = np.arange(n)[:, None, None]
            i1 = rng.integers(1, n, shape); i2 = rng.integers(1, n, shape)
            amp = rng.uniform(50, 500, shape)
            if kind == "hit": res = res + amp * (k >= i1)
            if kind == "two": res = res + amp * (k >= i1) + amp * (k >= i2)
            if kind == "drop": res = res - amp * (k >= i1)
            if kind == "spike": res = res + amp * (k == i1)
            g = fit_ramps(res, times, read_noise=rn, jump_threshold=5.0)
            z = (g.slope - rate) / np.sqrt(g.var)
            print(f"{name:8s} {rate:5.1f} {kind:6s} z2 {np.mean(z**2):8.3f} |z|max {np.abs(z).max():8.2f} jumps {g.n_jumps.sum():6d} dof0 {(g.dof==0).sum():5d}", flush=True)
