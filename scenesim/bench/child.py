"""One benchmark case in a fresh process (run by :func:`scenesim.bench.main`).

Usage: ``python -m scenesim.bench.child NAME CASE THREADS RESULT [KWARGS]`` where
``CASE`` and ``KWARGS`` are Python literals (``repr``) and ``RESULT`` is the pickle
file that receives ``("ok", result)`` or ``("error", message)``.  The process applies
:func:`noise.fast.memory.keep_freed_memory` as the ``scenesim`` command does, so its
time and memory are those of a user's run of the same work.  Its result carries
``process_peak_rss_mb``, the process's own high-water mark at the end
(:func:`scenesim.bench.process.peak_rss_self`; ``wait4``'s ``ru_maxrss`` would start
at the parent's).
"""

import ast
import pickle
import sys

__all__ = []


def _main(argv):
    name, case, threads, result = argv[:4]
    kwargs = ast.literal_eval(argv[4]) if len(argv) > 4 else {}
    from noise.fast.memory import keep_freed_memory
    keep_freed_memory()
    try:
        from scenesim.bench import run_case
        from scenesim.bench.process import peak_rss_self
        value = run_case(name, ast.literal_eval(case), int(threads), **kwargs)
        value["process_peak_rss_mb"] = peak_rss_self()
        out = ("ok", value)
    except BaseException as exc:  # reported to the parent, which raises it
        out = ("error", f"{type(exc).__name__}: {exc}")
    with open(result, "wb") as f:
        pickle.dump(out, f)
    return 0 if out[0] == "ok" else 1


if __name__ == "__main__":
    sys.exit(_main(sys.argv[1:]))
