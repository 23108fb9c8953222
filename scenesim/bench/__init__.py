"""Reference benchmarks: run time as a ratio to the random-number floor (DESIGN.md §7).

Absolute times drift on a shared machine, so every number is reported next to a
baseline measured in the same run, with the same number of threads:

* the **random-number floor** of a workload (:mod:`scenesim.bench.floor`) is the time
  to draw, in bulk and with the same threads, the variates its exact model cannot
  avoid;
* the ramp **fit** is not random-number bound: its baseline is the memory-bandwidth
  time of reading the resultant cube once (``np.sum``), labelled as such.

The workloads themselves are :mod:`scenesim.bench.workloads`.  Each case runs in a
fresh ``spawn`` subprocess, so ``ru_maxrss`` is the peak resident
memory of that case alone (it includes the ~100 MB of the interpreter and imports,
reported separately as ``base_rss``).  The floor is measured in the parent process
right after the case.

Reference numbers of other programs (from their authors / our earlier measurements,
not re-measured here): the original NG program (Rauscher 2015) takes 5.5 s for 1 frame,
54 s and 2.5 GB for 10 frames, 7 min and 9.5 GB for 40 frames of a 4-output H2RG;
romanisim 0.15 L1 takes 83-108 s and 3.4 GB for a full 4096x4096 exposure; stcal 1.20
ramp fitting of 2048x2048x20 takes ~11 s (C OLS) and 57-95 s (likelihood).
"""

import json
import multiprocessing as mp
import os
import resource
import sys
import time

import numpy as np

from noise.errors import ParameterError
from noise.fast.memory import keep_freed_memory
from scenesim.bench.floor import floor_counts, floor_seconds
from scenesim.bench.workloads import OPTION_CASES, WORKLOADS

__all__ = ["WORKLOADS", "OPTION_CASES", "main", "floor_seconds", "floor_counts", "run_case"]

_MB = 1024.0             # ru_maxrss is in KiB on Linux

#: Reference numbers of other programs, used for the comparison columns.
REFERENCES = {
    ("noise", 1): ("NG original", 5.5, None),
    ("noise", 10): ("NG original", 54.0, 2500.0),
    ("noise", 40): ("NG original", 420.0, 9500.0),
    ("roman", "full"): ("romanisim 0.15 L1", 83.0, 3400.0),
    ("fit", "ols"): ("stcal 1.20 C OLS", 11.0, None),
    ("fit", "gls"): ("stcal 1.20 likelihood", 57.0, None),
}


# ---------------------------------------------------------------------- running
def run_case(name, case, threads):
    """Run one case in this process; add peak and baseline RSS (MB) to its result."""
    base = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / _MB
    out = WORKLOADS[name][0](case, threads)
    out["peak_rss_mb"] = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / _MB
    out["base_rss_mb"] = base
    return out


def _child(name, case, threads, queue):
    keep_freed_memory()            # as the scenesim command does (noise.fast.memory)
    try:
        queue.put(("ok", run_case(name, case, threads)))
    except BaseException as exc:  # report any failure to the parent, then exit
        queue.put(("error", f"{type(exc).__name__}: {exc}"))


def _in_subprocess(name, case, threads):
    ctx = mp.get_context("spawn")
    q = ctx.Queue()
    p = ctx.Process(target=_child, args=(name, case, threads, q))
    p.start()
    status, value = q.get()
    p.join()
    if status != "ok":
        raise RuntimeError(f"workload {name} {case!r} failed: {value}")
    return value


def _label(case):
    if isinstance(case, tuple) and isinstance(case[1], bool):
        return f"{case[0]} ({'defeated' if case[1] else 'skipped'})"
    if isinstance(case, tuple) and isinstance(case[0], str):
        return f"{case[0]} ({case[1]})"
    if isinstance(case, tuple):
        return f"{case[0]}x{case[0]} {case[1]}"
    if case is None:
        return "exact"
    return f"{case:g}" if isinstance(case, float) else str(case)


def _reference(name, case):
    key = (name, case[1]) if name == "fit" and case[0] == 2048 else (name, case)
    return REFERENCES.get(key)


def _row(name, case, r, threads):
    row = dict(workload=name, case=_label(case), threads=threads, **r)
    if name == "fit":
        row["ratio"] = r["wall"] / r["baseline"] if r["baseline"] > 0 else None
        row["ratio_kind"] = "time / memory-bandwidth baseline"
    else:
        row["floor"] = floor_seconds(r["n_normal"], r["n_poisson"], r["lam"], threads)
        row["ratio"] = r["wall"] / row["floor"] if row["floor"] > 0 else None
        if r["n_poisson"] or r["n_normal"]:
            f2 = floor_seconds(r["n_normal"], r["n_poisson"], r["lam"], threads,
                               sampler="scenesim")
            row["floor_scenesim"] = f2
            row["ratio_scenesim"] = r["wall"] / f2 if f2 > 0 else None
        row["ratio_kind"] = "time / random-number floor"
    ref = _reference(name, case)
    if ref is not None:
        prog, sec, mb = ref
        row["reference"] = prog
        row["speedup_vs_reference"] = sec / r["wall"]
        row["reference_mb"] = mb
    return row


def _fmt(v, f):
    return "-" if v is None else format(v, f)


def _markdown(rows):
    head = ("| workload | case | wall s | CPU s | peak RSS MB | floor s | ratio | "
            "vs reference | notes |\n|---|---|---|---|---|---|---|---|---|\n")
    lines = []
    for r in rows:
        base = r.get("floor", r.get("baseline"))
        kind = "floor" if "floor" in r else "np.sum"
        ref = "-"
        if "reference" in r:
            ref = f"{r['speedup_vs_reference']:.1f}x faster than {r['reference']}"
            if r.get("reference_mb"):
                ref += f" ({r['reference_mb']:.0f} MB)"
        notes = r["detail"]
        if r.get("ratio_scenesim"):
            notes += (f"; ratio {r['ratio_scenesim']:.1f} against a floor drawn with "
                      f"scenesim's own samplers ({r['floor_scenesim']:.2f} s)")
        if r.get("pixel_reads") and r.get("floor"):
            notes += (f"; {r['pixel_reads'] / r['wall'] / 1e6:.0f} Mpixel-reads/s "
                      f"(floor {r['pixel_reads'] / r['floor'] / 1e6:.0f})")
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
        lines.append(f"| {r['workload']} | {r['case']} | {r['wall']:.2f} | "
                     f"{r['cpu']:.2f} | {r['peak_rss_mb']:.0f} | {_fmt(base, '.2f')} "
                     f"({kind}) | {_fmt(r['ratio'], '.1f')} | {ref} | {notes} |")
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
    fig.savefig(path, dpi=100)
    plt.close(fig)


def main(workloads, *, quick=False, out_dir="bench_out", threads=None):
    """Run the named workloads (all if empty), write ``bench.json``/``.md``/``.png``.

    Parameters
    ----------
    workloads : sequence of str
        Names from :data:`WORKLOADS`; empty: all.
    quick : bool
        Small sizes (seconds instead of minutes).
    out_dir : str
        Output directory (created).
    threads : int or None
        Threads for the workloads and the floor (default: all cores).

    Returns
    -------
    int
        Exit status (0).
    """
    names = list(workloads) or list(WORKLOADS)
    bad = [n for n in names if n not in WORKLOADS]
    if bad:
        raise ParameterError(f"'workloads' must be among {list(WORKLOADS)}, got {bad}")
    threads = int(threads) if threads is not None else (os.cpu_count() or 1)
    if threads < 1:
        raise ParameterError(f"'threads' must be >= 1, got {threads}")
    os.makedirs(out_dir, exist_ok=True)
    rows = []
    exact = {}
    for name in names:
        fn, full, small = WORKLOADS[name]
        for case in (small if quick else full):
            print(f"[bench] {name} {_label(case)} ...", flush=True)
            r = _in_subprocess(name, case, threads)
            arrays = {k: r.pop(k) for k in ("slope", "sigma_opt") if k in r}
            row = _row(name, case, r, threads)
            if name == "options":
                _versus_exact(row, arrays, exact)
            rows.append(row)
            extra = f" floor {row['floor']:.2f} s" if "floor" in row else \
                f" np.sum {row['baseline']:.3f} s"
            print(f"[bench] {name} {_label(case)}: wall {row['wall']:.2f} s, cpu "
                  f"{row['cpu']:.2f} s, peak {row['peak_rss_mb']:.0f} MB,{extra}, "
                  f"ratio {_fmt(row['ratio'], '.1f')}", flush=True)
            _write(rows, out_dir, threads, quick)
    return 0


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


def _write(rows, out_dir, threads, quick):
    meta = dict(threads=threads, quick=quick, nproc=os.cpu_count(),
                load_average=os.getloadavg(),
                python=sys.version.split()[0], numpy=np.__version__,
                date=time.strftime("%Y-%m-%d %H:%M:%S"))
    with open(os.path.join(out_dir, "bench.json"), "w") as f:
        json.dump(dict(meta=meta, rows=rows), f, indent=1)
    with open(os.path.join(out_dir, "bench.md"), "w") as f:
        f.write(f"Benchmarks ({meta['date']}, {threads} threads, "
                f"{'quick' if quick else 'full'})\n\n" + _markdown(rows))
    if any(r["workload"] in ("options", "pink") for r in rows):
        try:
            _plot(rows, os.path.join(out_dir, "bench.png"))
        except ImportError:
            print("[bench] matplotlib is not installed (pip install 'scenesim[plot]'): "
                  "no bench.png", flush=True)
