"""Logic tests of the benchmark harness (no timing assertions: times drift here)."""

import json
import os

import numpy as np
import pytest

import noise
from noise.errors import ParameterError
from scenesim import bench


def test_quick_timeseries_writes_json_and_markdown(tmp_path):
    out = tmp_path / "b"
    assert bench.main(["timeseries"], quick=True, out_dir=str(out), threads=1) == 0
    data = json.loads((out / "bench.json").read_text())
    (row,) = data["rows"]
    assert row["workload"] == "timeseries" and row["case"] == "30"
    assert row["wall"] > 0 and row["floor"] > 0 and row["peak_rss_mb"] > 0
    assert row["ratio"] == pytest.approx(row["wall"] / row["floor"])
    # the whole process contains the in-process work; the limit is the sum of its parts
    assert row["process_wall"] > row["wall"] and row["process_cpu"] > 0
    assert row["limit"] == pytest.approx(sum(row["limit_parts"].values()))
    assert row["limit_ratio"] == pytest.approx(row["wall"] / row["limit"])
    assert row["limit_parts"]["fft"] > 0 and row["limit_parts"]["write"] > 0
    # the method floor replaces the limit's inverse FFTs by the overlap-save pairs
    assert row["method_floor"] == pytest.approx(row["limit"] - row["limit_parts"]["fft"]
                                                + row["fft_method"])
    assert row["method_ratio"] == pytest.approx(row["wall"] / row["method_floor"])
    assert len(row["load_before"]) == 3 and len(data["meta"]["load_average_start"]) == 3
    assert row["peers"] == []
    md = (out / "bench.md").read_text()
    assert "| timeseries | 30 |" in md and "| wall / method floor |" in md


def test_scaling_pairs_alternate_and_report_medians_of_their_ratios(tmp_path):
    """With --scaling --pairs 2 a case runs twice on 2 threads and twice on 1 thread;
    the speed-up is the median of each pair's own ratio, the limit's likewise."""
    out = tmp_path / "s"
    assert bench.main(["timeseries"], quick=True, out_dir=str(out), threads=2,
                      scaling=True, pairs=2) == 0
    data = json.loads((out / "bench.json").read_text())
    (row,) = data["rows"]
    assert data["meta"]["pairs"] == 2 and row["pairs"] == 2
    assert len(row["walls"]) == len(row["walls_1thread"]) == 2
    assert row["walls"][0] == row["wall"]          # pair 1 is the case's own run
    ratios = [b / a for a, b in zip(row["walls"], row["walls_1thread"])]
    assert row["speedups"] == pytest.approx(ratios)
    assert row["speedup"] == pytest.approx(np.median(ratios))
    assert row["wall_1thread"] == pytest.approx(np.median(row["walls_1thread"]))
    assert len(row["limit_speedups"]) == 2
    assert row["limit_speedup"] == pytest.approx(np.median(row["limit_speedups"]))
    assert row["method_ratio_1thread"] == pytest.approx(row["wall_1thread"]
                                                        / row["method_floor_1thread"])
    assert "median of 2 pairs" in (out / "bench.md").read_text()


@pytest.mark.parametrize("kwargs, match", [
    (dict(scaling=True, pairs=0), "'pairs' must be an integer >= 1, got 0"),
    (dict(scaling=True, pairs=True), "'pairs' must be an integer >= 1, got True"),
    (dict(scaling=True, pairs=1.5), "'pairs' must be an integer >= 1, got 1.5"),
    (dict(pairs=3), "'pairs' = 3 .* give it with --scaling"),
])
def test_bad_pairs_are_refused_before_work(tmp_path, kwargs, match):
    with pytest.raises(ParameterError, match=match):
        bench.main(["timeseries"], quick=True, out_dir=str(tmp_path / "x"), threads=2,
                   **kwargs)
    assert not os.path.exists(tmp_path / "x")


def test_floor_counts_follow_design_section_7():
    # Closed form from DESIGN.md §7 for the NG defaults (all components on, 4 outputs):
    # per read nx*ny white + L (c_pink) + 4 L (u_pink) + 4 * 2 * (L/2) (ACN)
    # + (ny + nfoh) (picture frame); kTC: nx*ny per integration; Poisson: pixels x reads.
    det, p = noise.preset("H2RG", naxis1=256, naxis2=256), noise.NoiseParams()
    L = (det.ny + det.nfoh) * (det.ncols_out + det.nroh)
    per_read = det.ny * det.nx + L + 4 * L + 4 * L + det.ny + det.nfoh
    ktc = det.ny * det.nx if p.ktc > 0 else 0
    nn, npo = bench.floor_counts(det, p, n_reads=6, nints=2, charged=1000, n_intervals=6)
    assert nn == 6 * per_read + 2 * ktc
    assert npo == 6000
    assert bench.floor_counts(det, None, 6) == (0, 0)


def test_bad_arguments_raise_before_work(tmp_path):
    with pytest.raises(ParameterError, match="workloads"):
        bench.main(["nope"], quick=True, out_dir=str(tmp_path / "x"))
    with pytest.raises(ParameterError, match="--ng"):
        bench.main(["noise"], quick=True, out_dir=str(tmp_path / "x"),
                   ng=str(tmp_path / "nghxrg.py"))
    with pytest.raises(ParameterError, match="nghxrg.py"):
        bench.main(["noise"], quick=True, out_dir=str(tmp_path / "x"), peers=True,
                   ng=str(tmp_path / "nghxrg.py"))
    assert not os.path.exists(tmp_path / "x")
    with pytest.raises(ParameterError, match="n_normal"):
        bench.floor_seconds(-1, 0, 1.0, 1)
    with pytest.raises(ParameterError, match="lam"):
        bench.floor_seconds(10, 10, np.nan, 1)


def test_quick_options_report_errors_against_exact(tmp_path):
    """Each option row carries per-decade slope metrics, and the '2d' shortcut's slopes
    differ from the exact path's by more than 1 sigma somewhere (different draws)."""
    out = tmp_path / "o"
    assert bench.main(["options"], quick=True, out_dir=str(out), threads=1) == 0
    rows = {r["case"]: r for r in json.loads((out / "bench.json").read_text())["rows"]}
    assert set(rows) == {f"{c} (quick)" for c in bench.OPTION_CASES}
    for r in rows.values():
        assert set(r["per_decade"]) == {"-1", "0", "1", "2"}
        # unclipped ramps: the exact path is unbiased and efficient per decade
        # (~4000 pixels per decade at 256^2: 1 sigma of the bias 0.016, of the
        # scatter ratio 0.011; the bounds are > 5 sigma)
        assert r["max_diff_sigma"] >= 0
    assert rows["exact (quick)"]["max_abs_bias"] < 0.1
    assert rows["exact (quick)"]["max_scatter_dev"] < 0.06
    assert rows["arrivals=2d (quick)"]["max_diff_sigma"] > 1.0
    assert "speed-up vs exact" in (out / "bench.md").read_text()


def test_fit_scaling_grid_reports_time_memory_and_exponents(tmp_path):
    """The fit's scaling cases stream their exposure file and report what they
    measured; the slopes are right (a broken stream would not fit 10 e-/s)."""
    out = tmp_path / "f"
    assert bench.main(["fit"], out_dir=str(out), threads=1, fit_sizes=[64],
                      fit_resultants=[5, 10]) == 0
    rows = json.loads((out / "bench.json").read_text())["rows"]
    assert [(r["size"], r["nres"]) for r in rows] == [(64, 5), (64, 10)]
    for r in rows:
        assert r["wall"] > 0 and r["peak_rss_mb"] > 0 and r["baseline"] > 0
        assert r["read_pass"] > 0 and r["blocks"] == 1
        assert r["cube_mb"] == pytest.approx(r["nres"] * 64 * 64 * 4 / 2 ** 20)
        # 10 e-/s over 5 x 10.737 s with 10 e- per read: one slope's sd is ~0.56
        # e-/s, the median of 4096 has sd 1.25 x 0.56 / 64 = 0.011: 0.06 is 5 sigma
        assert abs(r["median_slope"] - 10.0) < 0.06
    md = (out / "bench.md").read_text()
    assert "| 64x64 | 5 |" in md and "| 64x64 | 10 |" in md
    assert "Exponents (least squares of log against log resultants" in md
    assert md.count("| 64x64 |") == 3


def test_fit_scaling_grid_arguments_are_checked_before_work(tmp_path, monkeypatch):
    for kw in (dict(fit_sizes=[0]), dict(fit_resultants=[1]),
               dict(fit_sizes=[64.5]), dict(fit_resultants=[])):
        with pytest.raises(ParameterError, match="fit_"):
            bench.main(["fit"], out_dir=str(tmp_path / "x"), **kw)
    with pytest.raises(ParameterError, match="add the 'fit' workload"):
        bench.main(["noise"], out_dir=str(tmp_path / "x"), fit_sizes=[64])
    # an impossible case is refused before the first one runs (before: a misleading
    # 'out of memory ... --force' or an EFBIG traceback, and an empty --out left)
    with pytest.raises(ParameterError, match=r"'fit_sizes' must be integers in "
                                             r"\[8, 8192\]"):
        bench.main(["fit"], out_dir=str(tmp_path / "x"), fit_sizes=[10 ** 9])
    # the largest ramp file, 4096^2 x 200 uint16 = 6.25 GiB, on a disk with 1 GiB free
    import collections
    usage = collections.namedtuple("usage", "total used free")
    monkeypatch.setattr(bench.shutil, "disk_usage",
                        lambda path: usage(2 ** 31, 2 ** 30, 2 ** 30))
    with pytest.raises(ParameterError, match=r"4096\^2 x 200 resultants, writes a "
                                             r"6\.2 GiB ramp file .* 1\.0 GiB free"):
        bench.main(["fit"], out_dir=str(tmp_path / "x"), fit_sizes=[512, 4096],
                   fit_resultants=[5, 200])
    assert not os.path.exists(tmp_path / "x")


def test_a_report_says_when_it_is_incomplete_and_drops_an_earlier_figure(
        tmp_path, monkeypatch):
    """Rewritten after every case, the report of an interrupted run looked complete;
    with --overwrite an earlier run's bench.png stayed beside a report without one; a
    failed write was a traceback that left an empty --out."""
    d = tmp_path / "b"
    d.mkdir()
    for name in ("bench.json", "bench.md", "bench.png"):
        (d / name).write_text("earlier")
    assert bench.main(["fit"], out_dir=str(d), threads=1, fit_sizes=[16],
                      fit_resultants=[3, 4], overwrite=True) == 0
    assert sorted(os.listdir(d)) == ["bench.json", "bench.md"]
    meta = json.loads((d / "bench.json").read_text())["meta"]
    assert (meta["complete"], meta["cases_done"], meta["cases_planned"]) == (True, 2, 2)
    assert "Incomplete" not in (d / "bench.md").read_text()
    # the second case fails: the report written after the first says so
    real, calls = bench._run_one, []

    def second_fails(*args, **kwargs):
        calls.append(1)
        if len(calls) == 2:
            raise OSError(27, "File too large")
        return real(*args, **kwargs)

    monkeypatch.setattr(bench, "_run_one", second_fails)
    with pytest.raises(noise.errors.OutputError, match="File too large"):
        bench.main(["fit"], out_dir=str(d), threads=1, fit_sizes=[16],
                   fit_resultants=[3, 4], overwrite=True)
    meta = json.loads((d / "bench.json").read_text())["meta"]
    assert (meta["complete"], meta["cases_done"], meta["cases_planned"]) == (False, 1, 2)
    assert (d / "bench.md").read_text().startswith("**Incomplete: 1 of 2 cases**")
    calls.clear()
    monkeypatch.setattr(bench, "_run_one", lambda *a, **k: (_ for _ in ()).throw(
        OSError(28, "No space left on device")))
    with pytest.raises(noise.errors.OutputError, match="No space left"):
        bench.main(["fit"], out_dir=str(tmp_path / "new"), threads=1, fit_sizes=[16],
                   fit_resultants=[3])
    assert not (tmp_path / "new").exists()


def test_kernel_probe_times_every_kernel_and_refuses_unknown_names():
    """``python -m scenesim.bench.kernels``: each kernel runs on 1 and 2 threads (a
    small fraction of its calls here); the values are measured, so only their form is
    checked.  The Poisson chunk's means hold one dominant value (the guide-table path
    the probe is about)."""
    from scenesim.bench import kernels
    rows = kernels.run_kernels(repeats=1, scale=0.005)
    assert [r["name"] for r in rows] == list(kernels.KERNELS)
    for r in rows:
        assert r["us_per_call"] > 0 and r["speedup"] > 0 and r["description"]
    lam = kernels.chunk_means()
    assert np.count_nonzero(lam == np.median(lam)) == lam.size - 3500
    with pytest.raises(ParameterError, match="'names'.*'fft_9'"):
        kernels.run_kernels(["fft_9"])
    with pytest.raises(ParameterError, match="'names' must be a list"):
        kernels.run_kernels("fft_4x32768")
    with pytest.raises(ParameterError, match="'repeats'"):
        kernels.run_kernels(["streams"], repeats=0)


def test_report_files_are_checked_before_any_work(tmp_path, monkeypatch):
    # no case may run before the output directory is accepted
    ran = []
    monkeypatch.setattr(bench, "_run_one", lambda *a, **k: ran.append(a) or {})
    afile = tmp_path / "f"
    afile.write_text("mine")
    with pytest.raises(ParameterError, match=r"'--out' .*/f' is a file; expected a "
                                             r"directory for bench.json, bench.md"):
        bench.main(["timeseries"], quick=True, out_dir=str(afile))
    with pytest.raises(ParameterError, match="does not exist"):
        bench.main(["timeseries"], quick=True, out_dir=str(tmp_path / "no" / "b"))
    # an earlier run's report is replaced only with overwrite (json, md; the png only
    # for the workloads that plot)
    for name in ("bench.json", "bench.md", "bench.png"):
        d = tmp_path / name.replace(".", "_")
        d.mkdir()
        (d / name).write_text("earlier")
        workloads = ["pink"] if name == "bench.png" else ["timeseries"]
        with pytest.raises(ParameterError, match=rf"bench report {name} .*exists; pass "
                                                 rf"--overwrite"):
            bench.main(workloads, quick=True, out_dir=str(d))
        assert (d / name).read_text() == "earlier"
    assert ran == []
    monkeypatch.undo()
    d = tmp_path / "bench_png"          # timeseries writes no png: it is not in the way
    assert bench.main(["timeseries"], quick=True, out_dir=str(d), threads=1) == 0
    assert (d / "bench.png").read_text() == "earlier"
    assert json.loads((d / "bench.json").read_text())["rows"][0]["case"] == "30"


def test_overwrite_replaces_the_report_atomically(tmp_path):
    d = tmp_path / "b"
    d.mkdir()
    (d / "bench.json").write_text("earlier")
    assert bench.main(["timeseries"], quick=True, out_dir=str(d), threads=1,
                      overwrite=True) == 0
    assert json.loads((d / "bench.json").read_text())["rows"][0]["case"] == "30"
    assert sorted(os.listdir(d)) == ["bench.json", "bench.md"]   # no temporary left


def test_the_help_lists_every_workload(capsys):
    """`scenesim bench --help` named no workload; only an error listed them.  The
    parser does not import the bench, so the names are typed there: this keeps them
    in step."""
    from scenesim.bench.workloads import WORKLOADS
    from scenesim.cli import main
    with pytest.raises(SystemExit):
        main(["bench", "--help"])
    text = " ".join(capsys.readouterr().out.split())
    listed = text.split("workloads (default: all):")[1].split(";")[0]
    assert [w.strip() for w in listed.split(",")] == list(WORKLOADS)
