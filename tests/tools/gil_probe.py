"""Is the second thread's loss the GIL or the machine?  (issue 16)

Runs the same one-thread noise generator (full-frame H2RG, NG defaults, ``frames``
frames after one untimed frame) three ways, in back-to-back rounds:

* **one**: alone;
* **threads**: two independent generators at once, in two threads of one process
  (they share nothing but the interpreter, hence the GIL);
* **processes**: the same two at once, in two forked processes (they share the
  cores, the caches and the memory bus, not the GIL).

If the two processes each take as long as one alone while the two threads take
longer, the difference is the GIL, not memory or cache contention.  Every number
printed is measured in that run::

    python tests/tools/gil_probe.py [frames] [rounds]     # defaults 12 and 3
"""

import argparse
import multiprocessing as mp
import sys
import threading
import time

from noise import NoiseGenerator, NoiseParams, preset

__all__ = ["main"]


def _work(seed, frames):
    g = NoiseGenerator(preset("H2RG"), NoiseParams(), rng=seed, threads=1)
    it = g.frames(frames + 1)
    next(it)
    t0 = time.perf_counter()
    for _ in it:
        pass
    return time.perf_counter() - t0


def _in_process(seed, frames, q):
    q.put(_work(seed, frames))


def _threads(frames):
    res = [None, None]

    def run(i):
        res[i] = _work(i + 1, frames)

    ts = [threading.Thread(target=run, args=(i,)) for i in range(2)]
    for t in ts:
        t.start()
    for t in ts:
        t.join()
    return res


def _processes(frames):
    ctx = mp.get_context("fork")
    q = ctx.Queue()
    ps = [ctx.Process(target=_in_process, args=(i + 1, frames, q)) for i in range(2)]
    for p in ps:
        p.start()
    res = [q.get(), q.get()]
    for p in ps:
        p.join()
    return res


def main(frames=12, rounds=3):
    print(f"H2RG noise generator, 1 thread each, {frames} frames (seconds per generator)")
    for _ in range(rounds):
        one = _work(1, frames)
        th = _threads(frames)
        pr = _processes(frames)
        print(f"one {one:.3f} | two threads {th[0]:.3f} {th[1]:.3f} "
              f"({max(th) / one:.2f}x one) | two processes {pr[0]:.3f} {pr[1]:.3f} "
              f"({max(pr) / one:.2f}x one)")
    return 0


def _positive(text):
    try:
        value = int(text)
    except ValueError:
        value = 0
    if value < 1:
        raise argparse.ArgumentTypeError(f"must be an integer >= 1, got {text!r}")
    return value


if __name__ == "__main__":
    ap = argparse.ArgumentParser(description="GIL or machine: one generator alone, "
                                 "two in threads, two in processes")
    ap.add_argument("frames", nargs="?", type=_positive, default=12,
                    help="frames per generator (default 12)")
    ap.add_argument("rounds", nargs="?", type=_positive, default=3,
                    help="rounds of the three runs (default 3)")
    args = ap.parse_args()
    sys.exit(main(args.frames, args.rounds))
