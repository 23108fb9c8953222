"""Hash the science arrays of every example scene, run through the command line.

Used to prove that a refactor changes nothing: run it before and after, and diff the
two outputs (``python tests/tools/hash_scenes.py --out before.json``, then
``--out after.json`` and ``--diff before.json``).  Each example scene is run with its
own seed; scenes without a fit get ``--fit gls``, and the quick scene is also fitted
with every fitter and reference correction, and graded by ``compare``.  What is
hashed: the data of every HDU of every output file (images and tables, byte for byte)
and the text ``compare`` prints.  Headers are not hashed (they carry dates and
versions); the hash test in ``tests/test_scene_hashes.py`` pins the small scenes.
"""

import argparse
import glob
import hashlib
import json
import os
import subprocess
import sys
import tempfile
from concurrent.futures import ThreadPoolExecutor

import numpy as np
from astropy.io import fits

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.dirname(os.path.dirname(HERE))
SMALL = ("quick", "bright_star", "cosmic_rays", "transit")


def hdu_hashes(path):
    """``{extname: sha256 of the data bytes}`` for every HDU of a FITS file."""
    out = {}
    with fits.open(path) as hdul:
        for i, hdu in enumerate(hdul):
            name = hdu.name or f"HDU{i}"
            data = hdu.data
            if data is None:
                continue
            if isinstance(data, fits.FITS_rec):
                arr = np.asarray(data)
                h = hashlib.sha256(arr.tobytes())
                h.update(repr(arr.dtype.names).encode())
            else:
                h = hashlib.sha256(np.ascontiguousarray(data).tobytes())
                h.update(str(data.dtype).encode() + repr(data.shape).encode())
            out[name] = h.hexdigest()[:16]
    return out


def _run(args, cwd):
    res = subprocess.run([sys.executable, "-m", "scenesim.cli", *args], cwd=cwd,
                         capture_output=True, text=True)
    if res.returncode:
        raise RuntimeError(f"{args}: {res.stderr}")
    return res.stdout


def _map(fn, items, jobs):
    """``{item: fn(item)}``, ``jobs`` subprocess-driving threads at a time (each run
    is its own process, so the results do not depend on ``jobs``)."""
    items = list(items)
    if jobs <= 1:
        return {k: fn(k) for k in items}
    with ThreadPoolExecutor(jobs) as pool:
        return dict(zip(items, pool.map(fn, items)))


def scene_hashes(names, workdir, jobs=1):
    def one(name):
        scene = os.path.join(ROOT, "scenes", f"{name}.toml")
        out = os.path.join(workdir, f"{name}.fits")
        _run(["run", scene, "-o", out, "--fit", "gls", "-q"], workdir)
        entry = {}
        for path in sorted(glob.glob(os.path.join(workdir, f"{name}*.fits"))):
            entry[os.path.basename(path)] = hdu_hashes(path)
        fit = os.path.join(workdir, f"{name}_gls.fits")
        truth = os.path.join(workdir, f"{name}_truth.fits")
        if os.path.exists(truth):
            text = _run(["compare", fit, truth], workdir)
            entry["compare"] = hashlib.sha256(text.encode()).hexdigest()[:16]
        return entry
    return _map(one, names, jobs)


def fitter_hashes(workdir, jobs=1):
    """The quick scene fitted every other way."""
    exp = os.path.join(workdir, "quick.fits")
    truth = os.path.join(workdir, "quick_truth.fits")

    def one(key):
        fitter, refpix = key.split("/")
        out = os.path.join(workdir, f"fit_{fitter}_{refpix}.fits")
        _run(["fit", exp, "-o", out, "--fitter", fitter, "--refpix", refpix],
             workdir)
        text = _run(["compare", out, truth, "--exposure", exp], workdir)
        return dict(hdu_hashes(out), compare=hashlib.sha256(text.encode()).hexdigest()[:16])
    return _map(one, [f"{f}/{r}" for f in ("cds", "ols", "gls")
                      for r in ("none", "median", "jwst")], jobs)


def noise_hashes(workdir, jobs=1):
    runs = {
        "e": ["--naxis", "128", "--frames", "3"],
        "dn_gain1.5": ["--naxis", "128", "--frames", "3", "--unit", "DN", "--gain", "1.5"],
        "dn_gain2": ["--naxis", "128", "--frames", "2", "--nints", "2", "--unit", "DN",
                     "--gain", "2"],
        "h1rg_1out": ["--preset", "H1RG", "--naxis", "64", "--n-out", "1", "--frames",
                      "4"],
    }

    def one(key):
        out = os.path.join(workdir, f"noise_{key}.fits")
        _run(["noise", *runs[key], "--seed", "7", "-o", out, "-q"], workdir)
        return hdu_hashes(out)
    return _map(one, runs, jobs)


def main(argv=None):
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--out", required=True, help="JSON file for the hashes")
    p.add_argument("--small", action="store_true", help="only the small scenes")
    p.add_argument("--diff", default=None, help="a previous JSON to compare with")
    p.add_argument("--jobs", type=int, default=1, help="commands run at once")
    a = p.parse_args(argv)
    names = SMALL if a.small else tuple(
        sorted(os.path.basename(f)[:-5] for f in glob.glob(os.path.join(ROOT, "scenes",
                                                                         "*.toml"))))
    with tempfile.TemporaryDirectory() as d:
        result = {"scenes": scene_hashes(names, d, a.jobs),
                  "fitters": fitter_hashes(d, a.jobs), "noise": noise_hashes(d, a.jobs)}
    with open(a.out, "w") as f:
        json.dump(result, f, indent=1, sort_keys=True)
    if a.diff:
        with open(a.diff) as f:
            old = json.load(f)
        diffs = []

        def walk(x, y, path):
            if isinstance(x, dict) and isinstance(y, dict):
                keys = set(y) if path == ("scenes",) and a.small else set(x) | set(y)
                for k in sorted(keys):
                    walk(x.get(k), y.get(k), path + (k,))
            elif x != y:
                diffs.append(f"{'/'.join(path)}: {x} -> {y}")
        walk(old, result, ())
        print("\n".join(diffs) if diffs else "identical")
        return 1 if diffs else 0
    return 0


if __name__ == "__main__":
    sys.exit(main())
