"""Helpers of the tests of forked helper processes: who a process's children are,
and which objects a factory made."""

import os

__all__ = ["children_of", "record_made"]


def children_of(pid=None):
    """Pids of the children of ``pid`` (default: this process), from every thread's
    ``/proc/PID/task/TID/children`` (Linux); empty if the process is gone."""
    pid = os.getpid() if pid is None else pid
    out = set()
    try:
        for tid in os.listdir(f"/proc/{pid}/task"):
            with open(f"/proc/{pid}/task/{tid}/children") as f:
                out |= {int(p) for p in f.read().split()}
    except OSError:
        pass
    return out


def record_made(monkeypatch, module, name):
    """Replace ``module.name`` (a class or factory) by a wrapper that makes the same
    objects and records them; return the list they are appended to."""
    made = []
    real = getattr(module, name)

    def spy(*args, **kwargs):
        made.append(real(*args, **kwargs))
        return made[-1]

    monkeypatch.setattr(module, name, spy)
    return made
