"""A forked helper process that produces numbered arrays into shared memory, in order.

Why a process and not a thread
------------------------------
Small frames (windows, time series) are made a batch at a time; their 1/f lines are
large GIL-free FFTs and normal draws, while the rest of a batch (white noise, the
charge engine, the file writer) is hundreds of small numpy calls per frame.  Run in a
worker *thread*, the line synthesis lost more than it gained: each small call releases
the GIL, the waiting thread takes it, and every hand-over between the two cores costs
a futex wake-up (BENCHMARKS.md has the measurement).  A forked child has
its own interpreter, so the two halves share nothing but the result buffers.

Protocol
--------
The parent maps ``depth`` result slots in anonymous shared memory (``MAP_SHARED``,
inherited by ``fork``) and forks.  The child calls ``make(j, slot)`` for ``j = 0, 1,
...`` in order, into slot ``j % depth``, and writes one byte to the *ready* pipe after
each; before reusing a slot it waits for one byte on the *free* pipe, which the parent
writes when it is done with an array (:meth:`ForkedProducer.release`).  A failure in
the child is sent as ``b"E"`` followed by its traceback, and raised in the parent by
:meth:`ForkedProducer.get`.  The child ends with ``os._exit`` (no atexit handlers, no
flushing of inherited buffers such as an output file being written by the parent).

Safety: ``fork`` copies only the calling thread, so a lock held by another thread at
that moment stays locked forever in the child.  :func:`available` therefore requires a
POSIX ``fork`` and a process with a single running thread; callers fall back to doing
the work themselves otherwise.  The results do not depend on which path is taken: the
caller's ``make`` must be a pure function of ``j`` (the 1/f samples depend only on
their indices, see :mod:`noise.pink`).
"""

import mmap
import os
import signal
import sys
import threading
import traceback

import numpy as np

from noise.errors import HelperProcessError

__all__ = ["ForkedProducer", "available"]


def available():
    """True if a producer can be forked safely here (POSIX fork, one thread running)."""
    return (hasattr(os, "fork") and sys.platform.startswith("linux")
            and threading.active_count() == 1)


class ForkedProducer:
    """Results ``make(0, a), make(1, a), ...`` made ahead by a forked child process.

    Parameters
    ----------
    make : callable
        ``make(j, outs)`` fills the float32 arrays ``outs`` (one per entry of
        ``shapes``) with result ``j``; run in the child, in order of ``j``.
    count : int
        Number of results.
    shapes : sequence of tuple of int
        Shapes of the float32 arrays of one result.
    depth : int
        Shared slots: the child runs at most ``depth - 1`` arrays ahead of the one the
        parent is using.

    Notes
    -----
    Use as a context manager (or call :meth:`close`): it stops and reaps the child.
    """

    def __init__(self, make, count, shapes, depth):
        self.count, self.depth = int(count), int(depth)
        shapes = [tuple(int(n) for n in shape) for shape in shapes]
        sizes = [int(np.prod(shape)) for shape in shapes]
        per = sum(sizes)
        self._map = mmap.mmap(-1, max(per, 1) * 4 * self.depth)
        self._slots = []
        for k in range(self.depth):
            arrays, off = [], k * per
            for shape, size in zip(shapes, sizes):
                arrays.append(np.frombuffer(self._map, dtype=np.float32, count=size,
                                            offset=off * 4).reshape(shape))
                off += size
            self._slots.append(arrays)
        ready_r, ready_w = os.pipe()
        free_r, free_w = os.pipe()
        # The interrupt signals stay blocked across fork: one that lands while fork
        # runs its at-fork handlers would be raised inside them, printed as
        # "Exception ignored" and lost.  Blocked, it waits (pending in the parent
        # only) and is raised once the producer is complete, which close() stops.
        interrupts = (signal.SIGINT, signal.SIGTERM, signal.SIGHUP)
        mask = signal.pthread_sigmask(signal.SIG_BLOCK, interrupts)
        pid = os.fork()
        if pid == 0:                                    # child: never returns
            code = 1
            try:
                os.close(ready_r)
                os.close(free_w)
                # the parent alone handles interrupts and stops the child
                # (close()); the child also ends when the parent dies (EOF on the
                # free pipe, EPIPE on the ready pipe)
                for sig in interrupts:
                    signal.signal(sig, signal.SIG_IGN)
                signal.pthread_sigmask(signal.SIG_SETMASK, mask)
                for j in range(self.count):
                    if j >= self.depth and os.read(free_r, 1) != b"\x01":
                        break                           # parent gone
                    make(j, self._slots[j % self.depth])
                    os.write(ready_w, b"\x01")
                code = 0
            except BaseException:                       # report, never propagate
                try:
                    os.write(ready_w, b"E" + traceback.format_exc().encode()[-60000:])
                except OSError:
                    pass
            finally:
                os._exit(code)
        os.close(ready_w)
        os.close(free_r)
        self._pid, self._ready, self._free = pid, ready_r, free_w
        self._next = 0
        try:
            signal.pthread_sigmask(signal.SIG_SETMASK, mask)   # pending ones: now
        except BaseException:
            self.close()
            raise

    @property
    def pid(self):
        """Process id of the helper, or None once it has been reaped."""
        return self._pid

    def slot(self, k):
        """The arrays of result slot ``k`` (``0 <= k < depth``; result ``j`` uses slot
        ``j % depth``), e.g. to build views of them before any result is ready."""
        return self._slots[k]

    def get(self, j):
        """Wait for result ``j`` (in order: 0, 1, ...) and return its arrays (views).

        The views stay valid until :meth:`release` of ``j``.
        """
        if j != self._next:
            raise RuntimeError(f"arrays must be taken in order: asked for {j}, "
                               f"next is {self._next}")
        token = os.read(self._ready, 1)
        if token != b"\x01":
            detail = b""
            if token == b"E":
                while True:
                    chunk = os.read(self._ready, 65536)
                    if not chunk:
                        break
                    detail += chunk
            self.close()
            if detail:
                last = detail.decode(errors="replace").strip().splitlines()[-1]
                raise HelperProcessError(f"the 1/f line process failed: {last}")
            raise HelperProcessError("the 1/f line process ended without a result "
                                     "(killed?); the run was stopped")
        self._next += 1
        return self._slots[j % self.depth]

    def release(self, j):
        """The parent is done with result ``j``: its slot may be reused."""
        if j + self.depth < self.count:
            try:
                os.write(self._free, b"\x01")
            except BrokenPipeError:
                # the child is gone: the next get() says how (its error, or that
                # it ended without a result)
                pass

    def close(self):
        """Stop the child (if still running), reap it and close the pipes."""
        if self._pid is None:
            return
        try:
            os.kill(self._pid, signal.SIGKILL)
        except ProcessLookupError:
            pass
        os.waitpid(self._pid, 0)
        os.close(self._ready)
        os.close(self._free)
        self._pid = None

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()
