"""Peers, whole processes and the limit (issue 16): every number measured in its run.

No timing assertions (times drift here): these tests check that the bench holds no
remembered peer number, that a peer which did not run prints "not measured" and no
ratio, that a peer which ran is measured on the scenesim case's own input, and the
closed forms of the limit's counts.
"""

import io
import json
import os
import re
import subprocess
import sys
import tokenize
from pathlib import Path

import numpy as np
import pytest

import noise
from noise.errors import ParameterError
from scenesim import bench
from scenesim.bench import limit, peers, workloads
from scenesim.bench.process import peak_memory, run_process

BENCH_DIR = Path(bench.__file__).parent

_PEER = r"(?:NG|nghxrg|romanisim|stcal|OLS_C|LIKELY|likelihood)"
_QUANTITY = r"\b\d+(?:\.\d+)?(?:\s*-\s*\d+(?:\.\d+)?)?\s*(?:s|sec|seconds|min|minutes|MB|GB|x|×)(?![A-Za-z])"
_NEAR = re.compile(rf"(?i)\b{_PEER}\b[\s\S]{{0,120}}?{_QUANTITY}|{_QUANTITY}\s*faster than")


def peer_timings(source):
    """Literal peer timings in Python ``source``: a number on a code line that names a
    peer in a string (a table of peer times), or a peer named within 120 characters
    of a time, memory or speed-up quantity in a string or comment ("NG takes 54 s")."""
    found = []
    lines = {}
    for tok in tokenize.generate_tokens(io.StringIO(source).readline):
        if tok.type in (tokenize.STRING, tokenize.COMMENT):
            m = _NEAR.search(tok.string)
            if m:
                found.append(f"line {tok.start[0]}: {m.group(0)!r}")
        if tok.type in (tokenize.STRING, tokenize.NUMBER):
            lines.setdefault(tok.start[0], []).append(tok)
    for lineno, toks in lines.items():
        named = any(t.type == tokenize.STRING and re.search(rf"(?i)\b{_PEER}\b", t.string)
                    for t in toks)
        numbers = [t.string for t in toks if t.type == tokenize.NUMBER]
        if named and numbers:
            found.append(f"line {lineno}: numbers {numbers} beside a peer name")
    return found


def test_the_scan_finds_remembered_peer_timings():
    """The scan would have caught what issue 16 removed (the old REFERENCES table and
    the module docstring's peer times)."""
    old = '''"""Reference numbers of other programs: the original NG program takes 5.5 s for
1 frame; romanisim 0.15 L1 takes 83-108 s and 3.4 GB."""
REFERENCES = {
    ("noise", 10): ("NG original", 54.0, 2500.0),
    ("fit", "ols"): ("stcal 1.20 C OLS", 11.0, None),
}
ref = f"{speedup:.1f}x faster than {name}"   # 8.7x faster than stcal
'''
    found = peer_timings(old)
    assert len(found) >= 4, found
    assert peer_timings('label = "stcal OLS_C"  # stcal 1.20, same cube\n') == []


@pytest.mark.parametrize("path", sorted(BENCH_DIR.glob("*.py")), ids=lambda p: p.name)
def test_bench_modules_hold_no_peer_timings(path):
    assert peer_timings(path.read_text()) == []
    assert "REFERENCES" not in path.read_text()


def test_quick_command_prints_no_peer_ratio_without_peers(tmp_path):
    """`scenesim bench --quick` (here the time series, whose workload has no peer, and
    the plan of a fit case, which has one) prints no peer number unless a peer ran."""
    out = tmp_path / "q"
    proc = subprocess.run([sys.executable, "-m", "scenesim.cli", "bench", "timeseries",
                           "--quick", "--threads", "1", "--out", str(out)],
                          capture_output=True, text=True, cwd=tmp_path)
    assert proc.returncode == 0, proc.stderr
    md = (out / "bench.md").read_text()
    text = proc.stdout + md
    assert "faster than" not in text and "peer / scenesim" not in text
    assert peers.NOT_MEASURED in md
    assert "scenesim bench timeseries --quick --threads 1" in md
    data = json.loads((out / "bench.json").read_text())
    assert all(r["peers"] == [] for r in data["rows"])
    # a case with a peer, peers not asked for: one "not measured" row, no number
    plan = peers.peer_plan("fit", (512, "ols"), peers=False)
    assert [p["status"] for p in plan] == [peers.NOT_MEASURED]
    row = dict(data["rows"][0], workload="fit", case="512x512 ols", peers=plan)
    (line,) = [ln for ln in bench._peer_markdown([row]).splitlines() if "stcal" in ln]
    cells = [c.strip() for c in line.split("|")[6:14]]
    assert cells[1] == peers.NOT_MEASURED and set(cells[2:]) == {"-"}


def test_peer_plan_says_why_a_peer_is_not_measured(monkeypatch):
    assert peers.peer_plan("timeseries", 30, peers=True) == []
    assert peers.peer_plan("fit", (512, "cds"), peers=True) == []
    (ng,) = peers.peer_plan("noise", 10, peers=True)
    assert ng["status"] == peers.NOT_MEASURED and "--ng" in ng["reason"]
    assert "package index" in ng["reason"]
    (ng,) = peers.peer_plan("noise", 10, peers=True, ng_path="/x/nghxrg.py")
    assert ng["status"] == "run"
    # more frames than the memory available now: not run, with the estimate
    monkeypatch.setattr(peers, "_available_bytes", lambda: 4e9)
    (ng,) = peers.peer_plan("noise", 40, peers=True, ng_path="/x/nghxrg.py")
    assert ng["status"] == peers.NOT_MEASURED and "GB" in ng["reason"]
    monkeypatch.setattr(peers, "_installed", lambda m: False)
    (rs,) = peers.peer_plan("roman", "full", peers=True)
    assert rs["status"] == peers.NOT_MEASURED and "scenesim[peers]" in rs["reason"]
    (st,) = peers.peer_plan("fit", (2048, "gls-jump"), peers=True)
    assert st["label"] == "stcal LIKELY" and st["status"] == peers.NOT_MEASURED


def test_ng_peak_estimate_grows_with_frames():
    # NG's 1/f time line: 2 nstep2 float64 samples, nstep2 the next power of two of
    # (512 + 12) x (2048 + 1) x frames steps per output
    nstep = 524 * 2049 * 10
    nstep2 = 1 << (nstep - 1).bit_length()
    assert peers.ng_peak_bytes(10) == 64 * nstep2 + 32 * 10 * 2048 * 2048
    assert peers.ng_peak_bytes(88) > 2 * peers.ng_peak_bytes(40)
    with pytest.raises(ParameterError, match="nghxrg"):
        peers.check_ng_path("/nonexistent/nghxrg.py")


@pytest.mark.parametrize("name, text, why", [
    ("nghxrg.txt", "class HXRGNoise:\n    pass\n", "does not end in .py"),
    ("nghxrg.py", "print('not NG')\n", "defines no class HXRGNoise"),
    ("nghxrg.py", None, "not a file"),
])
def test_ng_path_that_cannot_be_ng_is_refused_before_work(tmp_path, name, text, why):
    # refused by name: a file Python cannot import as a module, one that does not
    # define NG's class, a directory
    path = tmp_path / name
    if text is None:
        path.mkdir()
    else:
        path.write_text(text)
    with pytest.raises(ParameterError, match=rf"'--ng' must be the path of NG's "
                                             rf"nghxrg.py .*{why}"):
        peers.check_ng_path(str(path))


_FAKE_NG = '''
import numpy as np
from astropy.io import fits

class HXRGNoise:
    nghxrg_version = 0.5

    def __init__(self, naxis3=None, pca0_file=None, verbose=False):
        self.n = naxis3
        self.pca0 = fits.getdata(pca0_file)

    def mknoise(self, o_file):
        assert o_file is None
        return fits.PrimaryHDU(np.zeros((self.n, 8, 8), np.uint16))
'''


def test_ng_peer_runs_the_users_file_in_its_own_process(tmp_path):
    """A stand-in nghxrg.py at the user's path is run, measured and labelled with its
    own version; one that fails is "not measured" with its error."""
    ng = tmp_path / "nghxrg.py"
    ng.write_text(_FAKE_NG)
    work = tmp_path / "w"
    work.mkdir()
    (plan,) = peers.peer_plan("noise", 2, peers=True, ng_path=str(ng))
    m = peers.run_peer(plan, "noise", 2, str(work), ng_path=str(ng))
    assert m["status"] == "measured", m
    assert m["version"] == "0.5" and m["wall"] >= m["inprocess"] > 0
    assert m["peak_rss_mb"] > 0 and len(m["load_before"]) == 3
    assert (work / "pca0.fits").exists()
    ng.write_text("raise RuntimeError('no such luck')\n")
    m = peers.run_peer(plan, "noise", 2, str(work), ng_path=str(ng))
    assert m["status"] == peers.NOT_MEASURED and "no such luck" in m["reason"]


def test_stcal_peer_fits_the_fit_workloads_own_cube(tmp_path):
    """stcal OLS_C, in its own process, fits the very file the fit workload loads: its
    median slope is the cube's rate (10 e-/s) within 5 sigma, like scenesim's."""
    pytest.importorskip("stcal")
    case = (64, "ols")
    kw = workloads.prepare_fit(case, str(tmp_path))
    cube = np.load(kw["cube"])
    assert np.array_equal(cube, workloads.fit_input(64)[0])
    (plan,) = peers.peer_plan("fit", case, peers=True)
    m = peers.run_peer(plan, "fit", case, str(tmp_path))
    assert m["status"] == "measured", m
    ours = workloads.bench_fit(case, 1, cube=kw["cube"])
    # 4096 pixels; one slope's sigma at 10 e-/s over 20 x 10.7 s with 10 e- reads is
    # ~0.2 e-/s; the median's ~1.25 sigma/sqrt(n) ~ 0.004; 5 sigma ~ 0.02
    assert m["median_slope"] == pytest.approx(10.0, abs=0.05)
    assert ours["median_slope"] == pytest.approx(10.0, abs=0.05)
    slope = np.load(tmp_path / "slope.npy")
    assert slope.shape == (64, 64) and np.isfinite(slope).all()


@pytest.mark.slow
def test_romanisim_peer_runs_on_the_roman_rate_map(tmp_path):
    """romanisim's L1 on a small rate map with the Roman workload's MA table."""
    pytest.importorskip("romanisim")
    _, ro, rate = workloads.roman_scene("quick")
    np.save(tmp_path / "rate.npy", rate[:72, :72])
    spec = dict(rate=str(tmp_path / "rate.npy"), seed=7,
                ma_table=[[r[0], len(r)] for r in ro.resultants],
                result=str(tmp_path / "r.json"), output=str(tmp_path / "l1.asdf"))
    (tmp_path / "spec.json").write_text(json.dumps(spec))
    script = "import runpy; runpy.run_path(%r, run_name='__main__')" % str(
        BENCH_DIR / "peer_scripts.py")
    m = run_process([sys.executable, "-c", script, "romanisim", str(tmp_path / "spec.json")],
                    cwd=str(tmp_path), stdout_path=str(tmp_path / "o"),
                    stderr_path=str(tmp_path / "e"))
    assert m["returncode"] == 0, (tmp_path / "e").read_text()[-2000:]
    res = json.loads((tmp_path / "r.json").read_text())
    assert res["inprocess"] > 0 and res["version"]
    assert os.path.getsize(tmp_path / "l1.asdf") > 9 * 64 * 64 * 2


def test_peak_memory_is_the_processs_own(tmp_path):
    """A process started by a parent that holds 300 MB reports its own peak, not the
    parent's: Linux starts a child's ru_maxrss at the parent's high-water mark."""
    held = np.ones(300 * 2**20 // 8)          # 300 MB, touched
    script = "from scenesim.bench.process import peak_rss_self; print(peak_rss_self())"
    m = run_process([sys.executable, "-c", script], cwd=str(tmp_path),
                    stdout_path=str(tmp_path / "o"), stderr_path=str(tmp_path / "e"))
    assert m["returncode"] == 0, (tmp_path / "e").read_text()
    own = float((tmp_path / "o").read_text())
    assert m["rusage_maxrss_mb"] >= 300
    # an interpreter that imports only os, subprocess and time: ~10-20 MB
    assert 0 < own < 100
    del held


_FORKS_200MB = '''
import os, time
import numpy as np
pid = os.fork()
if pid == 0:
    held = np.ones(200 * 2**20 // 8)      # 200 MB, touched, in the child only
    time.sleep(1.0)
    os._exit(0)
os.waitpid(pid, 0)
from scenesim.bench.process import peak_rss_self
print(peak_rss_self())
'''


def test_peak_memory_counts_a_forked_helper(tmp_path):
    """A process whose forked child holds 200 MB for 1 s: its own VmHWM misses it,
    the sampled tree (every 0.1 s, ~10 samples while it is held) does not."""
    m = run_process([sys.executable, "-c", _FORKS_200MB], cwd=str(tmp_path),
                    stdout_path=str(tmp_path / "o"), stderr_path=str(tmp_path / "e"))
    assert m["returncode"] == 0, (tmp_path / "e").read_text()
    own = float((tmp_path / "o").read_text())
    assert own < 150                          # the interpreter and numpy: ~30-60 MB
    assert m["tree_pss_peak_mb"] >= 200       # the child's 200 MB, plus its share
    assert peak_memory(own, m["tree_pss_peak_mb"]) == m["tree_pss_peak_mb"]
    assert peak_memory(own, 0.0) == own


def test_pink_samples_follow_the_floor_definition():
    # NG defaults, 4 outputs: per read L (c_pink) + 4 L (u_pink) + 4 * 2 * (L/2) (ACN)
    # + (ny + nfoh) (picture frame): the floor's normals less the white ones
    det, p = noise.preset("H2RG", naxis1=256, naxis2=256), noise.NoiseParams()
    L = (det.ny + det.nfoh) * (det.ncols_out + det.nroh)
    assert limit.pink_samples(det, p, 3) == 3 * (L + 4 * L + 4 * L + det.ny + det.nfoh)
    nn, _ = bench.floor_counts(det, p, 3)
    ktc = det.ny * det.nx if p.ktc > 0 else 0
    assert limit.pink_samples(det, p, 3) == nn - 3 * det.ny * det.nx - ktc
    assert limit.pink_samples(det, None, 3) == 0
    assert limit.pink_samples(det, noise.ZERO_NOISE.replace(rd_noise=5.0), 3) == 0


def test_limit_parts_and_arguments(tmp_path):
    assert limit.fft_seconds(0, 2) == 0.0 and limit.write_seconds(0) == 0.0
    assert limit.fft_seconds(100_000, 2, repeats=1) > 0
    assert limit.write_seconds(3_000_000, str(tmp_path), repeats=1) > 0
    assert list(tmp_path.iterdir()) == []          # the written file is removed
    lim = limit.limit_seconds(10_000, 1000, 2.0, 40_000, 1000, 1, repeats=1)
    assert lim["limit"] == pytest.approx(lim["draws"] + lim["fft"] + lim["write"])
    assert lim["method"] == pytest.approx(lim["draws"] + lim["fft_method"] + lim["write"])
    assert lim["fft_method"] > 0
    with pytest.raises(ParameterError, match="n_samples"):
        limit.fft_seconds(-1, 1)
    with pytest.raises(ParameterError, match="nfft"):
        limit.fft_seconds(10, 1, nfft=7)
    with pytest.raises(ParameterError, match="'overlap'.*-1"):
        limit.fft_seconds(10, 1, overlap=-1)
    with pytest.raises(ParameterError, match="'overlap'.*32768"):
        limit.transforms(10, overlap=32768)
    with pytest.raises(ParameterError, match="nbytes"):
        limit.write_seconds(-5)


def test_method_floor_counts_one_overlap_save_block_per_28672_samples():
    # noise.pink's finest level: windows of 32768 samples keep 32768 - 4096 = 28672
    # new ones; the limit charges one transform per 32768 kept samples
    assert limit.transforms(28672, overlap=4096) == 1
    assert limit.transforms(28673, overlap=4096) == 2
    assert limit.transforms(10 * 28672, overlap=4096) == 10
    assert limit.transforms(10 * 32768) == 10 and limit.transforms(10 * 32768 + 1) == 11
    assert limit.transforms(0, overlap=4096) == 0
