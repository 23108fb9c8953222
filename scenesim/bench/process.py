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
"""

import os
import subprocess
import time

__all__ = ["run_process", "load_average", "peak_rss_self", "tail"]

_MB = 1024.0             # ru_maxrss is in KiB on Linux


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
        mark at the start, module notes), ``returncode``, ``load_before`` and
        ``load_after`` (1/5/15 min load averages).
    """
    load_before = load_average()
    with open(stdout_path, "wb") as out, open(stderr_path, "wb") as err:
        t0 = time.perf_counter()
        proc = subprocess.Popen(list(argv), cwd=cwd, stdout=out, stderr=err, env=env)
        try:
            _, status, ru = os.wait4(proc.pid, 0)
        except BaseException:
            proc.kill()
            proc.wait()
            raise
        wall = time.perf_counter() - t0
    proc.returncode = os.waitstatus_to_exitcode(status)
    return dict(wall=wall, cpu=ru.ru_utime + ru.ru_stime,
                rusage_maxrss_mb=ru.ru_maxrss / _MB, returncode=proc.returncode, load_before=load_before,
                load_after=load_average())


def tail(path, lines=5):
    """The last ``lines`` lines of a text file ('' if missing)."""
    try:
        with open(path, errors="replace") as f:
            return "".join(f.readlines()[-lines:]).strip()
    except OSError:
        return ""
