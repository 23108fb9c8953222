"""Whole-process measurements: wall time, CPU and peak memory of a fresh process.

What a user waits for is a process: the interpreter's start, the imports, the set-up,
the work and the write.  :func:`run_process` starts a command, waits for it with
``os.wait4`` and returns its wall time (from ``Popen`` to the reaped exit), its CPU
time as the kernel accounts it for the process and the children it reaped (the forked
helper of small frames included), and the load average before and after it, so every
measurement carries the state of the machine it was taken in.

Peak memory is **not** taken from ``wait4``: on Linux a process's ``ru_maxrss``
starts at the resident high-water mark of the process that forked it (the kernel
keeps the larger value across ``exec``; ``subprocess`` even execs from the parent's
own address space), so a 14 MB ``python -c pass`` started by a parent that once held
850 MB reports 850 MB.  Each measured program therefore reports its own high-water
mark, ``VmHWM`` of ``/proc/self/status`` (:func:`peak_rss_self`), which ``exec``
resets, read at its end; ``run_process`` returns the ``wait4`` value only as
``rusage_maxrss_mb``, an upper bound.

A program that forks helpers (scenesim's 1/f line helpers of long runs of large
frames) holds memory in them that its own ``VmHWM`` does not count.  While the
process runs, a thread of *this* process therefore samples every
:data:`TREE_INTERVAL` s the summed ``Pss`` (proportional set size: a page shared by
``k`` processes counts ``1/k`` in each, so the sum counts it once) of the process and
its descendants (``/proc/PID/smaps_rollup``), and returns the largest sum as
``tree_pss_peak_mb``.  Callers report ``max(VmHWM, tree_pss_peak_mb)``
(:func:`peak_memory`): the exact high-water mark of a lone process, and the whole
tree's at its sampled peak when it forks.
"""

import os
import subprocess
import threading
import time

__all__ = ["run_process", "load_average", "peak_rss_self", "peak_memory",
           "tree_pss_kb", "tail", "TREE_INTERVAL"]

_MB = 1024.0             # ru_maxrss is in KiB on Linux
#: Seconds between two samples of a measured process tree's memory.
TREE_INTERVAL = 0.1


def load_average():
    """The 1, 5 and 15 minute load averages, rounded to 0.01 (``os.getloadavg``)."""
    return [round(v, 2) for v in os.getloadavg()]


def peak_rss_self():
    """This process's own peak resident memory, MB: ``VmHWM`` of ``/proc/self/status``
    (reset by ``exec``, unlike ``ru_maxrss``; module notes), or ``ru_maxrss`` where
    ``/proc`` is missing."""
    try:
        with open("/proc/self/status") as f:
            for line in f:
                if line.startswith("VmHWM:"):
                    return int(line.split()[1]) / _MB
    except OSError:
        pass
    import resource
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / _MB


def _descendants(pid):
    """``pid`` and every process below it (``/proc/PID/task/TID/children``)."""
    found, todo = [], [pid]
    while todo:
        p = todo.pop()
        found.append(p)
        try:
            for tid in os.listdir(f"/proc/{p}/task"):
                with open(f"/proc/{p}/task/{tid}/children") as f:
                    todo += [int(c) for c in f.read().split()]
        except OSError:                     # ended meanwhile
            pass
    return found


def tree_pss_kb(pid):
    """Summed ``Pss`` (KiB) of ``pid`` and its descendants now; 0 where ``/proc``
    does not tell (processes that ended meanwhile count 0)."""
    total = 0
    for p in _descendants(pid):
        try:
            with open(f"/proc/{p}/smaps_rollup") as f:
                for line in f:
                    if line.startswith("Pss:"):
                        total += int(line.split()[1])
                        break
        except OSError:
            pass
    return total


def peak_memory(own_peak_mb, tree_peak_mb):
    """The peak memory reported for a measured process, MB: its own high-water mark
    or its tree's sampled peak (module notes), whichever is larger."""
    return max(float(own_peak_mb), float(tree_peak_mb or 0.0))


class _TreeSampler(threading.Thread):
    """Samples :func:`tree_pss_kb` of ``pid`` every :data:`TREE_INTERVAL` s until
    stopped; ``peak_kb`` is the largest sample."""

    def __init__(self, pid):
        super().__init__(name="scenesim-bench-memory", daemon=True)
        self.pid, self.peak_kb = pid, 0
        self._stop_event = threading.Event()

    def run(self):
        while not self._stop_event.wait(TREE_INTERVAL):
            self.peak_kb = max(self.peak_kb, tree_pss_kb(self.pid))

    def stop(self):
        self._stop_event.set()
        self.join()


def run_process(argv, *, cwd, stdout_path, stderr_path, env=None):
    """Run ``argv`` to its end; measure it as a whole process.

    Parameters
    ----------
    argv : sequence of str
        The command.
    cwd : str
        Working directory.
    stdout_path, stderr_path : str
        Files that receive the process's output (a pipe could fill and block it).
    env : mapping or None
        Environment (None: this process's).

    Returns
    -------
    dict
        ``wall`` (s), ``cpu`` (user + system s), ``rusage_maxrss_mb`` (``wait4``'s
        ``ru_maxrss``, MB: an upper bound that includes the parent's high-water
        mark at the start, module notes), ``tree_pss_peak_mb`` (the largest summed
        ``Pss`` of the process and its descendants, sampled every
        :data:`TREE_INTERVAL` s; module notes), ``returncode``, ``load_before`` and
        ``load_after`` (1/5/15 min load averages).
    """
    load_before = load_average()
    with open(stdout_path, "wb") as out, open(stderr_path, "wb") as err:
        t0 = time.perf_counter()
        proc = subprocess.Popen(list(argv), cwd=cwd, stdout=out, stderr=err, env=env)
        sampler = _TreeSampler(proc.pid)
        sampler.start()
        try:
            _, status, ru = os.wait4(proc.pid, 0)
        except BaseException:
            proc.kill()
            proc.wait()
            raise
        finally:
            sampler.stop()
        wall = time.perf_counter() - t0
    proc.returncode = os.waitstatus_to_exitcode(status)
    return dict(wall=wall, cpu=ru.ru_utime + ru.ru_stime,
                rusage_maxrss_mb=ru.ru_maxrss / _MB,
                tree_pss_peak_mb=sampler.peak_kb / _MB, returncode=proc.returncode,
                load_before=load_before, load_after=load_average())


def tail(path, lines=5):
    """The last ``lines`` lines of a text file ('' if missing)."""
    try:
        with open(path, errors="replace") as f:
            return "".join(f.readlines()[-lines:]).strip()
    except OSError:
        return ""
