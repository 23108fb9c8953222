"""How well each phase of a read scales to two threads.  (issue 16)

Runs one ``scenesim bench`` engine case (default ``jwst full-engine``) on 1 and on 2
threads, in fresh processes, and times the two phases of every read around their calls:
collecting the charge (``ChargeEngine._charge_of_read``: Poisson draws, cosmic rays,
IPC) and making the noise frame (``NoiseGenerator._frame``), with the process CPU time
spent inside each.  Printed per phase: wall, CPU, cores busy (CPU / wall) and the
speed-up from the second thread.  Every number is measured in that run::

    python tests/tools/engine_phases.py [workload case]     # default: jwst full-engine
"""

import json
import resource
import subprocess
import sys
import time

__all__ = ["main"]


def _cpu():
    r = resource.getrusage(resource.RUSAGE_SELF)
    return r.ru_utime + r.ru_stime


def _child(workload, case, threads):
    from noise.fast.memory import keep_freed_memory
    keep_freed_memory()
    import scenesim.engine as engine
    from noise.generator import NoiseGenerator
    from scenesim.bench import run_case
    acc = {}

    def timed(name, fn):
        def wrapper(*args, **kwargs):
            t, c = time.perf_counter(), _cpu()
            out = fn(*args, **kwargs)
            a = acc.setdefault(name, [0.0, 0.0])
            a[0] += time.perf_counter() - t
            a[1] += _cpu() - c
            return out
        return wrapper

    engine.ChargeEngine._charge_of_read = timed("charge", engine.ChargeEngine._charge_of_read)
    NoiseGenerator._frame = timed("noise frame", NoiseGenerator._frame)
    row = run_case(workload, case, threads)
    acc["whole run"] = [row["wall"], row.get("cpu", float("nan"))]
    print(json.dumps(acc))


def main(argv=None):
    argv = sys.argv[1:] if argv is None else argv
    if argv[:1] == ["--child"]:
        _child(argv[1], argv[2], int(argv[3]))
        return 0
    if len(argv) not in (0, 2):
        print("usage: python tests/tools/engine_phases.py [workload case]")
        return 2
    workload, case = argv if argv else ("jwst", "full-engine")
    res = {}
    for threads in (1, 2):
        out = subprocess.run([sys.executable, __file__, "--child", workload, case,
                              str(threads)], capture_output=True, text=True, check=True)
        res[threads] = json.loads(out.stdout.strip().splitlines()[-1])
    print(f"{workload} {case}")
    print("| phase | wall s, 1 / 2 threads | CPU s, 1 / 2 | cores busy on 2 | speed-up |")
    print("|---|---|---|---|---|")
    for name in res[1]:
        (w1, c1), (w2, c2) = res[1][name], res[2][name]
        print(f"| {name} | {w1:.2f} / {w2:.2f} | {c1:.2f} / {c2:.2f} | {c2 / w2:.2f} | "
              f"{w1 / w2:.2f} |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
