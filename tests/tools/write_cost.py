"""What writing a ramp's frames to a new file costs, four ways.  (issue 16)

Writes ``FRAMES`` frames of 8 MB (an H2RG uint16 frame) to a new file in
``DIRECTORY`` (default: the system's temporary directory), one ``os.write`` per
frame, and prints the wall and CPU time (user + system) per frame of:

* ``buffered``: plain writes into the page cache, in a fresh process (its pages are
  whatever the kernel hands out: on some virtual machines, memory the host must fault
  in again);
* ``recycled``: the same, right after a file of the same size was written and
  deleted in the same process (pages freed a moment before);
* ``write-behind``: as :class:`noise.fitsio.WriteBehind` does it, each frame's
  write-back started and the frame two before dropped from the cache;
* ``direct``: ``O_DIRECT`` (no page cache; Linux only; skipped where refused).

Every number is measured in that run; the files are removed::

    python tests/tools/write_cost.py [FRAMES [DIRECTORY]]       # default 60 frames
"""

import mmap
import os
import subprocess
import sys
import tempfile
import time

__all__ = ["main"]

_FRAME = 8 << 20


def _cpu():
    t = os.times()
    return t.user + t.system


def _write(path, frames, how):
    """Seconds of wall and CPU to write ``frames`` frames to ``path`` ``how``."""
    buf = mmap.mmap(-1, _FRAME)             # page-aligned, as O_DIRECT needs
    buf.write(b"\x07" * _FRAME)
    flags = os.O_WRONLY | os.O_CREAT | os.O_TRUNC
    if how == "direct":
        flags |= os.O_DIRECT
    t0, c0 = time.perf_counter(), _cpu()
    fd = os.open(path, flags, 0o644)
    try:
        for k in range(frames):
            os.write(fd, buf)
            if how == "write-behind":
                os.posix_fadvise(fd, k * _FRAME, _FRAME, os.POSIX_FADV_DONTNEED)
                if k >= 2:
                    os.posix_fadvise(fd, (k - 2) * _FRAME, _FRAME,
                                     os.POSIX_FADV_DONTNEED)
    finally:
        os.close(fd)
    return time.perf_counter() - t0, _cpu() - c0


def _child(how, frames, directory):
    fd, path = tempfile.mkstemp(prefix=".write-cost-", dir=directory)
    os.close(fd)
    try:
        if how == "recycled":
            _write(path, frames, "buffered")
            os.unlink(path)
            how = "buffered"
        print(*_write(path, frames, how))
    finally:
        if os.path.exists(path):
            os.unlink(path)


def main(argv=None):
    argv = sys.argv[1:] if argv is None else argv
    if argv[:1] == ["--child"]:
        _child(argv[1], int(argv[2]), argv[3])
        return 0
    try:
        frames = int(argv[0]) if argv else 60
        if frames < 1 or len(argv) > 2:
            raise ValueError
    except ValueError:
        print("usage: python tests/tools/write_cost.py [FRAMES [DIRECTORY]]")
        return 2
    directory = argv[1] if len(argv) > 1 else tempfile.gettempdir()
    print(f"{frames} frames of 8 MB to a new file in {directory}")
    print("| how | wall ms per frame | CPU ms per frame |")
    print("|---|---|---|")
    for how in ("buffered", "recycled", "write-behind", "direct"):
        if how == "direct" and not hasattr(os, "O_DIRECT"):
            print(f"| {how} | not measured (no O_DIRECT here) | |")
            continue
        out = subprocess.run([sys.executable, __file__, "--child", how, str(frames),
                              directory], capture_output=True, text=True)
        if out.returncode:
            reason = (out.stderr.strip().splitlines() or ["failed"])[-1]
            print(f"| {how} | not measured ({reason}) | |")
            continue
        wall, cpu = map(float, out.stdout.split())
        print(f"| {how} | {wall / frames * 1e3:.2f} | {cpu / frames * 1e3:.2f} |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
