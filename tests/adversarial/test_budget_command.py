"""The commands against scenes too big for the machine: refused before any work.

Before issue 12, ``naxis = 400000`` or ``cosmic_ray_rate = 1e12`` ended in a
MemoryError traceback after the work had started (and ``scenesim noise --naxis
400000`` likewise).  Now ``scenesim run`` and ``scenesim noise`` estimate the memory
and output first (:mod:`scenesim.budget`) and refuse with one line naming the
estimate, the limit, the keys that drive it and ``--force``.  Each case runs the
command in a fresh directory and checks the exit status, exactly one stderr line
(what it names), no ``Traceback`` and the directory unchanged (hashes).

The huge cases are never run with ``--force`` (they would fill the machine): the
override and the warning are tested on a tiny scene, with the machine's available
memory (or the warning threshold) replaced in the command's own process by a small
driver script around :func:`scenesim.cli.main`.
"""

import hashlib
import os
import subprocess
import sys

import pytest
from astropy.io import fits

SCENE = """seed = 5
[detector]
preset = "H2RG"
naxis1 = {naxis}
naxis2 = {naxis}
[noise]
preset = "nirspec"
[readout]
pattern = "RAPID"
ngroups = 3
[sources]
background = 1.0
[effects]
cosmic_ray_rate = {rate}
[output]
path = "out.fits"
"""

#: ``(scene or noise arguments, what the error line must name)``: each huge case
#: with the key that drives it.
HUGE = {
    "run-naxis": ({"naxis": 400000, "rate": 0.0}, "naxis1"),
    "run-cosmic_ray_rate": ({"naxis": 64, "rate": 1e12}, "cosmic_ray_rate"),
    "noise-naxis": (["--naxis", "400000", "--frames", "5"], "--naxis"),
}

#: Runs ``scenesim.cli.main`` with the budget module changed first (``PATCH``: its
#: assignments, e.g. ``available_memory = lambda: 1e6``) and prints on stdout the
#: seconds ``main`` took after the imports (``scenesim.commands`` and the modules
#: its commands import when they start, the engine and the generator, loaded first:
#: on a slower disk those imports alone took 0.55-0.68 s of the measured time).
DRIVER = """\
import sys, time
import scenesim.budget as budget
import scenesim.commands, scenesim.run, scenesim.engine, noise.generator
from scenesim.cli import main
exec(sys.argv[1], vars(budget))
t0 = time.perf_counter()
code = main(sys.argv[2:])
print(f"{time.perf_counter() - t0:.6f}")
sys.exit(code)
"""


def _snapshot(directory):
    """``{name: sha256}`` of every file in ``directory`` (hidden ones included)."""
    out = {}
    for name in sorted(os.listdir(directory)):
        with open(os.path.join(directory, name), "rb") as f:
            out[name] = hashlib.sha256(f.read()).hexdigest()
    return out


def _one_line(stderr, *must_name):
    lines = [ln for ln in stderr.splitlines() if ln.strip()]
    assert len(lines) == 1, stderr
    assert "Traceback" not in stderr
    for word in must_name:
        assert word in lines[0], (word, lines[0])
    return lines[0]


def _argv(case, tmp_path):
    args, _ = HUGE[case]
    if case.startswith("run"):
        (tmp_path / "scene.toml").write_text(SCENE.format(**args))
        return ["run", "scene.toml", "-q"]
    return ["noise", *args, "-q", "-o", "n.fits"]


def _driver(tmp_path, patch, argv):
    (tmp_path / "driver.py").write_text(DRIVER)
    return subprocess.run([sys.executable, "driver.py", patch, *argv], cwd=tmp_path,
                          capture_output=True, text=True, timeout=300)


@pytest.mark.parametrize("case", list(HUGE))
def test_a_run_beyond_the_machine_is_refused_before_any_work(case, tmp_path):
    argv = _argv(case, tmp_path)
    before = _snapshot(tmp_path)
    res = subprocess.run([sys.executable, "-m", "scenesim.cli", *argv], cwd=tmp_path,
                         capture_output=True, text=True, timeout=120)
    assert res.returncode == 2, res.stderr
    line = _one_line(res.stderr, HUGE[case][1], "memory", "available", "--force")
    assert line.startswith(f"scenesim {argv[0]}: error: the run needs about ")
    assert _snapshot(tmp_path) == before


@pytest.mark.parametrize("case", list(HUGE))
def test_the_refusal_takes_milliseconds(case, tmp_path):
    # The command's own time after the imports (its wall time is mostly the ~1-2 s
    # of imports on a loaded machine).  Arithmetic on the scene's numbers takes
    # ~10 ms here; 0.5 s leaves room for a busy machine and is still far below any
    # allocation of the terabytes the run would need.
    argv = _argv(case, tmp_path)
    before = _snapshot(tmp_path)
    res = _driver(tmp_path, "", argv)
    assert res.returncode == 2, res.stderr
    _one_line(res.stderr, HUGE[case][1], "--force")
    assert float(res.stdout) < 0.5, res.stdout
    assert _snapshot(tmp_path) | {"driver.py": None} == before | {"driver.py": None}


TINY_MEMORY = "available_memory = lambda: 1e6"           # 1 MB: every run exceeds it
TINY = {
    "run": ["run", "scene.toml", "-q"],
    "noise": ["noise", "--naxis", "64", "--frames", "2", "-q", "-o", "out.fits"],
}


@pytest.mark.parametrize("command", list(TINY))
def test_force_skips_the_refusal_and_warns_in_one_line(command, tmp_path):
    (tmp_path / "scene.toml").write_text(SCENE.format(naxis=64, rate=0.0))
    before = _snapshot(tmp_path)
    refused = _driver(tmp_path, TINY_MEMORY, TINY[command])
    assert refused.returncode == 2, refused.stderr
    _one_line(refused.stderr, "977 kB available", "--force")
    assert set(_snapshot(tmp_path)) == set(before) | {"driver.py"}

    forced = _driver(tmp_path, TINY_MEMORY, TINY[command] + ["--force"])
    assert forced.returncode == 0, forced.stderr
    _one_line(forced.stderr, f"scenesim {command}: warning: forced: the run needs",
              "977 kB available")
    with fits.open(tmp_path / "out.fits") as hdul:
        hdul.verify("exception")
        assert hdul[1 if command == "run" else 0].data.shape[-2:] == (64, 64)


@pytest.mark.parametrize("command", list(TINY))
def test_a_run_above_the_warning_threshold_warns_in_one_line(command, tmp_path):
    # WARN_FRACTION = 0: any run is above the threshold; the limits still hold
    (tmp_path / "scene.toml").write_text(SCENE.format(naxis=64, rate=0.0))
    res = _driver(tmp_path, "WARN_FRACTION = 0.0", TINY[command])
    assert res.returncode == 0, res.stderr
    line = _one_line(res.stderr, f"scenesim {command}: warning: the run needs about ")
    assert "forced" not in line and "% of the" in line
    assert os.path.exists(tmp_path / "out.fits")


@pytest.mark.parametrize("command", list(TINY))
def test_no_warning_for_a_small_run(command, tmp_path):
    (tmp_path / "scene.toml").write_text(SCENE.format(naxis=64, rate=0.0))
    res = _driver(tmp_path, "", TINY[command])
    assert res.returncode == 0, res.stderr
    assert res.stderr == ""


def test_reference_files_beyond_the_machine_are_refused_before_any_work(tmp_path):
    # Issue 12: writing the reference files (--reffiles) peaked at 3.1 GB on the full
    # Roman frame, which the size check did not count: a run that fits but whose
    # references do not was started and died at the end.  With the available memory
    # set between the run's estimate and its estimate with the references (over the
    # 80 % limit), the command refuses in one line naming the products and writes
    # nothing; without --reffiles the same run goes through.
    pytest.importorskip("jwst")
    from scenesim.budget import MEMORY_FRACTION, estimate_budget
    from scenesim.scene import load_scene
    (tmp_path / "scene.toml").write_text(SCENE.format(naxis=64, rate=0.0))
    scene = load_scene(str(tmp_path / "scene.toml"))
    run_only = estimate_budget(scene).memory
    with_refs = estimate_budget(scene, products=("reffiles",)).memory
    assert with_refs > run_only
    avail = (run_only + with_refs) / 2 / MEMORY_FRACTION
    patch = f"available_memory = lambda: {avail!r}"
    # the limit (80 % of avail) is the midpoint of the two estimates: strictly between
    assert run_only <= MEMORY_FRACTION * avail < with_refs
    before = _snapshot(tmp_path)
    refused = _driver(tmp_path, patch, ["run", "scene.toml", "-q", "--reffiles"])
    assert refused.returncode == 2, refused.stderr
    _one_line(refused.stderr, "memory", "peak while writing the pipeline products "
              "(reffiles)",
              "--force")
    assert set(_snapshot(tmp_path)) == set(before) | {"driver.py"}
    ok = _driver(tmp_path, patch, ["run", "scene.toml", "-q"])
    assert ok.returncode == 0, ok.stderr
    assert os.path.exists(tmp_path / "out.fits")
