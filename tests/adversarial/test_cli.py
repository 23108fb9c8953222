"""The command against a hostile user, case by class: targets, inputs and signals.

Every case runs ``python -m scenesim.cli`` in a fresh directory and checks, after it:

* the exit status (2 for refused input, 128 + the signal for an interrupt);
* exactly one line on stderr (``-q`` everywhere, so no progress bar), naming the file
  or parameter, and no ``Traceback``;
* no file left behind and no existing file changed (hashes of the directory);
* no process left alive (the forked 1/f helper included).
"""

import hashlib
import os
import signal
import stat
import subprocess
import sys
import textwrap
import time

import numpy as np
import pytest
from astropy.io import fits

from forks import children_of

SCENE = """seed = 5
[detector]
preset = "H2RG"
naxis1 = {naxis}
naxis2 = {naxis}
[noise]
preset = "nirspec"
[readout]
pattern = "RAPID"
ngroups = {ngroups}
[sources]
dark_current = {dark}
background = 1.0
[output]
path = "out.fits"
"""

#: a time series on a window: with 2 threads its 1/f lines come from a forked helper
SERIES = """seed = 6
[detector]
preset = "H2RG"
[detector.subarray]
kind = "window"
x0 = 0
y0 = 0
nx = 64
ny = 64
[noise]
preset = "nirspec"
[readout]
pattern = "RAPID"
ngroups = 5
nints = {nints}
[sources]
background = 1.0
[output]
path = "out.fits"
"""


def _cli(args, cwd, **kw):
    return subprocess.run([sys.executable, "-m", "scenesim.cli", *args], cwd=cwd,
                          capture_output=True, text=True, **kw)


def _snapshot(directory):
    """``{name: sha256}`` of every file in ``directory`` (hidden ones included)."""
    out = {}
    for name in sorted(os.listdir(directory)):
        path = os.path.join(directory, name)
        if os.path.isfile(path):
            with open(path, "rb") as f:
                out[name] = hashlib.sha256(f.read()).hexdigest()
        else:
            out[name] = "<dir>"
    return out


def _one_line(stderr, *must_name):
    lines = [ln for ln in stderr.splitlines() if ln.strip()]
    assert len(lines) == 1, stderr
    assert "Traceback" not in stderr
    for word in must_name:
        assert word in lines[0], (word, lines[0])
    return lines[0]


@pytest.fixture
def workdir(tmp_path):
    (tmp_path / "scene.toml").write_text(SCENE.format(naxis=64, ngroups=3, dark=0.1))
    return tmp_path


def _exposure(workdir):
    res = _cli(["run", "scene.toml", "-q"], workdir)
    assert res.returncode == 0, res.stderr
    return workdir / "out.fits"


# ----------------------------------------------------------------- targets
@pytest.mark.parametrize("case", ["exists", "read-only", "file", "no-directory"])
def test_bench_report_targets_are_refused_before_any_work(tmp_path, case):
    # bench writes a directory of reports: an earlier report, a read-only one (even
    # with --overwrite), a file given as the directory, a missing parent
    argv = ["bench", "timeseries", "--quick", "--threads", "1", "--out", "b"]
    named = "b"
    if case in ("exists", "read-only"):
        (tmp_path / "b").mkdir()
        (tmp_path / "b" / "bench.md").write_text("precious")
        named = "bench.md"
        if case == "read-only":
            (tmp_path / "b" / "bench.md").chmod(stat.S_IRUSR | stat.S_IRGRP)
            argv += ["--overwrite"]
    elif case == "file":
        (tmp_path / "b").write_text("precious")
    else:
        argv[-1] = named = "missing/b"
    before = _snapshot(tmp_path)
    res = _cli(argv, tmp_path)
    assert res.returncode == 2
    _one_line(res.stderr, named, "'--out'" if case in ("file", "no-directory") else "")
    assert _snapshot(tmp_path) == before


def _commands(workdir):
    """Each command with its main output: ``(argv, output name)``."""
    _exposure(workdir)
    return {
        "run": (["run", "scene.toml", "-q", "-o", "target.fits"], "target.fits"),
        "noise": (["noise", "--naxis", "64", "--frames", "2", "-q", "-o",
                   "target.fits"], "target.fits"),
        "fit": (["fit", "out.fits", "-o", "target.fits"], "target.fits"),
    }


@pytest.mark.parametrize("command", ["run", "noise", "fit"])
@pytest.mark.parametrize("case", ["exists", "read-only", "directory", "no-directory"])
def test_output_targets_are_refused_before_any_work(workdir, command, case):
    argv, target = _commands(workdir)[command]
    path = workdir / target
    if case in ("exists", "read-only"):
        path.write_bytes(b"precious")
        if case == "read-only":
            path.chmod(stat.S_IRUSR | stat.S_IRGRP)
            argv = argv + ["--overwrite"]
    elif case == "directory":
        path.mkdir()
    else:
        argv = [a if a != target else "missing/target.fits" for a in argv]
        target = "missing"
    before = _snapshot(workdir)
    res = _cli(argv, workdir)
    assert res.returncode == 2
    _one_line(res.stderr, target)
    assert _snapshot(workdir) == before


@pytest.mark.parametrize("which", ["scene", "map"])
def test_run_never_writes_over_its_inputs_even_with_overwrite(workdir, which):
    fits.PrimaryHDU(np.full((64, 64), 0.2)).writeto(workdir / "dark.fits")
    (workdir / "scene.toml").write_text(SCENE.format(naxis=64, ngroups=3, dark='"dark.fits"'))
    target = "scene.toml" if which == "scene" else "dark.fits"
    before = _snapshot(workdir)
    res = _cli(["run", "scene.toml", "-q", "--overwrite", "-o", target], workdir)
    assert res.returncode == 2
    _one_line(res.stderr, target)
    assert _snapshot(workdir) == before


def test_fit_never_writes_over_the_exposure(workdir):
    _exposure(workdir)
    before = _snapshot(workdir)
    res = _cli(["fit", "out.fits", "-o", "out.fits", "--overwrite"], workdir)
    assert res.returncode == 2
    _one_line(res.stderr, "out.fits", "reads")
    assert _snapshot(workdir) == before


def test_compare_plots_on_a_file_is_refused(workdir):
    _cli(["run", "scene.toml", "-q", "--fit", "gls"], workdir)
    (workdir / "plots").write_text("not a directory")
    before = _snapshot(workdir)
    res = _cli(["compare", "out_gls.fits", "out_truth.fits", "--plots", "plots"],
               workdir)
    assert res.returncode == 2
    _one_line(res.stderr, "plots")
    assert _snapshot(workdir) == before


@pytest.mark.parametrize("figure, target", [("slope.png", "out_gls.fits"),
                                              ("residuals.png", "out_truth.fits")])
def test_compare_figures_never_replace_an_input(workdir, figure, target):
    """A figure's name that is one of compare's inputs is refused, even with
    --overwrite, and nothing changes."""
    res = _cli(["run", "scene.toml", "-q", "--fit", "gls"], workdir)
    assert res.returncode == 0, res.stderr
    (workdir / "plots").mkdir()
    os.replace(workdir / target, workdir / "plots" / figure)
    before = _snapshot(workdir / "plots")
    args = ["plots/slope.png" if target == "out_gls.fits" else "out_gls.fits",
            "plots/residuals.png" if target == "out_truth.fits" else "out_truth.fits"]
    res = _cli(["compare", *args, "--plots", "plots", "--overwrite"], workdir)
    assert res.returncode == 2
    _one_line(res.stderr, figure, "reads")
    assert _snapshot(workdir / "plots") == before


def test_run_figures_never_replace_the_scene_file(workdir):
    (workdir / "plots").mkdir()
    os.replace(workdir / "scene.toml", workdir / "plots" / "slope.png")
    before = _snapshot(workdir / "plots")
    res = _cli(["run", "plots/slope.png", "-q", "--fit", "gls", "--compare", "--plots",
                "plots", "--overwrite"], workdir)
    assert res.returncode == 2
    _one_line(res.stderr, "slope.png", "reads")
    assert _snapshot(workdir / "plots") == before
    assert sorted(os.listdir(workdir)) == ["plots"]


@pytest.mark.parametrize("truth", ["missing.fits", "garbage.fits"])
def test_a_refused_compare_makes_no_plot_directory(workdir, truth):
    _cli(["run", "scene.toml", "-q", "--fit", "gls"], workdir)
    (workdir / "garbage.fits").write_text("not FITS")
    before = _snapshot(workdir)
    res = _cli(["compare", "out_gls.fits", truth, "--plots", "new_plots"], workdir)
    assert res.returncode == 2
    _one_line(res.stderr, truth)
    assert _snapshot(workdir) == before


def test_overwrite_replaces_and_keeps_the_umask_mode(workdir):
    _exposure(workdir)
    (workdir / "out.fits").write_bytes(b"old")
    res = _cli(["run", "scene.toml", "-q", "--overwrite"], workdir)
    assert res.returncode == 0, res.stderr
    assert (workdir / "out.fits").read_bytes()[:6] == b"SIMPLE"


# ------------------------------------------------------------ bad settings
@pytest.mark.parametrize("argv, name", [
    (["run", "scene.toml", "-q", "--threads", "0"], "threads"),
    (["run", "scene.toml", "-q", "--threads", "-2"], "threads"),
    (["noise", "--threads", "0", "-q", "-o", "n.fits"], "threads"),
    (["run", "scene.toml", "-q", "--fit", "gls", "-o", "one.fits"], "fit"),
    (["run", "missing.toml", "-q"], "missing.toml"),
    (["fit", "missing.fits"], "missing.fits"),
])
def test_bad_settings_one_line_nothing_written(workdir, argv, name):
    if "one.fits" in argv:
        (workdir / "scene.toml").write_text(SCENE.format(naxis=64, ngroups=1, dark=0.1))
    before = _snapshot(workdir)
    res = _cli(argv, workdir)
    assert res.returncode == 2
    _one_line(res.stderr, name)
    assert _snapshot(workdir) == before


def test_fit_of_a_one_group_file_is_refused(workdir):
    (workdir / "scene.toml").write_text(SCENE.format(naxis=64, ngroups=1, dark=0.1))
    _exposure(workdir)
    before = _snapshot(workdir)
    res = _cli(["fit", "out.fits"], workdir)
    assert res.returncode == 2
    _one_line(res.stderr, "out.fits", "NGROUPS = 1")
    assert _snapshot(workdir) == before


# ------------------------------------------------------------------ signals
def _alive(pid):
    try:
        with open(f"/proc/{pid}/stat") as f:
            return f.read().split()[2] != "Z"
    except OSError:
        return False


def _default_signals():
    """In the child: the default dispositions of the signals sent.  A background job
    of a non-interactive shell (``pytest ... &``, ``nohup``) inherits SIGINT (and
    SIGHUP) as ignored, and Python then never raises KeyboardInterrupt; a user's
    command starts with the defaults."""
    for sig in (signal.SIGINT, signal.SIGTERM, signal.SIGHUP):
        signal.signal(sig, signal.SIG_DFL)


def _catches(pid, sig):
    """True once process ``pid`` has a handler for ``sig`` (``SigCgt`` of
    /proc/PID/status).  ``scenesim.cli.main`` installs its SIGTERM handler first:
    'start' means from then on, with the command module's imports (signals blocked)
    still ahead.  Earlier, while the interpreter starts and imports scenesim.cli, no
    scenesim code runs yet: SIGTERM takes its default action (exit, nothing
    written) and SIGINT Python's KeyboardInterrupt."""
    try:
        with open(f"/proc/{pid}/status") as f:
            for line in f:
                if line.startswith("SigCgt:"):
                    return bool(int(line.split()[1], 16) >> (int(sig) - 1) & 1)
    except OSError:
        pass
    return False


def _interrupt(argv, cwd, sig, when):
    """Start the command, send ``sig`` at ``when`` ('start': during start-up, once
    the command has its handler (:func:`_catches`);
    'writing': once a temporary output file exists), and return (result, the
    children it had)."""
    proc = subprocess.Popen([sys.executable, "-m", "scenesim.cli", *argv], cwd=cwd,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            preexec_fn=_default_signals)
    before = set(os.listdir(cwd))
    children = set()
    t0 = time.monotonic()
    while time.monotonic() - t0 < 60:
        children |= children_of(proc.pid)
        new = set(os.listdir(cwd)) - before
        if when == "start" and _catches(proc.pid, signal.SIGTERM):
            break
        if when == "writing" and any(n.startswith(".") for n in new):
            time.sleep(0.3)
            children |= children_of(proc.pid)
            break
        if proc.poll() is not None:
            break
        time.sleep(0.02)
    proc.send_signal(sig)
    out, err = proc.communicate(timeout=60)
    return proc.returncode, err, children


@pytest.mark.slow
@pytest.mark.parametrize("sig", [signal.SIGINT, signal.SIGTERM, signal.SIGHUP])
@pytest.mark.parametrize("when", ["start", "writing"])
@pytest.mark.parametrize("job", ["run", "noise", "series"])
def test_signals_leave_nothing_behind(tmp_path, sig, when, job):
    if job == "run":
        # ~10 s of work each: the signal always lands while the job runs
        (tmp_path / "scene.toml").write_text(SCENE.format(naxis=256, ngroups=200,
                                                          dark=0.1))
        argv = ["run", "scene.toml", "-q"]
    elif job == "series":            # forked 1/f helper (2 threads, small frames)
        (tmp_path / "scene.toml").write_text(SERIES.format(nints=3000))
        argv = ["run", "scene.toml", "-q", "--threads", "2"]
    else:                            # forked 1/f line helpers (large frames, 2^25 px)
        argv = ["noise", "--naxis", "1024", "--frames", "40", "-q", "-o", "n.fits",
                "--threads", "2"]
    before = _snapshot(tmp_path)
    code, err, children = _interrupt(argv, tmp_path, sig, when)
    assert code == 128 + sig, err          # the jobs last far longer than the wait
    if when == "writing" and job != "run":
        assert children                    # the helpers ran when the signal came
    _one_line(err, "interrupted", signal.Signals(sig).name)
    assert _snapshot(tmp_path) == before
    time.sleep(0.2)
    assert not [c for c in children if _alive(c)]


@pytest.mark.slow
def test_sigkill_leftovers_are_removed_by_the_next_run(tmp_path):
    # SIGKILL cannot be caught: the killed run's temporary files stay, named with its
    # pid; the next run in that directory removes them (their owner is dead), says
    # so, and writes its own outputs
    (tmp_path / "scene.toml").write_text(SCENE.format(naxis=256, ngroups=200,
                                                      dark=0.1))
    code, err, _ = _interrupt(["run", "scene.toml", "-q"], tmp_path, signal.SIGKILL,
                              "writing")
    assert code == -signal.SIGKILL
    left = [n for n in os.listdir(tmp_path) if n.startswith(".")]
    assert left and all(n.startswith(".scenesim-") for n in left)
    (tmp_path / "scene.toml").write_text(SCENE.format(naxis=64, ngroups=3, dark=0.1))
    res = _cli(["run", "scene.toml"], tmp_path)
    assert res.returncode == 0, res.stderr
    assert "removed" in res.stdout and all(n in res.stdout for n in left)
    assert not [n for n in os.listdir(tmp_path) if n.startswith(".")]


#: Runs ``scenesim noise`` with its command replaced: the replacement sends the process
#: ``SIG`` (if ``SEND``) and turns the interrupt into another exception: with ``TURN``
#: = "context", a RuntimeError raised while handling it, as ``threading.Condition.wait``
#: does when the signal lands between its lock's release and its ``try`` ("cannot
#: release un-acquired lock", seen in CI in ``Future.result`` of the exposure's
#: write-behind); with ``TURN`` = "lost", an ImportError that does not keep it as
#: context, as numpy's import did when the signal landed inside it (seen in CI:
#: 'PyCapsule_Import could not import module "datetime"').
_TURNED = """
import os, signal, sys, time
import scenesim.commands as commands
from scenesim.cli import main

def command(args):
    lost = False
    try:
        if {send}:
            os.kill(os.getpid(), signal.{sig})
            time.sleep(30)               # the handler raises before this ends
    except KeyboardInterrupt:
        if {turn} == "context":
            raise RuntimeError("cannot release un-acquired lock")
        if not {turn}:
            raise
        lost = True
    if lost:                             # outside the handler: no context kept
        raise ImportError('PyCapsule_Import could not import module "datetime"')
    if {bug}:
        raise RuntimeError("a bug")

commands.noise_command = command
sys.exit(main(["noise", "-q", "-o", "n.fits"]))
"""


@pytest.mark.parametrize("sig", [signal.SIGINT, signal.SIGTERM, signal.SIGHUP])
@pytest.mark.parametrize("turn", [False, "context", "lost"])
def test_an_interrupt_ends_the_command_whatever_it_turned_into(tmp_path, sig, turn):
    code = _TURNED.format(sig=signal.Signals(sig).name, send=True, turn=repr(turn),
                          bug=False)
    res = subprocess.run([sys.executable, "-c", code], cwd=tmp_path, text=True,
                         capture_output=True, timeout=60, preexec_fn=_default_signals)
    assert res.returncode == 128 + sig, res.stderr
    _one_line(res.stderr, "interrupted", signal.Signals(sig).name)
    assert os.listdir(tmp_path) == []


def test_an_exception_without_an_interrupt_is_still_a_bug(tmp_path):
    # the rule above must not swallow real errors: no signal, a traceback, status 1
    code = _TURNED.format(sig="SIGTERM", send=False, turn=repr("lost"), bug=True)
    res = subprocess.run([sys.executable, "-c", code], cwd=tmp_path, text=True,
                         capture_output=True, timeout=60)
    assert res.returncode == 1
    assert "Traceback" in res.stderr and "RuntimeError: a bug" in res.stderr


@pytest.mark.parametrize("args, named", [
    (["--frames", "0"], "'--frames'"),
    (["--nints", "-1"], "'--nints'"),
    (["--naxis", "-4"], "'--naxis' must be >= 1, got -4"),
    # 0 read as "the preset's own" wrote a full 2048^2 cube (--n-out 0: 4 outputs)
    (["--naxis", "0"], "'--naxis' must be >= 1, got 0"),
    (["--n-out", "0"], "'--n-out' must be >= 1, got 0"),
    (["--n-out", "3"], "'--naxis' 64, '--n-out' 3"),
    (["--threads", "0"], "'--threads'"),
    (["--seed", "-1"], "'--seed'"),
    (["--seed", str(2 ** 63)], "'--seed' must be <= 9223372036854775807"),
    (["--unit", "DN", "--gain", "0"], "'--gain'"),
    (["--unit", "DN", "--gain", "nan"], "'--gain'"),
    (["--gain", "2"], "'--unit DN'"),                # a gain that would change nothing
    (["--unit", "DN", "--gain", "1e30"], "'gain' = 1e+30"),
    # the library's limits, by the options' names (a probe: 'nframes' for --frames)
    (["--frames", "1048577"], "'--frames' must be <= 1048576, got 1048577"),
    (["--nints", "1048577"], "'--nints' must be <= 1048576, got 1048577"),
    (["--frames", "1048576", "--nints", "1048576"], "'--frames' x '--nints' = "),
    # ACN on one column per output: the way out by the command's options (a probe:
    # "set 'acn' to 0", which no option of the command does)
    (["--n-out", "64"], "use '--noise white' (no ACN) or change '--naxis'/'--n-out'"),
    # a gain too small for the noise's range: the options, not 'bias_amp' or
    # 'bias_offset' (which the command does not set; a probe).  The least gain
    # 0.1728: (bias_offset 5000 + the pattern's top 6169.8 + 5 x 30.6) / 65535
    (["--unit", "DN", "--gain", "0.1"],
     "'--gain' 0.1 e-/DN is too small for '--noise nirspec' at the 16-bit ADC"),
    (["--unit", "DN", "--gain", "0.15"],
     "'--gain' must be >= 0.1728 e-/DN (or use '--noise white')"),
    (["--unit", "DN", "--gain", "0.05", "--noise", "white"],
     "'--gain' 0.05 e-/DN is too small for '--noise white' at the 16-bit ADC: "
     "the reads of a pixel without charge need 5026 e-"),
])
def test_noise_options_are_named_as_typed_before_any_work(tmp_path, args, named):
    """Each bad option of `scenesim noise` is refused in one line naming the option
    the user typed (before: 'nframes' for --frames, 'naxis1' for --naxis), before the
    progress bar or any file (before: --gain 0 failed after the bar was drawn, and
    --gain without --unit DN was written as a GAIN card of an electron file)."""
    res = _cli(["noise", "--preset", "H2RG", "--naxis", "64", "--frames", "3", *args,
                "-o", "n.fits"], tmp_path)
    assert res.returncode == 2, res.stderr
    _one_line(res.stderr, named)
    assert "%" not in res.stderr and os.listdir(tmp_path) == []


def test_a_gain_that_rounds_the_noise_away_is_warned_about_in_one_line(tmp_path):
    """--gain 1000 on 5.2 e- of read noise: every read one code (a probe: written
    without a word).  Written, with one warning line naming the option and the gain
    that keeps the noise; at 2 e-/DN no warning."""
    res = _cli(["noise", "--preset", "H2RG", "--naxis", "64", "--frames", "2",
                "--noise", "white", "--unit", "DN", "--gain", "1000", "-q", "-o",
                "n.fits"], tmp_path)
    assert res.returncode == 0, res.stderr
    lines = res.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith(
        "scenesim noise: warning: '--gain' 1000 e-/DN: half an ADC step"), res.stderr
    assert "below 10.4 e-/DN" in lines[0]
    res = _cli(["noise", "--preset", "H2RG", "--naxis", "64", "--frames", "2",
                "--noise", "white", "--unit", "DN", "--gain", "2", "-q", "-o",
                "m.fits"], tmp_path)
    assert res.returncode == 0 and res.stderr == "", res.stderr


def test_naxis_and_n_out_are_applied_together(tmp_path):
    """--naxis 40 with --n-out 4 on H1RG (16 outputs): 4 divides 40 (before: refused
    because --naxis was checked against the preset's 16 outputs first)."""
    from astropy.io import fits
    res = _cli(["noise", "--preset", "H1RG", "--naxis", "40", "--n-out", "4",
                "--frames", "1", "-q", "-o", "n.fits"], tmp_path)
    assert res.returncode == 0, res.stderr
    hdr = fits.getheader(tmp_path / "n.fits")
    assert (hdr["NAXIS1"], hdr["NAXIS2"], hdr["NOUTPUTS"]) == (40, 40, 4)


def test_fit_takes_the_fitter_in_any_case_and_lists_every_choice(workdir):
    _exposure(workdir)
    res = _cli(["fit", "out.fits", "--fitter", "GLS", "-o", "g.fits"], workdir)
    assert res.returncode == 0, res.stderr
    before = _snapshot(workdir)
    for bad in ("STCAL-bogus", "foo"):
        res = _cli(["fit", "out.fits", "--fitter", bad, "-o", "b.fits"], workdir)
        assert res.returncode == 2
        line = _one_line(res.stderr, "'--fitter'", repr(bad), "'stcal-ols_c'",
                         "'stcal-likely'", "'gls'")
        assert "algorithm" not in line
    res = _cli(["fit", "out.fits", "--jump-threshold", "-1", "-o", "b.fits"], workdir)
    assert res.returncode == 2
    _one_line(res.stderr, "'--jump-threshold'")
    # stcal's fitters have their own jump rule (likely: 4.5 sigma; ols_c: none): a
    # threshold given with them would change nothing (before: silently ignored)
    for fitter, words in (("stcal-likely", "4.5 sigma"), ("stcal-ols_c", "without jump")):
        res = _cli(["fit", "out.fits", "--fitter", fitter, "--jump-threshold", "0", "-o",
                    "b.fits"], workdir)
        assert res.returncode == 2
        _one_line(res.stderr, "'--jump-threshold' 0 applies to scenesim's fitters")
        assert words in res.stderr
    assert _snapshot(workdir) == before


def test_scene_errors_found_at_run_time_name_the_scene_file(workdir):
    """A map's values (read when the run starts), a one-group readout with a fit, and
    the scene's own output directory: each error starts with the scene file, as the
    loader's do; an -o of the command line is not the scene's."""
    fits.writeto(workdir / "neg.fits", np.full((64, 64), -1.0))
    text = (workdir / "scene.toml").read_text()
    cases = {
        "map.toml": text.replace("background = 1.0", 'background = "neg.fits"'),
        "one.toml": text.replace("ngroups = 3", "ngroups = 1"),
        "dir.toml": text.replace('path = "out.fits"', 'path = "nodir/out.fits"'),
    }
    for name, body in cases.items():
        (workdir / name).write_text(body)
    before = _snapshot(workdir)
    for name, extra, word in (("map.toml", [], "'background' map"),
                              ("one.toml", ["--fit", "gls"], "[output] 'fit'"),
                              ("dir.toml", [], "nodir")):
        res = _cli(["run", name, "-q", *extra], workdir)
        assert res.returncode == 2, res.stderr
        line = _one_line(res.stderr, word)
        assert line.startswith(f"scenesim run: error: {workdir / name}: "), line
    (workdir / "out.fits").write_bytes(b"x")
    res = _cli(["run", "scene.toml", "-q", "-o", "out.fits"], workdir)
    assert "scene.toml" not in _one_line(res.stderr, "exists")
    assert _snapshot(workdir) == {**before, "out.fits": _snapshot(workdir)["out.fits"]}


def test_compare_refuses_the_exposure_of_another_run(workdir):
    """--exposure gives the read times; one of another run (another seed here, or
    another window or frame time) made a silently wrong report: only NINTS was
    compared.  The cards both files carry must agree."""
    assert _cli(["run", "scene.toml", "-q", "--fit", "gls"], workdir).returncode == 0
    (workdir / "other.toml").write_text(
        SCENE.format(naxis=64, ngroups=3, dark=0.1).replace("seed = 5", "seed = 6")
        .replace('path = "out.fits"', 'path = "other.fits"'))
    assert _cli(["run", "other.toml", "-q"], workdir).returncode == 0
    res = _cli(["compare", "out_gls.fits", "out_truth.fits", "--exposure", "other.fits"],
               workdir)
    assert res.returncode == 2
    _one_line(res.stderr, "other.fits", "'SEED'", "not the same exposure")
    res = _cli(["compare", "out_gls.fits", "out_truth.fits", "--exposure", "out.fits"],
               workdir)
    assert res.returncode == 0, res.stderr


@pytest.mark.parametrize("args, named", [
    (["calibrate", "d.fits", "-o", "n.toml", "--f-min", "-1"],
     "'--f-min' must be > 0, got -1.0"),
    (["calibrate", "d.fits", "-o", "n.toml", "--template", "nope.fits"],
     "'--template' file"),
    (["psd", "d.fits", "missing.fits"], "missing.fits' does not exist"),
])
def test_calibrate_and_psd_check_every_option_before_reading_a_dark(tmp_path, args,
                                                                     named):
    """A bad --f-min or --template, or a missing second file, failed only after the
    first dark had been read and fitted (a probe): now before any dark is read,
    one line, status 2, nothing written."""
    res = _cli(["noise", "--preset", "H2RG", "--naxis", "64", "--frames", "4", "-q",
                "-o", "d.fits"], tmp_path)
    assert res.returncode == 0, res.stderr
    before = sorted(os.listdir(tmp_path))
    res = _cli(args, tmp_path)
    assert res.returncode == 2, res.stderr
    _one_line(res.stderr, named)
    assert sorted(os.listdir(tmp_path)) == before


@pytest.mark.parametrize("argv, named", [
    (["run", "scene.toml", "-o", "nosuch/../x.fits", "-q"], "'nosuch/..'"),
    (["noise", "--naxis", "64", "--frames", "2", "-o", "nosuch/../n.fits", "-q"],
     "'nosuch/..'"),
    (["run", "scene.toml", "-o", "a" * 300 + ".fits", "-q"], "305 bytes"),
    (["compare", "out_gls.fits", "out_truth.fits", "--plots", "nosuch/../pq"],
     "'nosuch/..'"),
    (["compare", "out_gls.fits", "out_truth.fits", "--plots", "p" * 300],
     "300 bytes"),
])
def test_paths_the_kernel_cannot_write_are_refused_before_any_work(workdir, argv,
                                                                   named):
    """'nosuch/../x.fits' exists as text ('x.fits' in this directory) but the kernel
    goes through 'nosuch'; a name of 300 bytes exceeds the file system's 255.  A
    probe: refused only after the simulation (run, noise), a traceback (--plots),
    or a stray 'nosuch' directory made by compare.  Now one line, status 2, before
    any work, nothing made."""
    if argv[0] == "compare":
        res = _cli(["run", "scene.toml", "-q", "--fit", "gls"], workdir)
        assert res.returncode == 0, res.stderr
    before = sorted(os.listdir(workdir))
    res = _cli(argv, workdir)
    assert res.returncode == 2, res.stderr
    _one_line(res.stderr, named)
    assert "%" not in res.stderr                  # no progress bar: nothing ran
    assert sorted(os.listdir(workdir)) == before


def test_a_scene_file_of_any_name_runs(workdir):
    # 'scène.toml' crashed the write of the SCENE card (FITS takes ASCII) after the
    # engine was built, and failed every batch task: written printable now
    from astropy.io import fits
    (workdir / "scène 'ü'.toml").write_text((workdir / "scene.toml").read_text())
    res = _cli(["run", "scène 'ü'.toml", "-o", "o.fits", "-q"], workdir)
    assert res.returncode == 0, res.stderr
    assert fits.getheader(workdir / "o.fits")["SCENE"] == "sc?ne '?'.toml"


def test_a_signal_after_the_work_does_not_fail_a_finished_command(tmp_path):
    # A probe: Ctrl-C or SIGTERM in the 0.3-0.4 s the interpreter takes to shut down
    # after the command returned ended it with status 130 or 143 and no line, its
    # outputs complete (`scenesim run ... && next` stopped).  The console entry
    # ignores them once the command is done: here both arrive after it returned.
    code = textwrap.dedent("""
        import os, signal, sys, time
        sys.argv = ["scenesim", "noise", "--preset", "H1RG", "--naxis", "64",
                    "--frames", "1", "-q", "-o", "n.fits"]
        from scenesim.cli import console_main
        rc = console_main()
        os.kill(os.getpid(), signal.SIGINT)
        os.kill(os.getpid(), signal.SIGTERM)
        time.sleep(0.2)
        sys.exit(rc)
    """)
    res = subprocess.run([sys.executable, "-c", code], cwd=tmp_path,
                         capture_output=True, text=True, timeout=300)
    assert res.returncode == 0 and res.stderr == "", (res.returncode, res.stderr)
    assert os.listdir(tmp_path) == ["n.fits"]
