"""E[z^2] of the fit's reported errors on digitised ramps with on-board rounded means,
with and without the rounding in the covariance (``resultant_noise``).

Ramps from ``tests/ramp_sim.py`` (independent of the simulator: Poisson charge, one
Gaussian read noise per read, a per-pixel bias, every read digitised, resultants the
rounded mean of their codes), read-noise dominated rates, the known rate passed as
``variance_rate``; 200 x 200 pixels, so the standard error of each E[z^2] is ~0.007.

    PYTHONPATH=tests python tests/tools/rounding_z2.py
"""

import numpy as np

import ramp_sim
from noise.adc import averaging_noise
from scenesim.rampfit import fit_ramps

PROBE_TABLE = ((0, 1), (1, 1), (3, 2), (8, 4), (16, 1), (30, 3))
READOUTS = {
    "MEDIUM8 x 10, 0.002 e-/s": (ramp_sim.jwst_times(10, nframes=8, groupgap=2), 0.002),
    "Roman 9-resultant table, 0.01 e-/s": (ramp_sim.roman_times(), 0.01),
    "6-resultant table, 0.01 e-/s": ([(np.arange(a, a + n) + 1) * ramp_sim.T_ROMAN
                                      for a, n in PROBE_TABLE], 0.01),
}


def main():
    print("| readout | gain e-/DN | read noise e- | seed | E[z^2] with q | E[z^2] without |")
    print("|---|---|---|---|---|---|")
    for name, (times, rate) in READOUTS.items():
        for gain, sigma in ((5.0, 6.0), (4.0, 3.0), (2.0, 5.0)):
            for seed in (11, 12):
                rng = np.random.default_rng(seed)
                res = ramp_sim.simulate(rng, rate, times, sigma, (200, 200), gain=gain)
                rn = float(np.hypot(sigma, gain / np.sqrt(12)))
                q = averaging_noise(gain, [len(t) for t in times])
                known = np.full(res.shape[1:], rate)
                cells = []
                for qq in (q, 0.0):
                    r = fit_ramps(res, times, read_noise=rn, resultant_noise=qq,
                                  variance_rate=known, threads=1)
                    z2 = (r.slope.astype(float) - rate) ** 2 / (
                        r.var_read.astype(float) + r.var_poisson)
                    cells.append(f"{z2.mean():.3f} +- {z2.std() / np.sqrt(z2.size):.3f}")
                print(f"| {name} | {gain:g} | {sigma:g} | {seed} | {cells[0]} | "
                      f"{cells[1]} |")


if __name__ == "__main__":
    main()
