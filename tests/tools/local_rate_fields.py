"""E[z^2] of fit_ramps' default variance_rate='local' on fields of known structure.

Run from the repository root: ``python tests/tools/local_rate_fields.py``.  Each line
is one field, read noise and the two seeds' ``E[z^2] = mean((f_hat - f)^2 / V_hat)``
over the selected pixels, with the count and the standard error ``sqrt(2 / n)``.
RAPID x 30 of 10 s, Poisson charge and Gaussian read noise drawn here, independent
of the simulator.  ``dark among bright``: the 0 e-/s pixels of 2-pixel stripes and of
a checkerboard of 0 and 1 e-/s (errors too large: the dark pixels take a share of
the bright ones' rate); ``0.3|1 checker``: the 0.3 e-/s pixels of a checkerboard of
0.3 and 1 e-/s (docs/VALIDATION_FIT.md, "Structured neighbourhoods").
"""

import numpy as np

from scenesim.rampfit import fit_ramps

N = 160
TIMES = [np.array([10.0 * (k + 1)]) for k in range(30)]


def fields():
    X, Y = np.meshgrid(np.arange(N), np.arange(N))
    checker = np.where((X + Y) % 2 == 1, 1.0, 0.0)
    stripes = np.where((X // 2) % 2 == 1, 1.0, 0.0)
    stars = sum(300 * np.exp(-((X - x0) ** 2 + (Y - y0) ** 2) / (2 * 1.2 ** 2))
                for x0, y0 in [(20.3, 30.6), (80.1, 90.9), (130.5, 40.2), (60.7, 140.1),
                               (110.2, 120.4)]) + 0.1
    return [("flat 0.05", np.full((N, N), 0.05), None),
            ("flat 10", np.full((N, N), 10.0), None),
            ("gradient 0-2", X / N * 2.0, None),
            ("checker, bright", checker, checker > 0),
            ("checker, dark", checker, checker == 0),
            ("stripes, dark", stripes, stripes == 0),
            ("0.3|1 checker, 0.3", 0.3 + 0.7 * checker, checker == 0),
            ("stars > 1 e-/s", stars, stars > 1)]


def main():
    inner = np.zeros((N, N), bool)
    inner[4:-4, 4:-4] = True
    for rn in (2.0, 10.0):
        for name, rate, sel in fields():
            m = inner if sel is None else inner & sel
            out = []
            for seed in (1, 2):
                rng = np.random.default_rng(seed)
                q = np.cumsum(rng.poisson(rate * 10.0, (30, N, N)), 0) \
                    + rng.normal(0, rn, (30, N, N))
                r = fit_ramps(q, TIMES, read_noise=rn)
                z2 = (r.slope - rate) ** 2 / (r.var_read + r.var_poisson)
                out.append(float(np.mean(z2[m])))
            print(f"read noise {rn:4.1f} e-  {name:18s} E[z^2] {out[0]:.3f} {out[1]:.3f}"
                  f"  (n = {int(m.sum())}, s.e. {np.sqrt(2 / m.sum()):.3f})")


if __name__ == "__main__":
    main()
