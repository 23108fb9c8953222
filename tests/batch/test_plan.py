"""Batch planning: seeds spawned from the batch seed, grids over scene keys, and the
errors of bad batch files, before anything runs (no dask needed)."""

import os

import numpy as np
import pytest

from noise.errors import ParameterError
from scenesim.batch.plan import plan_batch, realisation_seed, spawn_key


def test_realisation_seed_is_the_spawned_child():
    """Realisation k of a one-point batch draws from SeedSequence(batch).spawn(N)[k]:
    its seed is the top 63 bits of the first word that child generates."""
    children = np.random.SeedSequence(2026).spawn(6)
    for k, child in enumerate(children):
        word = int(child.generate_state(1, np.uint64)[0])
        assert realisation_seed(2026, spawn_key(0, k, 1)) == word >> 1
    # grid point p, realisation k: spawn(P)[p].spawn(N)[k]
    grand = np.random.SeedSequence(5).spawn(3)[2].spawn(4)[1]
    assert realisation_seed(5, spawn_key(2, 1, 3)) == \
        int(grand.generate_state(1, np.uint64)[0]) >> 1


def test_seeds_are_distinct_and_do_not_depend_on_the_count(small_scene, tmp_path):
    a = plan_batch(small_scene, out=tmp_path / "a", realisations=8).tasks()
    b = plan_batch(small_scene, out=tmp_path / "b", realisations=3).tasks()
    assert len({t.seed for t in a}) == 8
    assert [t.seed for t in a[:3]] == [t.seed for t in b]
    assert all(0 <= t.seed < 2 ** 63 for t in a)
    # the scene's seed is the default batch seed; --seed overrides it
    assert a[0].batch_seed == 777
    c = plan_batch(small_scene, out=tmp_path / "c", realisations=2, seed=1).tasks()
    assert c[0].seed != a[0].seed and c[0].batch_seed == 1


def test_task_files_and_scene(small_scene, tmp_path):
    plan = plan_batch(small_scene, out=tmp_path / "o", realisations=2,
                      fit=["gls", "ols"], ramp=False)
    t = plan.tasks()[1]
    p = t.path
    assert "exposure" not in p
    assert p["truth"] == str(tmp_path / "o" / "r0001_truth.fits")
    assert p["gls"] == str(tmp_path / "o" / "r0001_gls.fits")
    assert p["record"] == str(tmp_path / "o" / "r0001.json")
    assert t.scene.seed == t.seed


def _batch_file(tmp_path, text):
    path = tmp_path / "scenes" / "grid.toml"
    path.write_text(text)
    return path


def test_grid_and_detectors_expand(small_scene, tmp_path):
    path = _batch_file(tmp_path, """\
scene = "small.toml"
seed = 9
realisations = 2
[grid]
"sources.background" = [0.5, 2.0]
noise.rd_noise = [3.0, 6.0, 9.0]
[[detectors]]
name = "SCA01"
[[detectors]]
name = "SCA02"
"sources.stars.1.flux" = 10.0
""")
    plan = plan_batch(path, out=tmp_path / "g")
    assert len(plan.points) == 2 * 3 * 2 and plan.batch_seed == 9
    tasks = plan.tasks()
    assert len(tasks) == 24 and tasks[0].name == "p000/r0000"
    assert len({t.seed for t in tasks}) == 24
    scenes = {p.params: p.scene for p in plan.points}
    sca2 = [s for k, s in scenes.items() if ("detector", "SCA02") in k]
    assert all(s.sources.stars[1].flux == 10.0 for s in sca2)
    assert {s.sources.background for s in scenes.values()} == {0.5, 2.0}
    assert {float(np.atleast_1d(s.noise.rd_noise)[0]) for s in scenes.values()} == \
        {3.0, 6.0, 9.0}


@pytest.mark.parametrize("grid, match", [
    ('"sources.backgroud" = [1.0]', r"'sources.backgroud'.*did you mean 'background'"),
    ('"sourcs.background" = [1.0]', r"did you mean 'sources'"),
    ('"seed" = [1, 2]', r"'seed'.*batch seed"),
    ('"output.fit" = ["ols"]', r"'output.fit'.*batch"),
    ('"sources.stars.5.flux" = [1.0]', r"'sources.stars.5.flux' is not a scene key"),
    ('"sources.background.x" = [1.0]', r"is not a scene key"),
    ('"sources.background" = []', r"non-empty list"),
    ('"sources.background" = [-1.0]', r"background"),
    # a detector the noise generator refuses (17 columns per output: no ACN pairs),
    # refused with the plan, not when its task runs
    ('"detector.naxis1" = [64, 68]', r"grid point 1.*ACN needs an even number"),
])
def test_bad_grid_keys_are_refused_naming_the_key(small_scene, tmp_path, grid, match):
    path = _batch_file(tmp_path, f'scene = "small.toml"\n[grid]\n{grid}\n')
    with pytest.raises(ParameterError, match=match):
        plan_batch(path, out=tmp_path / "g")
    assert not (tmp_path / "g").exists()


def test_a_key_set_twice_is_refused(small_scene, tmp_path):
    # a [[detectors]] key the [grid] also varies: the grid's value had silently won
    path = _batch_file(tmp_path, """\
scene = "small.toml"
[grid]
"noise.rd_noise" = [3.0, 5.2]
[[detectors]]
name = "SCA01"
[[detectors]]
name = "SCA02"
"noise.rd_noise" = 6.0
""")
    with pytest.raises(ParameterError, match=r"'SCA02' sets 'noise.rd_noise', which "
                                             r"the \[grid\] also varies"):
        plan_batch(path, out=tmp_path / "g")
    # quoted and dotted spellings of one key: one axis had been dropped
    path = _batch_file(tmp_path, 'scene = "small.toml"\n[grid]\n'
                                 '"noise.rd_noise" = [3.0, 5.2]\nnoise.rd_noise = [9.0]\n')
    with pytest.raises(ParameterError, match=r"'noise.rd_noise' is given twice"):
        plan_batch(path, out=tmp_path / "g")
    assert not (tmp_path / "g").exists()


def test_sizes_are_refused_before_anything_is_built(small_scene, tmp_path):
    # 8 axes of 10 values: the product (10^8 points) was built before its cap was
    # checked (10^7 took 1.2 GB); -n 10^8: no answer in 120 s
    grid = "\n".join(f'"sources.{k}" = [{", ".join(str(v + 1) for v in range(10))}]'
                     for k in ("background", "dark_current"))
    grid += "\n" + "\n".join(
        f'"noise.{k}" = [{", ".join(str(v + 1) for v in range(10))}]'
        for k in ("c_pink", "u_pink", "acn", "pca0", "pedestal", "ktc"))
    path = _batch_file(tmp_path, f'scene = "small.toml"\n[grid]\n{grid}\n')
    with pytest.raises(ParameterError, match=r"the grid has 100000000 points"):
        plan_batch(path, out=tmp_path / "g")
    with pytest.raises(ParameterError, match=r"100000000 runs; at most 100000"):
        plan_batch(small_scene, out=tmp_path / "g", realisations=10 ** 8)


def test_the_files_a_scene_reads_are_part_of_the_batch(small_scene, tmp_path):
    # a batch resumed after its catalogue changed had pooled two scenes
    from astropy.table import Table
    scene_dir = os.path.dirname(small_scene)
    cat = os.path.join(scene_dir, "stars.ecsv")
    Table({"x": [30.2], "y": [31.6], "flux": [3000.0]}).write(cat, overwrite=True)
    with open(small_scene) as fh:
        text = fh.read()
    path = os.path.join(scene_dir, "with_cat.toml")
    with open(path, "w") as fh:
        fh.write(text.replace("[sources]", '[sources]\ncatalogue = "stars.ecsv"', 1))
    a = plan_batch(path, out=tmp_path / "g").identity()
    Table({"x": [30.2], "y": [31.6], "flux": [3e5]}).write(cat, overwrite=True)
    b = plan_batch(path, out=tmp_path / "g").identity()
    assert a["inputs_sha256"] != b["inputs_sha256"] and a != b
    # a scene that reads no file keeps the identity it had (no inputs key)
    assert "inputs_sha256" not in plan_batch(small_scene, out=tmp_path / "g").identity()


def test_a_project_moved_whole_is_the_same_batch(small_scene, tmp_path):
    # The identity held the scene's absolute path: a project moved or copied
    # whole (scene, catalogue, outputs) was "another batch" and could not resume.
    import shutil
    from astropy.table import Table
    from scenesim.batch.manifest import check_same_batch
    home = tmp_path / "a"
    home.mkdir()
    Table({"x": [30.2], "y": [31.6], "flux": [3000.0]}).write(home / "stars.ecsv")
    (home / "s.toml").write_text(small_scene.read_text().replace(
        "[sources]", '[sources]\ncatalogue = "stars.ecsv"', 1))
    a = plan_batch(home / "s.toml", out=home / "out").identity()
    moved = tmp_path / "b" / "deeper"
    shutil.copytree(home, moved)
    b = plan_batch(moved / "s.toml", out=moved / "out").identity()
    assert a["scene"] != b["scene"]
    check_same_batch({"identity": a}, b, str(moved / "out"))       # no error
    # what still makes it another batch: the files' contents, the scene's name
    Table({"x": [30.2], "y": [31.6], "flux": [3e5]}).write(moved / "stars.ecsv",
                                                        overwrite=True)
    c = plan_batch(moved / "s.toml", out=moved / "out").identity()
    with pytest.raises(ParameterError, match="differs in inputs_sha256"):
        check_same_batch({"identity": a}, c, str(moved / "out"))
    os.rename(moved / "s.toml", moved / "t.toml")
    shutil.copyfile(home / "stars.ecsv", moved / "stars.ecsv")
    d = plan_batch(moved / "t.toml", out=moved / "out").identity()
    with pytest.raises(ParameterError, match="differs in scene"):
        check_same_batch({"identity": a}, d, str(moved / "out"))


def test_bad_batch_files(small_scene, tmp_path):
    with pytest.raises(ParameterError, match=r"unknown key 'realisation'.*realisations"):
        plan_batch(_batch_file(tmp_path, 'scene = "small.toml"\nrealisation = 3\n'),
                   out=tmp_path / "g")
    with pytest.raises(ParameterError, match="'fit'.*'gls'"):
        plan_batch(small_scene, out=tmp_path / "g", fit=["gsl"])
    with pytest.raises(ParameterError, match="realisations"):
        plan_batch(small_scene, out=tmp_path / "g", realisations=0)
    with pytest.raises(ParameterError, match="compare.*fitter"):
        plan_batch(small_scene, out=tmp_path / "g", fit=[], compare=True)
    # a batch file's compare, ramp and refpix: named with the file (a probe: compare
    # and ramp named no file, refpix read "batch file ...: 'refpix'" must be ...)
    for text, match in (('compare = "yes"\n', r"'compare' must be true or false"),
                        ('ramp = 1\n', r"'ramp' must be true or false, got 1"),
                        ('refpix = "jwsT"\n', r"'refpix' must be one of .*'jwst'")):
        path = _batch_file(tmp_path, 'scene = "small.toml"\n' + text)
        with pytest.raises(ParameterError, match=rf"^batch file .*: {match}"):
            plan_batch(path, out=tmp_path / "g")


def test_an_out_directory_that_cannot_be_written_is_refused_first(tmp_path,
                                                                  monkeypatch):
    # a read-only file system (as root, modes do not stop writes; os.access does see
    # a read-only mount): before, OSError from the lock file once the workers were up
    from scenesim.batch import runner
    real = os.access
    monkeypatch.setattr(runner.os, "access",
                        lambda p, m: False if os.path.abspath(p) == str(tmp_path)
                        else real(p, m))
    for out in (tmp_path, tmp_path / "new" / "deeper"):
        with pytest.raises(ParameterError, match=r"'out' .*is not writable"):
            runner._check_out_writable(str(out))
    (tmp_path / "file").write_text("x")
    with pytest.raises(ParameterError, match="is not a directory"):
        runner._check_out_writable(str(tmp_path / "file" / "sub"))


def test_refpix_is_checked_against_every_point_before_any_task(small_scene, tmp_path):
    """A correction the readout cannot support stops the plan (before, 'median' on a
    window without reference rows ran every task and fitted without a correction,
    and 'irs2' was refused for every scene, the IRS2 ones included)."""
    with pytest.raises(ParameterError, match=r"--refpix: .*refpix 'irs2' needs "
                                             r"interleaved reference samples"):
        plan_batch(small_scene, out=tmp_path / "g", refpix="irs2")
    # a window inside the array has no reference pixel
    window = small_scene.read_text().replace(
        "[readout]", "[detector.subarray]\nx0 = 20\ny0 = 20\nnx = 16\nny = 16\n\n[readout]")
    (tmp_path / "scenes" / "window.toml").write_text(window)
    path = _batch_file(tmp_path, 'scene = "window.toml"\nrefpix = "median"\n'
                                 '[grid]\n"sources.background" = [1.0, 2.0]\n')
    with pytest.raises(ParameterError, match=r"'refpix' \(grid point 0\): refpix "
                                             r"'median' needs top/bottom reference"):
        plan_batch(path, out=tmp_path / "g")
    assert not (tmp_path / "g").exists()
    # what such a window can have: 'jwst' (nothing to subtract: the fit records
    # 'none') and 'none'
    for scheme in ("jwst", "none"):
        path.write_text(f'scene = "window.toml"\nrefpix = "{scheme}"\n'
                        '[grid]\n"sources.background" = [1.0, 2.0]\n')
        assert plan_batch(path, out=tmp_path / "g").refpix == scheme


@pytest.mark.slow
def test_a_batch_of_the_irs2_scene_fits_as_its_run_does(tmp_path):
    """The IRS2 example scene in a batch: its task fits with the interleaved
    reference samples (REFPIX 'irs2') and gives the slopes of ``scenesim run`` of the
    task's scene, which has the task's seed.  Slopes only (no ramp file): the fit
    reads the raw samples from the exposure kept in memory."""
    import shutil

    from astropy.io import fits

    from scenesim.batch.tasks import run_task
    from scenesim.io.fitfile import read_fit
    from scenesim.run import run_scene

    scenes = os.path.join(os.path.dirname(__file__), "..", "..", "scenes")
    shutil.copy(os.path.join(scenes, "nirspec_irs2.toml"), tmp_path)
    shutil.copytree(os.path.join(scenes, "data"), tmp_path / "data")
    plan = plan_batch(tmp_path / "nirspec_irs2.toml", out=tmp_path / "b",
                      realisations=1, ramp=False, compare=False)
    assert plan.refpix == "irs2"
    os.makedirs(tmp_path / "b")
    task = plan.tasks()[0]
    run_task(task)
    (tmp_path / "single").mkdir()
    single = run_scene(task.scene, output=str(tmp_path / "single" / "x.fits"),
                       fit="gls", compare=False, progress=False)
    assert fits.getheader(task.path["gls"])["REFPIX"] == "irs2"
    a, b = read_fit(task.path["gls"]), read_fit(single.fit)
    for name in ("slope", "var_read", "var_poisson", "dq"):
        np.testing.assert_array_equal(getattr(a, name), getattr(b, name), name)


def test_a_file_that_is_not_utf8_and_an_endless_timeout_are_one_line(small_scene,
                                                                      tmp_path, capsys):
    # A probe: a Latin-1 scene (an editor's "café") was a UnicodeDecodeError
    # traceback from run and batch; --connect-timeout inf a KeyError inside dask.
    from scenesim.cli import main
    bad = tmp_path / "u.toml"
    bad.write_bytes(b'seed = 1\ndescription = "caf\xe9"\n')
    for argv in (["run", str(bad), "-o", str(tmp_path / "u.fits")],
                 ["batch", str(bad), "--out", str(tmp_path / "o")]):
        assert main(argv) == 2
        err = capsys.readouterr().err.strip()
        assert len(err.splitlines()) == 1 and "is not UTF-8 text" in err, err
        assert "byte 27" in err
    for value in ("inf", "1e300", "86401"):
        assert main(["batch", str(small_scene), "--out", str(tmp_path / "o"),
                     "--scheduler", "tcp://127.0.0.1:1", "--connect-timeout",
                     value]) == 2
        err = capsys.readouterr().err.strip()
        assert err.startswith("scenesim batch: error: '--connect-timeout' must be > 0 "
                              "and <= 86400"), err
    assert not (tmp_path / "o").exists() and not (tmp_path / "u.fits").exists()
