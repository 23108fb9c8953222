"""Benchmarks: every number measured in the run that prints it (DESIGN.md §7, §9).

Absolute times drift on a shared machine, so every time is reported next to
baselines measured in the same run, with the same number of threads:

* the **random-number floor** of a workload (:mod:`scenesim.bench.floor`) is the time
  to draw, in bulk and with the same threads, the variates its exact model cannot
  avoid with numpy's samplers; a second floor draws them with scenesim's own;
* the **limit** of a simulation workload (:mod:`scenesim.bench.limit`, issue 16) adds
  to that second floor one inverse FFT per kept 1/f sample and one write of the output:
  ``wall / limit`` is the distance left for the current method;
* the **method floor** adds to the limit what the exact 1/f synthesis cannot avoid
  (a forward FFT of each overlap-save window, and the window's overlap):
  ``wall / method floor`` is the distance left for the implementation;
* the ramp **fit** is not random-number bound: its baseline is the memory-bandwidth
  time of reading the resultant cube once (``np.sum``), labelled as such.

The workloads themselves are :mod:`scenesim.bench.workloads`.  Each case runs in a
fresh process (``python -m scenesim.bench.child``, :mod:`scenesim.bench.process`):
the **in-process** time is the work the workload times (engine and write, or the fit);
the **process** time is what a user waits for: the interpreter, the imports, the
set-up, the work and the write, from start to exit, with the process's CPU and peak
resident memory (``os.wait4``) and the load average before and after.  Floors and
limits are measured in this process right after the case.  With ``scaling`` each case
runs once more on one thread (``wall_1thread``, ``speedup``), and a simulation case's
limit is measured on one thread too (``limit_1thread``, ``limit_speedup``): the
speed-up this machine gives the limit's own work (bulk draws, FFTs: independent
numpy calls that release the GIL), the ceiling against which scenesim's is judged.
With ``pairs`` > 1 the N- and one-thread runs alternate that many times and each
speed-up is the median of the pairs' own ratios (the machine's speed drifts over
minutes; a pair's two runs are seconds apart).

**Peers** (:mod:`scenesim.bench.peers`) run only when asked (``--peers``, or the
``peers`` workload), each in its own process on the very input of the scenesim case
beside it (NG from a path the user gives, romanisim, stcal); a peer that did not run
in this run is printed as "not measured".  This package holds no timing of any other
program (a test scans it).
"""

import io
import json
import os
import pickle
import shutil
import sys
import tempfile
import time

import numpy as np

from noise.errors import OutputError, ParameterError, ScenesimError
from noise.fast.memory import available_memory
from noise.fitsio import atomic_file, atomic_path
from noise.validate import check_writable
from scenesim.outputs import check_not_dangling, check_outputs, made_directory
from scenesim.bench.floor import floor_counts, floor_seconds
from scenesim.bench.limit import limit_seconds
from scenesim.bench.peers import NOT_MEASURED, check_ng_path, peer_plan, run_peer
from scenesim.bench.process import (load_average, peak_memory, peak_rss_self,
                                     run_process, tail)
from scenesim.bench.workloads import (FIT_SCALING_NRES, FIT_SCALING_SIZES, OPTION_CASES,
                                      PREPARE, WORKLOADS, fit_scaling_cases)

__all__ = ["WORKLOADS", "OPTION_CASES", "PEER_WORKLOADS", "main", "floor_seconds",
           "floor_counts", "limit_seconds", "run_case", "write_report"]

#: Workloads of ``scenesim bench peers``: those with a peer.
PEER_WORKLOADS = ("noise", "roman", "fit")


# ---------------------------------------------------------------------- running
def run_case(name, case, threads, **kwargs):
    """Run one case in this process; add peak and baseline RSS (MB) to its result.

    Both are this process's own high-water mark (``VmHWM``,
    :func:`scenesim.bench.process.peak_rss_self`): before the work (the imports) and
    after it.  ``kwargs`` go to the workload (the prepared input of :data:`PREPARE`)."""
    base = peak_rss_self()
    out = WORKLOADS[name][0](case, threads, **kwargs)
    out["peak_rss_mb"] = peak_rss_self()
    out["base_rss_mb"] = base
    return out


def _run_child(name, case, threads, work, kwargs):
    """One case in a fresh process: its in-process result plus the process's own
    measurement (``process_wall``, ``process_cpu``, loads) and ``peak_rss_mb``: the
    process's own high-water mark at its end (reported by the child,
    ``own_peak_rss_mb``) or, if larger, the sampled peak of its process tree
    (``tree_pss_peak_mb``: the 1/f line helpers included;
    :mod:`scenesim.bench.process`)."""
    tag = f"{name}_{_slug(case)}_{threads}t"
    result = os.path.join(work, tag + ".pickle")
    argv = [sys.executable, "-m", "scenesim.bench.child", name, repr(case), str(threads),
            result] + ([repr(kwargs)] if kwargs else [])
    err = os.path.join(work, tag + ".stderr")
    m = run_process(argv, cwd=work, stdout_path=os.path.join(work, tag + ".stdout"),
                    stderr_path=err)
    try:
        with open(result, "rb") as f:
            status, value = pickle.load(f)
    except OSError:
        status, value = "error", f"exit {m['returncode']}: {tail(err) or 'no output'}"
    if status != "ok":
        raise RuntimeError(f"workload {name} {case!r} failed: {value}")
    os.unlink(result)
    value["inprocess_peak_rss_mb"] = value.pop("peak_rss_mb")
    own = value.pop("process_peak_rss_mb")
    value.update(process_wall=m["wall"], process_cpu=m["cpu"],
                 peak_rss_mb=peak_memory(own, m["tree_pss_peak_mb"]), own_peak_rss_mb=own,
                 tree_pss_peak_mb=m["tree_pss_peak_mb"],
                 rusage_maxrss_mb=m["rusage_maxrss_mb"], load_before=m["load_before"],
                 load_after=m["load_after"])
    return value


def _slug(case):
    return "".join(c if c.isalnum() else "_" for c in repr(case)).strip("_")


def _label(case):
    if isinstance(case, tuple) and len(case) == 3:
        return f"{case[0]}x{case[0]} {case[1]} x{case[2]}"
    if isinstance(case, tuple) and isinstance(case[1], bool):
        return f"{case[0]} ({'defeated' if case[1] else 'skipped'})"
    if isinstance(case, tuple) and isinstance(case[0], str):
        return f"{case[0]} ({case[1]})"
    if isinstance(case, tuple):
        return f"{case[0]}x{case[0]} {case[1]}"
    if case is None:
        return "exact"
    return f"{case:g}" if isinstance(case, float) else str(case)


def _row(name, case, r, threads, work):
    row = dict(workload=name, case=_label(case), threads=threads, **r)
    if name == "fit":
        row["ratio"] = r["wall"] / r["baseline"] if r["baseline"] > 0 else None
        row["ratio_kind"] = "time / memory-bandwidth baseline"
        return row
    row["floor"] = floor_seconds(r["n_normal"], r["n_poisson"], r["lam"], threads)
    row["ratio"] = r["wall"] / row["floor"] if row["floor"] > 0 else None
    row["ratio_kind"] = "time / random-number floor"
    lim = _limit_of(r, threads, work)
    if r["n_poisson"] or r["n_normal"]:
        row["floor_scenesim"] = lim["draws"]
        row["ratio_scenesim"] = r["wall"] / lim["draws"] if lim["draws"] > 0 else None
    row["limit_parts"] = {k: lim[k] for k in ("draws", "fft", "write")}
    row["limit"] = lim["limit"]
    row["limit_ratio"] = r["wall"] / lim["limit"] if lim["limit"] > 0 else None
    # the method floor: the limit plus the forward FFTs and overlap of overlap-save
    row["fft_method"] = lim["fft_method"]
    row["method_floor"] = lim["method"]
    row["method_ratio"] = r["wall"] / lim["method"] if lim["method"] > 0 else None
    return row


def _fmt(v, f):
    return "-" if v is None else format(v, f)


def _load(v):
    return "-" if not v else f"{v[0]:.2f}"


def _notes(r):
    notes = r["detail"]
    if r.get("pairs", 1) > 1:
        notes += (f"; speed-up {_spread(r['speedups'])}, in-process s "
                  f"{'/'.join(f'{w:.2f}' for w in r['walls'])} against 1 thread "
                  f"{'/'.join(f'{w:.2f}' for w in r['walls_1thread'])}")
        if r.get("limit_speedups"):
            notes += f"; limit's speed-up {_spread(r['limit_speedups'])}"
    if r.get("pixel_reads") and r.get("floor"):
        notes += (f"; {r['pixel_reads'] / r['wall'] / 1e6:.0f} Mpixel-reads/s "
                  f"(floor {r['pixel_reads'] / r['floor'] / 1e6:.0f})")
    if "limit_parts" in r:
        p = r["limit_parts"]
        notes += (f"; limit = draws {p['draws']:.2f} + inverse FFTs {p['fft']:.2f} + "
                  f"write {p['write']:.2f} s")
        if r.get("fft_method"):
            notes += (f"; method floor: forward and inverse overlap-save FFTs "
                      f"{r['fft_method']:.2f} s instead of {p['fft']:.2f}")
    if "max_abs_bias" in r:
        notes += (f"; speed-up vs exact {_fmt(r.get('speedup_vs_exact'), '.2f')}; "
                  f"per decade of rate: max abs(bias) {r['max_abs_bias']:.3f} sigma_opt"
                  f" (1 sigma {r['bias_noise']:.3f}), max abs(scatter/sigma_opt - 1) "
                  f"{r['max_scatter_dev']:.3f} (1 sigma {r['scatter_noise']:.3f}), "
                  f"max abs(chi2 - 1) {r['max_chi2_dev']:.3f}; max per-pixel slope "
                  f"difference from exact {_fmt(r.get('max_diff_sigma'), '.2f')} sigma_opt")
    if "max_psd_dev" in r:
        notes += (f"; 1/f PSD vs theory, max per decade 30 Hz-30 kHz: designed "
                  f"{r['max_design_dev']:.1e} dex, measured {r['max_psd_dev']:.3f} dex"
                  f" (at most {r['psd_z']:.1f} sigma of its sampling noise); kurtosis "
                  f"of first "
                  f"differences {r['kurtosis']:.4f} +- {r['kurtosis_sigma']:.4f}")
    return notes


def _markdown(rows):
    """The table of the scenesim cases."""
    head = ("| workload | case | in-process s | process s | CPU s | peak memory MB | "
            "floor s | ratio | own-sampler floor s | ratio | limit s | wall / limit | "
            "method floor s | wall / method floor | "
            "1 thread s | speed-up | limit's speed-up | load | notes |\n"
            "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|\n")
    lines = []
    for r in rows:
        if r["workload"] == "fit":
            base = f"{r['baseline']:.2f} (np.sum)"
        else:
            base = _fmt(r.get("floor"), ".2f")
        lines.append(
            f"| {r['workload']} | {r['case']} | {r['wall']:.2f} | "
            f"{r['process_wall']:.2f} | {r['process_cpu']:.2f} | {r['peak_rss_mb']:.0f} | "
            f"{base} | {_fmt(r['ratio'], '.1f')} | {_fmt(r.get('floor_scenesim'), '.2f')} "
            f"| {_fmt(r.get('ratio_scenesim'), '.1f')} | {_fmt(r.get('limit'), '.2f')} | "
            f"{_fmt(r.get('limit_ratio'), '.1f')} | {_fmt(r.get('method_floor'), '.2f')} | "
            f"{_fmt(r.get('method_ratio'), '.1f')} | {_fmt(r.get('wall_1thread'), '.2f')} | "
            f"{_fmt(r.get('speedup'), '.2f')} | {_fmt(r.get('limit_speedup'), '.2f')} | "
            f"{_load(r.get('load_before'))} | "
            f"{_notes(r)} |")
    return head + "\n".join(lines) + "\n"


def _exponent(x, y):
    """Least-squares slope of log y against log x (None with fewer than 2 points)."""
    if len(x) < 2 or len(set(x)) < 2:
        return None
    return float(np.polyfit(np.log(x), np.log(y), 1)[0])


def _scaling_markdown(rows):
    """The fit's scaling cases: time and peak memory against ramp length and size,
    with the fitted exponents (each number from this run's rows)."""
    cases = [r for r in rows if r["workload"] == "fit" and "nres" in r]
    if not cases:
        return ""
    head = ("| size | resultants | in-process s | CPU s | process s | peak memory MB | cube "
            "MB (float32) | peak / cube | peak / peak at fewest resultants | ns per "
            "pixel x resultant (CPU) | CPU per resultant / at fewest | read pass s | "
            "np.sum s | wall / np.sum | load |\n"
            "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|\n")
    lines, fits = [], []
    for size in sorted({r["size"] for r in cases}):
        rs = sorted((r for r in cases if r["size"] == size), key=lambda r: r["nres"])
        r0 = rs[0]
        for r in rs:
            per = r["cpu"] / (size * size * r["nres"]) * 1e9
            per0 = r0["cpu"] / (size * size * r0["nres"]) * 1e9
            lines.append(
                f"| {size}x{size} | {r['nres']} | {r['wall']:.2f} | {r['cpu']:.2f} | "
                f"{r['process_wall']:.2f} | {r['peak_rss_mb']:.0f} | {r['cube_mb']:.0f} "
                f"| {r['peak_rss_mb'] / r['cube_mb']:.2f} | "
                f"{r['peak_rss_mb'] / r0['peak_rss_mb']:.2f} | {per:.1f} | "
                f"{per / per0:.2f} | {r['read_pass']:.2f} | {r['baseline']:.3f} | "
                f"{_fmt(r['ratio'], '.0f')} | {_load(r.get('load_before'))} |")
        fits.append(f"| {size}x{size} | " + " | ".join(
            _fmt(_exponent([r["nres"] for r in sel], [r[key] for r in sel]), ".2f")
            for key in ("wall", "cpu", "peak_rss_mb")
            for sel in (rs, [r for r in rs if r["nres"] >= 20])) + " |")
    return (head + "\n".join(lines) + "\n\nExponents (least squares of log against "
            "log resultants; all the size's cases, then those with >= 20 resultants):"
            "\n\n| size | wall, all | wall, >= 20 | CPU, all | CPU, >= 20 | peak memory, "
            "all | peak memory, >= 20 |\n|---|---|---|---|---|---|---|\n"
            + "\n".join(fits) + "\n")


def _peer_markdown(rows):
    """Process against process: each peer beside the scenesim case of the same input."""
    head = ("| workload | case | scenesim process s | scenesim CPU s | scenesim peak memory "
            "MB | peer | peer process s | peer CPU s | peer in-process s | peer peak memory "
            "MB | time: peer / scenesim | CPU: peer / scenesim | memory: peer / scenesim "
            "| load before / after | notes |\n"
            "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|\n")
    lines = []
    for r in rows:
        for p in r.get("peers", ()):
            pre = (f"| {r['workload']} | {r['case']} | {r['process_wall']:.2f} | "
                   f"{r['process_cpu']:.2f} | {r['peak_rss_mb']:.0f} | {p['label']}")
            if p["status"] != "measured":
                lines.append(f"{pre} | {NOT_MEASURED} | - | - | - | - | - | - | "
                             f"{_load(p.get('load_before'))} | {p['reason']} |")
                continue
            lines.append(
                f"{pre} {p['version']} | {p['wall']:.2f} | {p['cpu']:.2f} | "
                f"{p['inprocess']:.2f} | "
                f"{p['peak_rss_mb']:.0f} | {p['wall'] / r['process_wall']:.1f} | "
                f"{p['cpu'] / r['process_cpu']:.1f} | "
                f"{p['peak_rss_mb'] / r['peak_rss_mb']:.1f} | "
                f"{_load(p['load_before'])} / {_load(p['load_after'])} | "
                f"{p['detail']}; in-process scenesim {r['wall']:.2f} s, peer "
                f"{p['inprocess']:.2f} s |")
    if not lines:
        return ""
    return head + "\n".join(lines) + "\n"


def _plot(rows, path):
    """Run time against error: one point per approximation option."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    fig, ax = plt.subplots(figsize=(6, 4.5))
    for r in rows:
        if r["workload"] == "options":
            err = max(r["max_abs_bias"], r["max_scatter_dev"], r["max_chi2_dev"])
            label = r["case"]
        elif r["workload"] == "pink":
            err = r["max_psd_dev"]
            label = "1/f synthesis (exact)"
        else:
            continue
        ax.scatter(r["wall"], max(err, 1e-4))
        ax.annotate(label, (r["wall"], max(err, 1e-4)), fontsize=8)
    ax.set_xlabel("run time (s)")
    ax.set_ylabel("error: max over decades of |bias|, |scatter-1|, |chi2-1|\n"
                  "(1/f: max PSD deviation per decade, dex)")
    ax.set_yscale("log")
    ax.set_title("run time against error (one point per option)")
    fig.tight_layout()
    with atomic_path(path, overwrite=True) as tmp:
        fig.savefig(tmp, format="png", dpi=100)
    plt.close(fig)


def main(workloads, *, quick=False, out_dir="bench_out", threads=None, peers=False,
         ng=None, scaling=False, command=None, fit_sizes=None, fit_resultants=None,
         pairs=1, overwrite=False):
    """Run the named workloads (all if empty), write ``bench.json``/``.md``/``.png``.

    Parameters
    ----------
    workloads : sequence of str
        Names from :data:`WORKLOADS`, or ``'peers'`` (:data:`PEER_WORKLOADS` with
        ``peers=True``); empty: all workloads.
    quick : bool
        Small sizes (seconds instead of minutes).
    out_dir : str
        Output directory (created; its parent must exist).  Its ``bench.json``,
        ``bench.md`` (and ``bench.png`` with the ``options`` or ``pink`` workload)
        are checked before any work: an existing one is replaced only with
        ``overwrite``.  They are rewritten, each atomically, after every case.
    threads : int or None
        Threads for the workloads, floors and limits (default: all cores).
    peers : bool
        Run each case's peers (:mod:`scenesim.bench.peers`) beside it.
    ng : str or None
        Path of the original NG program, ``nghxrg.py`` (with ``peers``).
    scaling : bool
        Run each case again on one thread (when ``threads`` > 1).
    pairs : int
        With ``scaling``: alternating (``threads``, one thread) pairs of runs per case,
        >= 1; the speed-ups printed are medians over the pairs (:func:`_scaling`).
    command : str or None
        The command line, recorded in the outputs.
    overwrite : bool
        Replace the report files of an earlier run in ``out_dir``.
    fit_sizes, fit_resultants : sequence of int or None
        The fit's scaling grid (:func:`scenesim.bench.workloads.fit_scaling_cases`):
        given either, the ``fit`` workload runs only that grid (the default of the
        other: :data:`~scenesim.bench.workloads.FIT_SCALING_SIZES` or
        :data:`~scenesim.bench.workloads.FIT_SCALING_NRES`).

    Returns
    -------
    int
        Exit status (0).
    """
    names = list(workloads) or list(WORKLOADS)
    twice = sorted({n for n in names if names.count(n) > 1})
    if twice:          # it had run and reported the same case twice
        raise ParameterError(f"'workloads' names {', '.join(map(repr, twice))} more than "
                             f"once; name each workload once")
    if "peers" in names:
        names = [n for n in names if n != "peers"]
        names += [n for n in PEER_WORKLOADS if n not in names]
        peers = True
    bad = [n for n in names if n not in WORKLOADS]
    if bad:
        raise ParameterError(f"'workloads' must be among {list(WORKLOADS) + ['peers']}, "
                             f"got {bad}")
    threads = int(threads) if threads is not None else (os.cpu_count() or 1)
    if threads < 1:
        raise ParameterError(f"'threads' must be >= 1, got {threads}")
    if ng is not None and not peers:
        raise ParameterError("'--ng' runs NG as a peer: give it with --peers (or the "
                             "'peers' workload)")
    if isinstance(pairs, bool) or not isinstance(pairs, (int, np.integer)) or pairs < 1:
        raise ParameterError(f"'pairs' must be an integer >= 1, got {pairs!r}")
    if pairs > 1 and not scaling:
        raise ParameterError(f"'pairs' = {pairs} counts the 1- and N-thread runs of "
                             f"--scaling: give it with --scaling")
    pairs = int(pairs)
    ng = check_ng_path(ng)
    grid = _fit_grid(fit_sizes, fit_resultants)
    if grid and "fit" not in names:
        raise ParameterError("'fit_sizes'/'fit_resultants' set the fit workload's "
                             f"scaling grid: add the 'fit' workload (got {names})")
    _check_out_dir(out_dir, names, overwrite)
    meta = dict(command=command or f"scenesim.bench.main({names!r}, quick={quick}, "
                                   f"threads={threads}, peers={peers}, ng={ng!r}, "
                                   f"scaling={scaling}, pairs={pairs})",
                threads=threads, quick=quick, peers=peers, scaling=scaling, pairs=pairs,
                nproc=os.cpu_count(), load_average_start=load_average(),
                python=sys.version.split()[0], numpy=np.__version__,
                date=time.strftime("%Y-%m-%d %H:%M:%S"))
    plan = [(name, case, cases) for name in names
            for cases in [grid if name == "fit" and grid else
                          (WORKLOADS[name][2] if quick else WORKLOADS[name][1])]
            for case in cases]
    # until the last case is written, the report says how far it got
    meta.update(cases_planned=len(plan), complete=False)
    rows = []
    exact = {}
    work = tempfile.mkdtemp(prefix="scenesim-bench-")
    try:
        with made_directory(out_dir):     # removed again if nothing was written
            # --overwrite replaces the earlier report: its figure too, when this run
            # draws none (without it, a figure that is not in the way is kept)
            stale = os.path.join(out_dir, "bench.png")
            if overwrite and "bench.png" not in _report_files(names) and \
                    os.path.isfile(stale):
                os.unlink(stale)
            for k, (name, case, cases) in enumerate(plan):
                rows.append(_run_one(name, case, threads, work, scaling=scaling,
                                     peers=peers, ng=ng, exact=exact, cases=cases,
                                     pairs=pairs))
                _write(rows, out_dir, dict(meta, complete=k + 1 == len(plan)))
    except OSError as exc:          # a temporary cube or a report: disk full, EFBIG
        if isinstance(exc, ScenesimError):
            raise
        where = repr(exc.filename) if exc.filename else (
            f"its temporary inputs in {work!r} or its report in {out_dir!r}")
        raise OutputError(f"cannot write {where}: {exc.strerror or exc}") from exc
    finally:
        shutil.rmtree(work, ignore_errors=True)
    return 0


def _report_files(names):
    """The files a run of the workloads ``names`` writes into its output directory."""
    plot = any(n in ("options", "pink") for n in names)
    return ("bench.json", "bench.md") + (("bench.png",) if plot else ())


def _check_out_dir(out_dir, names, overwrite):
    """Refuse, before any work, an output directory that is a file, whose parent is
    missing, or that holds an earlier run's report files (without ``overwrite``)."""
    out_dir = check_not_dangling("--out", os.fspath(out_dir))
    files = _report_files(names)
    if os.path.exists(out_dir) and not os.path.isdir(out_dir):
        raise ParameterError(f"'--out' {out_dir!r} is a file; expected a directory for "
                             f"{', '.join(files)}")
    if os.path.isdir(out_dir):
        check_outputs({f"bench report {f}": os.path.join(out_dir, f) for f in files},
                      overwrite=overwrite)
    else:                       # to be created: its parent exists and is writable
        check_writable("--out", out_dir, overwrite=False)


#: Largest array side and resultant count of the fit's scaling grid.
FIT_MAX_SIZE, FIT_MAX_NRES = 8192, 1000
#: Bytes per pixel the fit of a scaling case holds besides its row blocks (the
#: per-pixel outputs, flags and the noise model's maps; the cube stays on disk and
#: is read by row blocks): a generous bound, so that an impossible grid is refused
#: before the first case, not after an hour.
_FIT_BYTES_PER_PIXEL = 64


def _fit_grid(sizes, nres):
    """The fit's scaling cases asked for (checked), or None.  The largest case's
    ramp file (uint16, in the system's temporary directory) must fit on that disk,
    and its per-pixel arrays in the memory available now."""
    if sizes is None and nres is None:
        return None
    got = {}
    for label, values, default, least, most in (
            ("fit_sizes", sizes, FIT_SCALING_SIZES, 8, FIT_MAX_SIZE),
            ("fit_resultants", nres, FIT_SCALING_NRES, 2, FIT_MAX_NRES)):
        values = default if values is None else list(values)
        if not values or any(isinstance(v, bool) or not isinstance(v, (int, np.integer))
                             or not least <= v <= most for v in values):
            raise ParameterError(f"'{label}' must be integers in [{least}, {most}], got "
                                 f"{values!r}")
        got[label] = sorted(set(int(v) for v in values))
    side, longest = max(got["fit_sizes"]), max(got["fit_resultants"])
    what = f"'fit_sizes'/'fit_resultants': the largest case, {side}^2 x {longest} resultants,"
    disk = side * side * longest * 2
    free = shutil.disk_usage(tempfile.gettempdir()).free
    if disk > free:
        raise ParameterError(f"{what} writes a {disk / 2 ** 30:.1f} GiB ramp file and "
                             f"{tempfile.gettempdir()!r} has {free / 2 ** 30:.1f} GiB "
                             f"free; ask for a smaller grid")
    memory, have = side * side * _FIT_BYTES_PER_PIXEL, available_memory()
    if have is not None and memory > have:
        raise ParameterError(f"{what} needs about {memory / 2 ** 30:.1f} GiB of memory "
                             f"and {have / 2 ** 30:.1f} GiB is available; ask for a "
                             f"smaller grid")
    return fit_scaling_cases(got["fit_sizes"], got["fit_resultants"])


def _run_one(name, case, threads, work, *, scaling, peers, ng, exact, cases=(),
             pairs=1):
    """One case: the scenesim process, floors and limit, one-thread run, peers."""
    print(f"[bench] {name} {_label(case)} ...", flush=True)
    kwargs = PREPARE[name](case, work, cases) if name in PREPARE else {}
    r = _run_child(name, case, threads, work, kwargs)
    arrays = {k: r.pop(k) for k in ("slope", "sigma_opt") if k in r}
    row = _row(name, case, r, threads, work)
    if name == "options":
        _versus_exact(row, arrays, exact)
    extra = (f" floor {row['floor']:.2f} s, limit {row['limit']:.2f} s (wall/limit "
             f"{_fmt(row['limit_ratio'], '.1f')}), method floor {row['method_floor']:.2f} s "
             f"(wall/method floor {_fmt(row['method_ratio'], '.1f')})" if "floor" in row
             else f" np.sum {row['baseline']:.3f} s")
    if "read_pass" in row:
        extra += (f", read pass {row['read_pass']:.3f} s, cube {row['cube_mb']:.0f} MB "
                  f"in float32")
    print(f"[bench] {name} {_label(case)}: in-process {row['wall']:.2f} s, process "
          f"{row['process_wall']:.2f} s, peak {row['peak_rss_mb']:.0f} MB,{extra}, "
          f"ratio {_fmt(row['ratio'], '.1f')}, load {_load(row['load_before'])}",
          flush=True)
    if scaling and threads > 1:
        _scaling(row, name, case, threads, work, kwargs, pairs)
    row["peers"] = []
    for plan in peer_plan(name, case, peers=peers, ng_path=ng):
        if plan["status"] == "run":
            print(f"[bench] {name} {_label(case)}: peer {plan['label']} ...", flush=True)
            plan = run_peer(plan, name, case, work, ng_path=ng)
        row["peers"].append(plan)
        if plan["status"] == "measured":
            print(f"[bench] {name} {_label(case)}: {plan['label']} {plan['version']}: "
                  f"process {plan['wall']:.2f} s ({plan['wall'] / row['process_wall']:.1f}"
                  f" x scenesim's {row['process_wall']:.2f} s), peak "
                  f"{plan['peak_rss_mb']:.0f} MB, load {_load(plan['load_before'])}",
                  flush=True)
        else:
            print(f"[bench] {name} {_label(case)}: {plan['label']}: {NOT_MEASURED} "
                  f"({plan['reason']})", flush=True)
    return row


def _scaling(row, name, case, threads, work, kwargs, pairs):
    """One-thread times and speed-ups of a case, from ``pairs`` alternating runs.

    Pair 1 is the case's first run (already in ``row``) and a one-thread run right
    after it; each further pair runs the case again on ``threads`` and then on one
    thread.  A simulation case's limit is measured in every pair on one thread, and
    again on ``threads`` from the second pair on.  The speed-ups reported are the
    medians over the pairs of each pair's own ratio: the machine's speed drifts by
    tens of per cent over minutes (BENCHMARKS.md), and a ratio of two runs made
    seconds apart is less exposed to that drift than one of medians over the whole
    run.  With one pair the figures are those of that pair.
    """
    walls, walls1, procs1 = [row["wall"]], [], []
    lims, lims1, methods1 = [row.get("limit")], [], []
    for k in range(pairs):
        if k:
            walls.append(_run_child(name, case, threads, work, kwargs)["wall"])
            if row.get("limit"):
                lims.append(_limit_of(row, threads, work)["limit"])
        r1 = _run_child(name, case, 1, work, kwargs)
        walls1.append(r1["wall"])
        procs1.append(r1["process_wall"])
        if row.get("limit"):
            one = _limit_of(row, 1, work)
            lims1.append(one["limit"])
            methods1.append(one["method"])
    speedups = [w1 / w for w, w1 in zip(walls, walls1)]
    row.update(pairs=pairs, walls=walls, walls_1thread=walls1,
               wall_1thread=float(np.median(walls1)),
               process_wall_1thread=float(np.median(procs1)),
               speedup=float(np.median(speedups)), speedups=speedups)
    ceiling = ""
    if row.get("limit"):
        # the machine's own speed-up on the limit's work (draws, FFTs, write:
        # independent, GIL-free numpy calls), measured in the same pairs
        lim_speedups = [l1 / ln for ln, l1 in zip(lims, lims1)]
        row.update(limit_1thread=float(np.median(lims1)),
                   limit_speedup=float(np.median(lim_speedups)),
                   limit_speedups=lim_speedups,
                   method_floor_1thread=float(np.median(methods1)))
        row["method_ratio_1thread"] = row["wall_1thread"] / row["method_floor_1thread"]
        ceiling = (f" (the limit's own work: {row['limit_1thread']:.2f} s on 1 thread, "
                   f"speed-up {_spread(lim_speedups)})")
    print(f"[bench] {name} {_label(case)}: 1 thread {row['wall_1thread']:.2f} s, "
          f"speed-up with {threads} threads {_spread(speedups)}{ceiling}", flush=True)


def _spread(values):
    """``'1.62'`` for one value; ``'1.62 (median of 3 pairs, 1.50-1.70)'`` for more."""
    if len(values) == 1:
        return f"{values[0]:.2f}"
    return (f"{float(np.median(values)):.2f} (median of {len(values)} pairs, "
            f"{min(values):.2f}-{max(values):.2f})")


def _limit_of(row, threads, work):
    """The limit of a simulation case's counts (``row``: its result or row), measured
    now on ``threads``."""
    return limit_seconds(row["n_normal"], row["n_poisson"], row["lam"],
                         row.get("n_pink", 0), row.get("output_bytes", 0), threads,
                         directory=work)


def _versus_exact(row, arrays, exact):
    """Options: the largest per-pixel slope difference from the exact case (same seed
    and scene), in units of the optimal sigma; and the speed-up over the exact case."""
    if row["case"].startswith("exact"):
        exact.update(arrays, wall=row["wall"])
        row["max_diff_sigma"] = 0.0
        row["speedup_vs_exact"] = 1.0
        return
    if "slope" in exact and "slope" in arrays:
        d = np.abs(arrays["slope"].astype(float) - exact["slope"]) / exact["sigma_opt"]
        row["max_diff_sigma"] = float(d.max())
        row["speedup_vs_exact"] = exact["wall"] / row["wall"]


def _write(rows, out_dir, meta):
    """Write ``bench.json`` (with the end time and load), ``bench.md`` and the plot."""
    meta = dict(meta, load_average_end=load_average(), cases_done=len(rows),
                end=time.strftime("%Y-%m-%d %H:%M:%S"))
    text = json.dumps(dict(meta=meta, rows=rows), indent=1)
    with atomic_file(os.path.join(out_dir, "bench.json"), overwrite=True) as f:
        f.write(text.encode())
    write_report(rows, out_dir, meta)


def _threads(n):
    """``'1 thread'``, ``'2 threads'``."""
    return f"{n} thread{'' if n == 1 else 's'}"


def write_report(rows, out_dir, meta):
    """Write ``bench.md`` (and ``bench.png``) from the rows and metadata of a run, as
    ``bench.json`` holds them (nothing is measured here)."""
    peer_table = _peer_markdown(rows)
    with atomic_file(os.path.join(out_dir, "bench.md"), overwrite=True) as raw, \
            io.TextIOWrapper(raw, encoding="utf-8") as f:
        if not meta.get("complete", True):
            f.write(f"**Incomplete: {meta.get('cases_done', len(rows))} of "
                    f"{meta.get('cases_planned', '?')} cases** (the run stopped before "
                    f"the rest; their rows are missing).\n\n")
        f.write(f"Benchmarks ({meta['date']} - {meta['end']}, {_threads(meta['threads'])}, "
                f"{'quick' if meta['quick'] else 'full'}; load average "
                f"{'/'.join(map(str, meta['load_average_start']))} at the start, "
                f"{'/'.join(map(str, meta['load_average_end']))} at the end)\n\n"
                f"    {meta['command']}\n\n"
                "Peak memory: a process's own high-water mark (VmHWM) or, if larger, "
                "the peak of its process tree's summed Pss (forked helpers included), "
                "sampled every 0.1 s.\n\n" + _markdown(rows))
        scaling = _scaling_markdown(rows)
        if scaling:
            f.write("\nThe fit's scaling (cube read by row blocks from its file; "
                    f"{_threads(meta['threads'])}):\n\n" + scaling)
        if peer_table:
            f.write("\nPeers, process against process, on the same input:\n\n"
                    + peer_table)
        else:
            f.write("\nPeers: none in this report, " + NOT_MEASURED + " (they run "
                    "with --peers: NG beside noise, romanisim beside roman, stcal "
                    "beside the fit's standard cases).\n")
    if any(r["workload"] in ("options", "pink") for r in rows):
        try:
            _plot(rows, os.path.join(out_dir, "bench.png"))
        except ImportError:
            print("[bench] matplotlib is not installed (pip install 'scenesim[plot]'): "
                  "no bench.png", flush=True)
