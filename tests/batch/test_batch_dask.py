"""``scenesim batch`` on real dask clusters (``LocalCluster`` with worker processes).

What the issue asks of a batch, each checked on the small scene of ``conftest.py``:

* 8 realisations on 2 workers give the same science arrays (exposure, truth, fit)
  as 1 worker and as ``scenesim run --seed`` run one by one;
* a worker killed (SIGKILL) during the batch: the batch completes, no partial,
  temporary or duplicate file, the arrays unchanged;
* Ctrl-C (SIGINT to the whole process group, as a terminal sends it) stops the
  command cleanly; re-running it completes the rest without recomputing finished
  tasks (their files keep their modification times);
* bad input (an address no scheduler answers, a grid key that is not a scene key,
  another batch's manifest) is one error line before any task starts, nothing
  written;
* ``--compare`` pools the comparison of our GLS and stcal's OLS_C over realisations,
  and ``scenesim compare --pool`` prints the same tables.
"""

import glob
import json
import os
import signal
import socket
import subprocess
import sys
import time

import numpy as np
import pytest
from astropy.io import fits

from scenesim.batch.manifest import load_record
from scenesim.batch.plan import plan_batch
from scenesim.batch.runner import run_batch
from scenesim.cli import main

# dask.distributed is part of the [test] extra: no skip if it is missing.
# Its client leaves process-wide threads behind: these tests run last (conftest).
pytestmark = pytest.mark.leaves_threads

N = 8


def _hdus(path):
    """``{extension name: data bytes}`` of every HDU with data (images and tables)."""
    with fits.open(path) as hdul:
        return {h.name: np.asarray(h.data).tobytes() for h in hdul if h.data is not None}


def _science(paths):
    """Arrays of the exposure, truth and GLS fit of one realisation."""
    return {k: _hdus(paths[k]) for k in ("exposure", "truth", "gls")}


def _temps(directory):
    return glob.glob(os.path.join(directory, "**", ".scenesim-*"), recursive=True)


@pytest.fixture(scope="module")
def reference(tmp_path_factory):
    """The small scene and its 8-realisation batch on a 2-worker local cluster."""
    from tests.batch.conftest import SMALL_SCENE
    root = tmp_path_factory.mktemp("batch")
    scene = root / "small.toml"
    scene.write_text(SMALL_SCENE)
    plan = plan_batch(scene, out=root / "w2", realisations=N)
    before = dict(os.environ)
    res = run_batch(plan, workers=2, progress=False)
    # dask's nanny puts OMP_NUM_THREADS=1, MALLOC_TRIM_THRESHOLD_=65536, ... in the
    # environment of the process that starts the cluster: the batch puts it back,
    # so the caller's later subprocesses are not slowed or single-threaded
    assert dict(os.environ) == before
    return scene, plan, res


def test_batch_timings_split_start_up_from_tasks(reference):
    _, _, res = reference
    # the whole call is the start-up, the tasks and the stop, each positive
    assert 0 < res.startup_seconds and 0 < res.task_seconds
    assert res.startup_seconds + res.task_seconds < res.seconds


def test_two_workers_equal_one_worker_and_run_seed(reference, tmp_path):
    scene, plan2, res2 = reference
    assert sorted(res2.ran) == [f"r{k:04d}" for k in range(N)] and res2.workers == 2
    plan1 = plan_batch(scene, out=tmp_path / "w1", realisations=N)
    res1 = run_batch(plan1, workers=1, progress=False)
    assert res1.workers == 1 and len(res1.ran) == N
    with open(os.path.join(plan2.out_dir, "batch.json"), encoding="utf-8") as fh:
        manifest = json.load(fh)
    for t2, t1 in zip(plan2.tasks(), plan1.tasks()):
        assert t1.seed == t2.seed
        one = tmp_path / "one" / f"{t2.name}.fits"
        one.parent.mkdir(exist_ok=True)
        assert main(["run", str(scene), "--seed", str(t2.seed), "-o", str(one),
                     "-q"]) == 0
        run_paths = {"exposure": str(one), "truth": str(one)[:-5] + "_truth.fits",
                     "gls": str(one)[:-5] + "_gls.fits"}
        ref = _science(t2.path)
        assert _science(t1.path) == ref
        assert _science(run_paths) == ref
        # the seed is recorded in the outputs and in the manifest
        for kind in ("exposure", "truth"):
            hdr = fits.getheader(t2.path[kind])
            assert hdr["SEED"] == t2.seed and hdr["BATCHSD"] == 777
            assert hdr["BATCHKEY"] == str(t2.realisation)
        row = manifest["tasks"][t2.name]
        assert row["seed"] == t2.seed and row["status"] == "done" and row["params"] == []
        assert row["outputs"]["gls"] == f"{t2.name}_gls.fits"
        assert row["files"]["exposure"]["sha256"]
    assert not _temps(plan2.out_dir)


def test_killed_worker_is_retried_without_partial_files(reference, tmp_path):
    """SIGKILL one worker while the other finishes a task: dask reschedules the
    killed worker's task, the nanny restarts the worker, and every file is whole."""
    from distributed import Client, LocalCluster
    scene, ref_plan, _ = reference
    plan = plan_batch(scene, out=tmp_path / "k", realisations=N)
    killed = []
    with LocalCluster(n_workers=2, threads_per_worker=1, processes=True,
                      dashboard_address=None) as cluster, Client(cluster) as client:
        pids = set(client.run(os.getpid).values())

        def kill_the_busy_one(task, record):
            if not killed:
                victim = next(p for p in pids if p != record["pid"])
                os.kill(victim, signal.SIGKILL)
                killed.append(victim)

        # an existing cluster, reached through a scheduler file as dask-jobqueue
        # or `dask scheduler --scheduler-file` write it
        sched = tmp_path / "scheduler.json"
        sched.write_text(json.dumps({"address": cluster.scheduler_address}))
        res = run_batch(plan, scheduler=str(sched), progress=False,
                        on_result=kill_the_busy_one)
        after = set(client.run(os.getpid).values())
    assert killed and killed[0] not in after
    assert not res.failed and len(res.ran) == N
    assert not _temps(plan.out_dir)
    names = sorted(os.listdir(plan.out_dir))
    assert len([n for n in names if n.endswith("_truth.fits")]) == N
    for t, r in zip(plan.tasks(), ref_plan.tasks()):
        assert load_record(t) is not None
        assert _science(t.path) == _science(r.path)


def _default_signals():
    """In the child: the default dispositions of the signals sent.  A background job
    of a non-interactive shell (``pytest ... &``, ``nohup``) inherits SIGINT as
    ignored, and Python then never raises KeyboardInterrupt; a user's command starts
    with the defaults."""
    for sig in (signal.SIGINT, signal.SIGTERM, signal.SIGHUP):
        signal.signal(sig, signal.SIG_DFL)


def _wait_for(predicate, timeout):
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        if predicate():
            return True
        time.sleep(0.05)
    return False


def test_interrupt_then_resume_recomputes_nothing_finished(reference, tmp_path):
    scene, ref_plan, _ = reference
    out = tmp_path / "i"
    n = 24
    cmd = [sys.executable, "-m", "scenesim.cli", "batch", str(scene), "-n", str(n),
           "--out", str(out), "--workers", "2", "-q"]
    proc = subprocess.Popen(cmd, start_new_session=True, preexec_fn=_default_signals,
                            stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True)
    try:
        assert _wait_for(lambda: len(glob.glob(str(out / "r*.json"))) >= 3, 120)
        os.killpg(proc.pid, signal.SIGINT)            # Ctrl-C: the whole group
        _, err = proc.communicate(timeout=60)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    assert proc.returncode == 130, err
    # one line: the workers (in the same process group, as under a terminal) never
    # see the SIGINT, so none prints a KeyboardInterrupt of its own
    assert err.strip().splitlines() == [
        "scenesim batch: interrupted (SIGINT); the finished tasks are kept (the same "
        "command resumes the batch); no partial output was left"], err
    assert not _temps(str(out))
    plan = plan_batch(scene, out=out, realisations=n)
    tasks = plan.tasks()
    finished = [t for t in tasks if load_record(t) is not None]
    assert 3 <= len(finished) < n
    manifest = json.loads((out / "batch.json").read_text())
    assert {k for k, r in manifest["tasks"].items() if r["status"] == "done"} <= \
        {t.name for t in finished}
    mtimes = {t.name: {k: os.stat(p).st_mtime_ns for k, p in t.paths}
              for t in finished}
    res = run_batch(plan, workers=2, progress=False)
    assert sorted(res.skipped) == sorted(mtimes)
    assert len(res.ran) == n - len(finished)
    for t in finished:
        assert {k: os.stat(p).st_mtime_ns for k, p in t.paths} == mtimes[t.name]
    for t, r in zip(tasks[:N], ref_plan.tasks()):
        assert _science(t.path) == _science(r.path)
    assert not _temps(str(out))


def _free_port():
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def test_quiet_batch_prints_nothing_when_port_8787_is_taken(small_scene, tmp_path):
    # a probe: with another cluster's dashboard on dask's default port, a -q batch
    # printed distributed's three-line "Port 8787 is already in use" warning
    held = socket.socket()
    try:
        held.bind(("127.0.0.1", 8787))
        held.listen()
    except OSError:
        pass                                    # taken already: the case itself
    try:
        proc = subprocess.run(
            [sys.executable, "-m", "scenesim.cli", "batch", str(small_scene), "-n", "1",
             "--out", str(tmp_path / "q"), "--workers", "1", "-q"],
            capture_output=True, text=True, timeout=300)
    finally:
        held.close()
    assert proc.returncode == 0, proc.stderr
    assert proc.stderr == "" and proc.stdout == ""


def test_bad_input_is_one_error_before_any_task(small_scene, tmp_path, capsys):
    out = tmp_path / "o"
    # an address no scheduler answers
    t0 = time.monotonic()
    rc = main(["batch", str(small_scene), "-n", "2", "--out", str(out), "--scheduler",
               f"tcp://127.0.0.1:{_free_port()}", "--connect-timeout", "1"])
    err = capsys.readouterr().err.strip()
    assert rc == 2 and len(err.splitlines()) == 1, err
    assert "no dask scheduler answered within 1 s" in err
    assert time.monotonic() - t0 < 30 and not out.exists()
    rc = main(["batch", str(small_scene), "--out", str(out), "--scheduler", "nowhere"])
    err = capsys.readouterr().err
    assert rc == 2 and "neither an address" in err and not out.exists()
    # a grid key that is not a scene key
    grid = small_scene.parent / "grid.toml"
    grid.write_text('scene = "small.toml"\n[grid]\n"effects.ipc_alfa" = [0.01]\n')
    rc = main(["batch", str(grid), "--out", str(out)])
    err = capsys.readouterr().err
    assert rc == 2 and "'effects.ipc_alfa'" in err and "did you mean 'ipc_alpha'" in err
    assert not out.exists()
    # an output directory holding another batch's manifest
    other = plan_batch(small_scene, out=out, realisations=1, seed=1)
    out.mkdir()
    manifest = {"format": "scenesim-batch 1", "identity": other.identity(),
                "tasks": {}}
    (out / "batch.json").write_text(json.dumps(manifest))
    before = sorted(os.listdir(out))
    rc = main(["batch", str(small_scene), "-n", "2", "--out", str(out), "--seed", "2"])
    err = capsys.readouterr().err
    assert rc == 2 and "holds the manifest of another batch" in err
    assert "differs in seed" in err
    assert sorted(os.listdir(out)) == before
    (out / "batch.json").write_text("{}")
    rc = main(["batch", str(small_scene), "--out", str(out)])
    assert rc == 2 and "not a scenesim batch manifest" in capsys.readouterr().err
    # files named like the batch's outputs, but no manifest: never replaced
    (out / "batch.json").unlink()
    (out / "r0001_truth.fits").write_bytes(b"mine")
    rc = main(["batch", str(small_scene), "-n", "2", "--out", str(out)])
    err = capsys.readouterr().err
    assert rc == 2 and "no batch manifest" in err and "'r0001_truth.fits'" in err
    assert (out / "r0001_truth.fits").read_bytes() == b"mine"
    assert sorted(os.listdir(out)) == ["r0001_truth.fits"]


def test_compare_pools_gls_and_stcal(small_scene, tmp_path, capsys):
    pytest.importorskip("stcal")
    out = tmp_path / "c"
    rc = main(["batch", str(small_scene), "-n", "3", "--out", str(out), "--fit",
               "gls,stcal-ols_c", "--compare", "--workers", "1", "--no-ramp"])
    text = capsys.readouterr().out
    assert rc == 0
    assert "Pooled: small.toml fitter gls: 3 realisations" in text
    assert "fitter stcal-ols_c: 3 realisations" in text
    assert "jumps: completeness" in text
    assert not glob.glob(str(out / "r000?.fits"))          # --no-ramp: no ramps
    assert len(glob.glob(str(out / "r*_stcal-ols_c.fits"))) == 3
    manifest = json.loads((out / "batch.json").read_text())
    gls = manifest["pooled"][""]["gls"]
    assert gls["n_real"] == 3 and gls["jumps"]["n_hit"] > 0
    # GLS flags jumps; stcal's OLS_C is run without jump detection
    assert gls["jumps"]["completeness"] > 0.5
    assert manifest["pooled"][""]["stcal-ols_c"]["jumps"]["completeness"] == 0
    assert main(["compare", "--pool", str(out)]) == 0
    assert capsys.readouterr().out.strip() == text[text.index("Pooled:"):].strip()
    # a smaller -n: the batch pools its 2, and so does --pool (it had pooled the 3
    # rows the manifest keeps for a later resume)
    rc = main(["batch", str(small_scene), "-n", "2", "--out", str(out), "--fit",
               "gls,stcal-ols_c", "--compare", "--workers", "1", "--no-ramp"])
    text = capsys.readouterr().out
    assert rc == 0 and "fitter gls: 2 realisations" in text
    assert main(["compare", "--pool", str(out)]) == 0
    assert capsys.readouterr().out.strip() == text[text.index("Pooled:"):].strip()
    # a damaged record: refused, naming it (it had been left out without a word)
    (out / "r0001.json").write_text("{")
    assert main(["compare", "--pool", str(out)]) == 2
    err = capsys.readouterr().err
    assert "1 of the 2 finished tasks" in err and "r0001" in err


def test_a_tasks_own_warnings_are_said_once_in_one_line(small_scene, tmp_path,
                                                         capsys):
    # A star off the array warns in every task (a probe: Python's two-line form,
    # once per task, on the workers' stderr): said once, as one line, by the
    # command; the record keeps it
    text = small_scene.read_text().replace("x = 45.2", "x = 1e6")
    scene = small_scene.parent / "off.toml"
    scene.write_text(text)
    out = tmp_path / "b"
    rc = main(["batch", str(scene), "-n", "2", "--out", str(out), "--workers", "1",
               "-q"])
    err = capsys.readouterr().err
    assert rc == 0, err
    lines = [ln for ln in err.splitlines() if "warning" in ln]
    assert len(lines) == 1 and lines[0].startswith(
        "scenesim batch: warning: 1 of 2 stars put no charge"), err
    rec = json.loads((out / "r0001.json").read_text())
    assert len(rec["warnings"]) == 1 and "(1e+06, 15.1)" in rec["warnings"][0]


def test_an_extended_batch_never_writes_over_a_file_its_scene_reads(small_scene,
                                                                    tmp_path, capsys):
    # the scene's background map lies in the output directory under the name of
    # realisation 1's truth: -n 1 runs; -n 2 (an extension) had replaced the map
    # (a probe; the name check ran only without a manifest): refused, untouched
    from astropy.io import fits as _fits
    out = tmp_path / "b"
    out.mkdir()
    bg = out / "r0001_truth.fits"
    _fits.writeto(bg, np.full((64, 64), 0.5, np.float32))
    text = small_scene.read_text().replace("background = 1.0",
                                           f'background = "{bg}"')
    scene = small_scene.parent / "map.toml"
    scene.write_text(text)
    before = bg.read_bytes()
    assert main(["batch", str(scene), "-n", "1", "--out", str(out), "--workers", "1",
                 "-q"]) == 0
    assert main(["batch", str(scene), "-n", "2", "--out", str(out), "--workers", "1",
                 "-q"]) == 2
    err = capsys.readouterr().err
    assert "r0001's truth file" in err and "a file the scene reads" in err, err
    assert bg.read_bytes() == before


def test_a_resumed_batch_with_a_drawn_seed_prints_the_seed_it_used(small_scene,
                                                                   tmp_path, capsys):
    # the summary printed a freshly drawn seed on a resume; the data used the
    # manifest's (a probe)
    text = "\n".join(ln for ln in small_scene.read_text().splitlines()
                     if not ln.startswith("seed"))
    scene = small_scene.parent / "noseed.toml"
    scene.write_text(text + "\n")
    out = tmp_path / "d"
    seeds = []
    for n in ("1", "2"):
        assert main(["batch", str(scene), "-n", n, "--out", str(out), "--workers",
                     "1"]) == 0
        line = [ln for ln in capsys.readouterr().out.splitlines()
                if "batch seed" in ln][-1]
        seeds.append(line.split("batch seed ")[1].split()[0])
    manifest = json.loads((out / "batch.json").read_text())
    assert seeds[0] == seeds[1] == str(manifest["batch_seed"]), seeds


def test_grid_of_detectors_runs_point_by_point(small_scene, tmp_path):
    grid = small_scene.parent / "grid.toml"
    grid.write_text("""\
scene = "small.toml"
realisations = 2
compare = true
[[detectors]]
name = "SCA01"
[[detectors]]
name = "SCA02"
"noise.rd_noise" = 12.0
""")
    plan = plan_batch(grid, out=tmp_path / "g")
    res = run_batch(plan, workers=2, progress=False)
    assert sorted(res.ran) == ["p000/r0000", "p000/r0001", "p001/r0000", "p001/r0001"]
    assert set(res.pooled) == {"p000", "p001"}
    rows = res.manifest["tasks"]
    assert rows["p000/r0001"]["params"] == [["detector", "SCA01"]]
    assert rows["p001/r0000"]["params"] == [["detector", "SCA02"],
                                            ["noise.rd_noise", 12.0]]
    for t in plan.tasks():
        head = fits.getheader(t.path["exposure"])
        assert head["BATCHKEY"] == f"{t.point},{t.realisation}"
        # which detector a file is, in the file itself (it was only in the manifest)
        assert head["BATCHDET"] == ("SCA01", "SCA02")[t.point]
        assert fits.getheader(t.path["gls"])["BATCHDET"] == head["BATCHDET"]
    # the second detector's read noise is its own
    rdn = [fits.getheader(plan.tasks()[i].path["truth"])["RDNOISE"] for i in (0, 2)]
    assert rdn[1] == 12.0 and rdn[0] != 12.0


@pytest.mark.parametrize("limit", ["memory", "disk"])
def test_a_batch_the_machine_cannot_hold_is_refused_before_any_task(
        small_scene, tmp_path, monkeypatch, limit):
    # The size check of `scenesim run`, for a batch: the local workers each hold
    # the largest task at once, and the tasks left write their files (issue 12:
    # `scenesim batch` did not check).  Limits patched to 1 MB: refused in one line
    # naming the override, before any cluster starts or any file is written.
    import scenesim.budget as budget_module
    from noise.errors import ParameterError
    if limit == "memory":
        monkeypatch.setattr(budget_module, "available_memory", lambda: 1e6)
    else:
        monkeypatch.setattr(budget_module, "free_disk", lambda path: 1e6)
    out = tmp_path / "b"
    plan = plan_batch(small_scene, out=out, realisations=4)
    with pytest.raises(ParameterError) as info:
        run_batch(plan, workers=2, progress=False)
    msg = str(info.value)
    assert "\n" not in msg and "--force" in msg
    assert ("2 local workers" in msg) if limit == "memory" else ("4 tasks" in msg)
    assert not out.exists()
