"""Write ``starfield.ecsv``: the seeded star catalogue of ``scenes/h2rg_starfield.toml``.

200 stars uniformly placed on the regular (non-reference) pixels of a 2048x2048 H2RG,
``4 <= x, y <= 2043`` (0-based pixel coordinates, centres at integers), with fluxes
log-uniform over four decades, 0.3 to 3000 e-/s (total over the PSF).  With a 2-pixel
FWHM Gaussian PSF a star centred on a pixel puts erf(0.5 / (sqrt(2) sigma))**2 = 19.7 %
of its flux in that pixel (sigma = 2 / 2.3548 pixels), so over the ~1050 s MEDIUM8 x 10
ramp the faintest stars sit below the 0.5 e-/s background and the brightest reach the
1e5 e- full well within ~200 s.

Run from anywhere: ``python scenes/data/make_starfield.py``.  The output is written
next to this script (atomically) and is the same on every run (seed below).
"""

import os

import numpy as np
from astropy.table import Table

SEED = 20240611
N_STARS = 200
LOW, HIGH = 4.0, 2043.0          # regular-pixel range of a 2048x2048 array, pixels
FLUX_MIN, FLUX_MAX = 0.3, 3000.0  # e-/s


def make_table(seed=SEED):
    """The catalogue as an astropy Table (columns x, y in pixels, flux in e-/s)."""
    rng = np.random.default_rng(seed)
    x = rng.uniform(LOW, HIGH, N_STARS)
    y = rng.uniform(LOW, HIGH, N_STARS)
    flux = np.exp(rng.uniform(np.log(FLUX_MIN), np.log(FLUX_MAX), N_STARS))
    table = Table({"x": np.round(x, 3), "y": np.round(y, 3),
                   "flux": np.array([float(f"{f:.4g}") for f in flux])})
    table["x"].description = "column, 0-based pixel coordinate (centres at integers)"
    table["y"].description = "row, 0-based pixel coordinate (centres at integers)"
    table["flux"].description = "total rate over the PSF, e-/s"
    table.meta["comments"] = [
        f"Synthetic star field for scenes/h2rg_starfield.toml: {N_STARS} stars, "
        f"seed {seed}, written by scenes/data/make_starfield.py"]
    return table


def main():
    path = os.path.join(os.path.dirname(os.path.abspath(__file__)), "starfield.ecsv")
    tmp = path + ".tmp"
    make_table().write(tmp, format="ascii.ecsv", overwrite=True)
    os.replace(tmp, path)
    print(f"wrote {path}")


if __name__ == "__main__":
    main()
