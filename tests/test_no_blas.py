"""No BLAS or LAPACK in what a run writes.  (reproducibility across machines)

The same scene file and seed must give the same arrays on every machine.  BLAS and
LAPACK (``@``, ``np.dot``, ``np.linalg``, ``np.einsum(optimize=...)``,
``np.tensordot``) pick their kernels by CPU, and the kernels sum in different orders:
the ``READS`` tables of the three example scenes with multi-read resultants
(``TMEAN``, ``TAU``: dot products) differed in their last bits between two machines
of this project, and their pinned hashes failed.  The modules that compute what a
run writes (simulation, truth, files, ramp fit, reference correction) therefore use
element-wise numpy and exactly rounded sums (``math.fsum``) instead.  This test reads
their source (comments and strings left out) and names every BLAS or LAPACK entry
point it finds.

Not covered, on purpose: ``noise/calibrate.py`` (noise parameters estimated from
darks: an estimate with its own error bars), ``scenesim/validate/`` (studies that
print statistics) and ``scenesim/bench/`` (timings).
"""

import io
import os
import tokenize

import pytest

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
EXEMPT = {os.path.join("noise", "calibrate.py")}
EXEMPT_DIRS = (os.path.join("scenesim", "validate"), os.path.join("scenesim", "bench"))
#: numpy / scipy functions that dispatch to BLAS or LAPACK
BLAS_NAMES = {"dot", "matmul", "tensordot", "einsum", "inner", "vdot", "linalg",
              "multi_dot", "kron"}


def _modules():
    out = []
    for pkg in ("noise", "scenesim"):
        for base, _, files in os.walk(os.path.join(ROOT, pkg)):
            rel_dir = os.path.relpath(base, ROOT)
            if rel_dir.startswith(EXEMPT_DIRS):
                continue
            for name in files:
                rel = os.path.join(rel_dir, name)
                if name.endswith(".py") and rel not in EXEMPT:
                    out.append(rel)
    return sorted(out)


def blas_uses(source):
    """``(line, text)`` of every BLAS or LAPACK use in Python ``source``: the ``@``
    operator (not a decorator), ``X.dot(...)``, ``np.``/``numpy.``/``scipy.`` one of
    :data:`BLAS_NAMES`, and imports of ``linalg``."""
    toks = [t for t in tokenize.generate_tokens(io.StringIO(source).readline)
            if t.type not in (tokenize.COMMENT, tokenize.STRING, tokenize.NL)]
    found = []
    for i, t in enumerate(toks):
        prev = toks[i - 1] if i else None
        starts_line = prev is None or prev.type in (tokenize.NEWLINE, tokenize.INDENT,
                                                    tokenize.DEDENT)
        if t.type == tokenize.OP and t.string in ("@", "@=") and not starts_line:
            found.append((t.start[0], t.line.strip()))
        elif t.type == tokenize.NAME and t.string in BLAS_NAMES and prev is not None \
                and prev.string == "." and i >= 2:
            owner = toks[i - 2].string
            if t.string == "dot" or owner in ("np", "numpy", "scipy", "sp"):
                found.append((t.start[0], t.line.strip()))
        elif t.type == tokenize.NAME and t.string == "linalg" and prev is not None \
                and prev.string in (".", "import"):
            found.append((t.start[0], t.line.strip()))
    return found


@pytest.mark.parametrize("source, n", [
    ("y = a @ b\n", 1),
    ("y = np.dot(a, b) + x.dot(b)\n", 2),
    ("y = np.einsum('ij,j->i', a, b)\n", 1),
    ("from numpy import linalg\n", 1),
    ("import scipy.linalg\n", 1),
    ("y = numpy.tensordot(a, b, 1)\n", 1),
    ("@property\ndef f(self):\n    return 1\n", 0),
    ("class A:\n    @staticmethod\n    def f():\n        pass\n", 0),
    ("s = 'M @ reads, np.dot'  # a @ b, np.linalg\n", 0),
    ("y = self.solve(k) + np.sum(a * b)\n", 0),
])
def test_the_scanner_finds_blas_and_only_blas(source, n):
    assert len(blas_uses(source)) == n


def test_no_blas_in_what_a_run_writes():
    hits = []
    for rel in _modules():
        with open(os.path.join(ROOT, rel), encoding="utf-8") as f:
            hits += [f"{rel}:{line}: {text}" for line, text in blas_uses(f.read())]
    assert len(_modules()) > 50            # the walk found the packages
    assert hits == []
