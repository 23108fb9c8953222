"""Process memory policy for long array workloads (glibc malloc tuning).

Why: a simulation allocates and frees the same large temporaries every read (band
buffers, FFT outputs, per-chunk means and draws).  By default glibc returns freed
memory at the top of the heap to the kernel once more than 128 kB is free, and serves
requests above a (dynamic) threshold with fresh ``mmap`` regions; the next allocation
then page-faults fresh pages, which the kernel must zero.  On the 4096^2 Roman-like
workload that zeroing was a large share of the CPU (BENCHMARKS.md).

:func:`keep_freed_memory` raises the trim threshold and the top pad so that freed heap
memory is kept for reuse, and fixes the mmap threshold at its maximum (32 MB), so only
full frames and larger come from ``mmap``.  Peak memory is unchanged (the same arrays
are live at the peak); memory freed after the peak is simply not handed back to the
kernel until the process exits.  It is a process-wide setting, so the library never
calls it on import: the ``scenesim`` command and the benchmark processes do.  On other
C libraries it does nothing.
"""

import ctypes
import os
import sys

__all__ = ["keep_freed_memory", "available_memory"]

_M_TRIM_THRESHOLD = -1
_M_TOP_PAD = -2
_M_MMAP_THRESHOLD = -3


def keep_freed_memory():
    """Tell glibc malloc to keep freed memory for reuse (see the module notes).

    Returns
    -------
    bool
        True if the settings were applied (glibc), False otherwise.
    """
    if not sys.platform.startswith("linux"):
        return False
    try:
        mallopt = ctypes.CDLL(None).mallopt
    except (OSError, AttributeError):
        return False
    mallopt.argtypes = [ctypes.c_int, ctypes.c_int]
    mallopt.restype = ctypes.c_int
    ok = mallopt(_M_MMAP_THRESHOLD, 32 * 1024 * 1024)
    ok &= mallopt(_M_TRIM_THRESHOLD, 1 << 30)
    ok &= mallopt(_M_TOP_PAD, 64 * 1024 * 1024)
    return bool(ok)


def available_memory():
    """Bytes of memory available to this process now, or None if unknown.

    ``MemAvailable`` of ``/proc/meminfo`` (what the kernel can give without swapping),
    bounded by the cgroup v2 limit ``memory.max - memory.current`` of this process
    when one is set; else ``os.sysconf('SC_AVPHYS_PAGES') * SC_PAGE_SIZE``.
    """
    avail = None
    try:
        with open("/proc/meminfo") as f:
            for line in f:
                if line.startswith("MemAvailable:"):
                    avail = float(line.split()[1]) * 1024
                    break
    except (OSError, ValueError, IndexError):
        avail = None
    if avail is None:
        try:
            avail = float(os.sysconf("SC_AVPHYS_PAGES") * os.sysconf("SC_PAGE_SIZE"))
        except (AttributeError, ValueError, OSError):
            return None
    try:
        with open("/sys/fs/cgroup/memory.max") as f:
            limit = f.read().strip()
        if limit != "max":
            with open("/sys/fs/cgroup/memory.current") as f:
                used = float(f.read().strip())
            avail = min(avail, max(float(limit) - used, 0.0))
    except (OSError, ValueError):
        pass
    return avail
