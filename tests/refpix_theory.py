"""The variance factor of an iteratively clipped mean, derived here (test helper).

Shared by the tests of :mod:`scenesim.calib.refpix` and
:mod:`scenesim.validate.refpix_study`; independent of the package's own closed form.
"""

import numpy as np
from scipy.stats import norm


def clip_factor(sigma=3.0, iters=5):
    """Variance factor of the clipped mean, derived from its influence function.

    The clip threshold in true sigmas starts at ``sigma`` (std of all values) and
    shrinks as the std of the kept values is used: k <- sigma sqrt(1 - 2 k phi(k) /
    P(k)), P = 1 - 2 Q(k), for the remaining ``iters - 1`` passes.  The estimate is the
    mean of the values within k of the sample median: its influence function is
    [x 1(|x| <= k) + 2 k phi(k) sqrt(pi/2) sign(x)] / P (moving the window by d moves
    the kept mean by 2 k phi(k) d / P; the median's influence is sqrt(pi/2) sign(x)),
    and c = E[IF^2] = [P - 2 k phi + 2 (2 k phi) sqrt(pi/2) E|x|1(|x|<=k)
    + (pi/2)(2 k phi)^2] / P^2 with E|x|1(|x|<=k) = 2 (phi(0) - phi(k)).
    """
    k = sigma
    for _ in range(iters - 1):
        k = sigma * np.sqrt(1 - 2 * k * norm.pdf(k) / (1 - 2 * norm.sf(k)))
    p, a = 1 - 2 * norm.sf(k), 2 * k * norm.pdf(k)
    e_abs = 2 * (norm.pdf(0) - norm.pdf(k))
    return (p - a + 2 * a * np.sqrt(np.pi / 2) * e_abs + np.pi / 2 * a ** 2) / p ** 2


C_CLIP = clip_factor()
