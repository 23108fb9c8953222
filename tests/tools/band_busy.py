"""How busy the noise generator keeps its threads, band by band.  (issue 16)

Runs the full-frame H2RG noise generator (NG defaults, ``frames`` frames after one
untimed frame) on 1 and on 2 threads, in fresh processes, and times every task of
``NoiseGenerator._run`` (one call per band of rows, each ending at a barrier).
Printed per thread count: the wall time, the time spent outside the bands (the
frame's serial set-up), the tasks' summed time and the threads' busy fraction
(task time / (threads x band wall)), overall and per band position in the frame.
Task time on 2 threads above that on 1 is what the second thread costs the work
itself (GIL hand-overs, memory traffic); 1 - busy is the idle time at barriers.
Every number is measured in that run::

    python tests/tools/band_busy.py [frames]          # default 20
"""

import json
import subprocess
import sys
import threading
import time

__all__ = ["main"]


def _child(threads, frames):
    from noise.fast.memory import keep_freed_memory
    keep_freed_memory()
    import noise.generator as gen_module
    from noise import NoiseGenerator, NoiseParams, preset
    busy = {}
    runs = []

    def call(task):
        t = time.perf_counter()
        try:
            return task()
        finally:
            key = threading.get_ident()
            busy[key] = busy.get(key, 0.0) + time.perf_counter() - t

    def run(pool, tasks):
        before, t = sum(busy.values()), time.perf_counter()
        if pool is None or len(tasks) < 2:
            for task in tasks:
                call(task)
        else:
            list(pool.map(call, tasks))
        runs.append((time.perf_counter() - t, sum(busy.values()) - before))

    gen_module.NoiseGenerator._run = staticmethod(run)
    g = NoiseGenerator(preset("H2RG"), NoiseParams(), rng=1, threads=threads)
    it = g.frames(frames + 1, reuse=2)
    next(it)
    runs.clear()
    t = time.perf_counter()
    for _ in it:
        pass
    wall = time.perf_counter() - t
    per_frame = len(runs) // frames
    print(json.dumps({"wall": wall, "runs": runs, "per_frame": per_frame}))


def _row(threads, res):
    runs = res["runs"]
    band_wall = sum(r[0] for r in runs)
    work = sum(r[1] for r in runs)
    k = res["per_frame"]
    by_band = []
    for b in range(k):
        w = sum(r[0] for r in runs[b::k])
        by_band.append(sum(r[1] for r in runs[b::k]) / (threads * w))
    return (f"| {threads} | {res['wall']:.3f} | {res['wall'] - band_wall:.3f} | {work:.3f} | "
            f"{work / (threads * band_wall):.3f} | "
            + " / ".join(f"{v:.3f}" for v in by_band) + " |")


def main(argv=None):
    argv = sys.argv[1:] if argv is None else argv
    if argv[:1] == ["--child"]:
        _child(int(argv[1]), int(argv[2]))
        return 0
    if len(argv) > 1:
        print("usage: python tests/tools/band_busy.py [frames]")
        return 2
    frames = int(argv[0]) if argv else 20
    print(f"H2RG noise generator, NG defaults, {frames} frames")
    print("| threads | wall s | outside the bands s | task time s | busy | busy per band |")
    print("|---|---|---|---|---|---|")
    for threads in (1, 2):
        out = subprocess.run([sys.executable, __file__, "--child", str(threads),
                              str(frames)], capture_output=True, text=True, check=True)
        print(_row(threads, json.loads(out.stdout.splitlines()[-1])))
    return 0


if __name__ == "__main__":
    sys.exit(main())
