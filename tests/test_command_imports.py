"""``scenesim noise`` imports only what a noise ramp needs.  (issue 16)

A user waits for the whole process, imports included: the scene, engine, fitting,
pipeline and batch modules (with astropy.table and asdf among their imports) cost
0.2-0.3 s that an empty ramp does not need.  The command runs in a fresh interpreter
and reports which modules it loaded; so does the benchmark's process of the noise
case, whose whole-process time is compared with the original NG program's.
"""

import json
import subprocess
import sys

from astropy.io import fits

#: Modules the noise command must not load: the scene machinery and its heavy imports.
NOT_FOR_NOISE = ("scenesim.engine", "scenesim.scene", "scenesim.run", "scenesim.rampfit",
                 "scenesim.calib", "scenesim.adapters", "scenesim.pipelines",
                 "scenesim.sky", "scenesim.io", "scenesim.bench", "astropy.table",
                 "asdf", "stcal")

DRIVER = """\
import json, sys
from scenesim.cli import main
code = main(sys.argv[1:])
print(json.dumps([code, sorted(sys.modules)]))
"""

BENCH_DRIVER = """\
import json, sys
from scenesim.bench.child import _main
code = _main(sys.argv[1:])
print(json.dumps([code, sorted(sys.modules)]))
"""


def _heavy(modules, allowed=()):
    """The modules of ``NOT_FOR_NOISE`` (and their submodules) among ``modules``."""
    return [m for m in modules if any(m == p or m.startswith(p + ".")
                                      for p in NOT_FOR_NOISE if p not in allowed)]


def test_noise_command_does_not_import_the_scene_machinery(tmp_path):
    out = tmp_path / "n.fits"
    proc = subprocess.run(
        [sys.executable, "-c", DRIVER, "noise", "--naxis", "64", "--n-out", "1",
         "--frames", "2", "--seed", "3", "-q", "-o", str(out)],
        cwd=tmp_path, capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr
    code, modules = json.loads(proc.stdout.splitlines()[-1])
    assert code == 0
    assert _heavy(modules) == [], _heavy(modules)
    # and it did its work: the ramp of 2 frames of 64x64
    with fits.open(out) as hdul:
        assert hdul[0].data.shape[-3:] == (2, 64, 64)


def test_bench_noise_process_does_not_import_the_scene_machinery(tmp_path):
    """The bench's noise case (one frame) in its own process, as ``scenesim bench``
    runs it (:mod:`scenesim.bench.child`)."""
    import pickle
    result = tmp_path / "r.pickle"
    proc = subprocess.run([sys.executable, "-c", BENCH_DRIVER, "noise", "1", "1",
                           str(result)], cwd=tmp_path, capture_output=True, text=True,
                          timeout=300)
    assert proc.returncode == 0, proc.stderr
    code, modules = json.loads(proc.stdout.splitlines()[-1])
    assert code == 0
    with open(result, "rb") as f:
        status, value = pickle.load(f)
    assert status == "ok" and value["output_bytes"] > 2048 * 2048 * 2, (status, value)
    heavy = _heavy(modules, allowed=("scenesim.bench",))
    assert heavy == [], heavy
