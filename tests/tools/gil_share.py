"""Where a run holds the GIL: summarise a py-spy ``--gil`` profile.  (issue 16)

py-spy is not a dependency.  Record a profile of the one-thread noise generator (or any
script) with it, then summarise::

    pip install --target /tmp/pyspy py-spy
    /tmp/pyspy/bin/py-spy record --gil -r 500 -f raw -o gil.txt -- \\
        python -c "from noise import NoiseGenerator, NoiseParams, preset
    g = NoiseGenerator(preset('H2RG'), NoiseParams(), rng=1, threads=1)
    for _ in g.frames(61): pass"
    python tests/tools/gil_share.py gil.txt [top]

With ``--gil``, py-spy samples only the thread that holds the GIL, so each sample's
innermost Python line is code running with the GIL held (the interpreter, or a C call
that does not release it).  Printed: the samples per part of the run (the first
matching frame among the six innermost), then the ``top`` innermost lines
(default 25).  Samples under an import (anywhere in the stack: module bodies too) are
a part of their own; the rest is the frame loop.
"""

import collections
import sys

__all__ = ["main", "PARTS"]

#: (part, substring of a frame) in priority order.
PARTS = (("import", "importlib"), ("stream construction", "streams.py"),
         ("stream construction", "seedhash.py"), ("normals", "normal.py"),
         ("scipy.fft wrappers", "scipy/fft"), ("frame rows", "_rows_task"),
         ("1/f compute", "_compute"), ("1/f write", "PinkSeries._"),
         ("1/f white", "_Level._fill"), ("thread pool", "concurrent/futures"),
         ("frame planning", "NoiseGenerator."))


def summarise(path, top=25):
    """``(total, parts, lines)``: sample counts per part and per innermost line."""
    parts, lines, total = collections.Counter(), collections.Counter(), 0
    with open(path) as f:
        for row in f:
            stack, _, n = row.rstrip().rpartition(" ")
            if not stack:
                continue
            n = int(n)
            total += n
            frames = stack.split(";")
            lines[frames[-1]] += n
            if any("importlib" in fr for fr in frames):    # anywhere: module bodies
                parts["import"] += n
                continue
            inner = frames[::-1][:6]
            for name, pat in PARTS[1:]:
                if any(pat in fr for fr in inner):
                    parts[name] += n
                    break
            else:
                parts["other"] += n
    return total, parts, lines.most_common(top)


def main(argv=None):
    argv = sys.argv[1:] if argv is None else argv
    try:
        path = argv[0]
        top = int(argv[1]) if len(argv) > 1 else 25
        if top < 1 or len(argv) > 2:
            raise ValueError
    except (IndexError, ValueError):
        print("usage: python tests/tools/gil_share.py PYSPY_RAW_FILE [top >= 1]")
        return 2
    total, parts, lines = summarise(path, top)
    loop = total - parts.get("import", 0)
    print(f"{total} samples with the GIL held, {loop} outside imports")
    for name, n in parts.most_common():
        share = "" if name == "import" else f" ({100 * n / max(loop, 1):.0f} % of the loop's)"
        print(f"{n:7d}  {name}{share}")
    print("innermost lines:")
    for line, n in lines:
        print(f"{n:7d}  {line}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
