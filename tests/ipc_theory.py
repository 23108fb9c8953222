"""The IPC operator as a dense matrix, written out from its rule (test helper).

Shared by ``tests/detector/test_ipc_inverse.py`` and ``tests/calib/test_prepare_ipc.py``;
independent of :mod:`scenesim.detector.ipc`.
"""

import numpy as np


def ipc_matrix(k, ny, nx):
    """Dense (ny nx, ny nx) IPC operator from the rule, written out."""
    n = ny * nx
    m = np.zeros((n, n))
    for y in range(ny):
        for x in range(nx):
            src = y * nx + x
            for dy in (-1, 0, 1):
                for dx in (-1, 0, 1):
                    ty, tx = y + dy, x + dx
                    if 0 <= ty < ny and 0 <= tx < nx:
                        m[ty * nx + tx, src] += k[1 + dy, 1 + dx]
                    else:
                        m[src, src] += k[1 + dy, 1 + dx]
    return m
