"""Peers timed in the same run, on the same input, process against process.

``scenesim bench --peers`` (or the ``peers`` workload: ``noise``, ``roman`` and
``fit`` with their peers) runs, right after each scenesim case and on the identical
input, every peer of that case that is present here, each in its own fresh process
(:mod:`scenesim.bench.peer_scripts`, which imports nothing of scenesim's), measured
like the scenesim case (:func:`scenesim.bench.process.run_process`: whole-process
wall time, CPU, the load average before and after; the peak RSS each process reports
of itself):

==================  =====================================  ============================
scenesim case       peer                                   same input
==================  =====================================  ============================
``noise`` N         the original NG program, ``--ng        N frames of the 4-output
                    PATH/nghxrg.py`` (not on the package   H2RG with NG's own defaults
                    index; the user gives it)              (scenesim's presets), uint16
``roman``           romanisim's L1 (``pip install          the same MA table (read
                    'scenesim[peers]'``)                   indices) and rate map
                                                           (``rate.npy``, the interior)
``fit`` ``ols``     stcal ``OLS_C`` (a test dependency)    the same cube (``.npy``)
``fit`` ``gls-jump`` stcal ``LIKELY`` (which always        the same cube (``.npy``)
                    detects jumps)
==================  =====================================  ============================

A peer that cannot run here is reported as **not measured**, with the reason (not
installed, no ``--ng`` path, more memory than the machine has free, or the peer's own
error); no number is ever carried over from another run.
"""

import importlib.util
import json
import math
import os
import sys

import numpy as np

from noise.errors import ParameterError
from scenesim.bench.process import peak_memory, run_process, tail

__all__ = ["NOT_MEASURED", "peer_plan", "prepare_peer_input", "run_peer", "check_ng_path",
           "ng_peak_bytes"]

#: The text of a peer that did not run.
NOT_MEASURED = "not measured"

_SCRIPT = os.path.join(os.path.dirname(os.path.abspath(__file__)), "peer_scripts.py")

#: Fraction of the memory available now that NG's estimated peak may take.
_NG_MEMORY_SHARE = 0.6

_LABELS = {"ng": "NG original (nghxrg.py)", "romanisim": "romanisim L1",
           "stcal-OLS_C": "stcal OLS_C", "stcal-LIKELY": "stcal LIKELY"}


def check_ng_path(path):
    """The absolute path of the user's ``nghxrg.py``, or raise ParameterError."""
    if path is None:
        return None
    path = os.path.abspath(os.fspath(path))
    what = "'--ng' must be the path of NG's nghxrg.py (a Python file defining HXRGNoise)"
    if not os.path.isfile(path):
        raise ParameterError(f"{what}, got {path!r}, which is not a file")
    if not path.endswith(".py"):
        # the peer script imports it as a module: Python loads only .py sources so
        raise ParameterError(f"{what}, got {path!r}, which does not end in .py")
    try:
        with open(path, "rb") as f:
            text = f.read()
    except OSError as exc:
        raise ParameterError(f"{what}, got {path!r}, which cannot be read "
                             f"({exc.strerror})") from None
    if b"class HXRGNoise" not in text:
        raise ParameterError(f"{what}, got {path!r}, which defines no class HXRGNoise")
    return path


def ng_peak_bytes(frames, ny=2048, nx=2048, n_out=4, nroh=12, nfoh=1):
    """Rough upper estimate of NG's peak memory (bytes) for ``frames`` frames.

    NG draws each 1/f series as ``2 nstep2`` float64 white samples (``nstep2`` the
    next power of two of the cube's time steps per output) and filters them with
    complex128 FFTs (~64 bytes per ``nstep2`` alive at once), and holds the float32
    cube plus float64 even/odd masks and per-frame temporaries (~32 bytes per pixel
    and frame).  Used only to skip a run the machine cannot hold.
    """
    nstep = (nx // n_out + nroh) * (ny + nfoh) * int(frames)
    nstep2 = 2 ** math.ceil(math.log2(nstep))
    return 64 * nstep2 + 32 * int(frames) * ny * nx


def _available_bytes():
    try:
        with open("/proc/meminfo") as f:
            for line in f:
                if line.startswith("MemAvailable:"):
                    return int(line.split()[1]) * 1024
    except OSError:
        pass
    return None


def _installed(module):
    return importlib.util.find_spec(module) is not None


def _not_measured(peer, reason):
    return dict(peer=peer, label=_LABELS[peer], status=NOT_MEASURED, reason=reason)


def peer_plan(name, case, *, peers, ng_path=None):
    """The peers of one scenesim case: what would run, or why it is not measured.

    Parameters
    ----------
    name : str
        Workload.
    case : object
        The workload's case.
    peers : bool
        Whether peers were asked for (``--peers``).
    ng_path : str or None
        The user's ``nghxrg.py``.

    Returns
    -------
    list of dict
        One per peer of this case (none for cases without a peer): ``peer``,
        ``label`` and either ``status = 'run'`` or ``status`` = :data:`NOT_MEASURED`
        with a ``reason``.
    """
    if name == "noise":
        keys = ["ng"]
    elif name == "roman":
        keys = ["romanisim"]
    elif name == "fit" and case[1] == "ols":
        keys = ["stcal-OLS_C"]
    elif name == "fit" and case[1] == "gls-jump":
        keys = ["stcal-LIKELY"]
    else:
        return []
    out = []
    for key in keys:
        if not peers:
            out.append(_not_measured(key, "peers not run (add --peers)"))
        elif key == "ng" and ng_path is None:
            out.append(_not_measured(key, "no --ng PATH/nghxrg.py given (NG is not on "
                                          "the package index)"))
        elif key == "ng" and _ng_too_big(case):
            need, avail = ng_peak_bytes(case) / 1e9, _available_bytes() / 1e9
            out.append(_not_measured(key, f"NG's in-memory arrays at {case} frames "
                                          f"(~{need:.0f} GB estimated) exceed "
                                          f"{_NG_MEMORY_SHARE:.0%} of the "
                                          f"{avail:.0f} GB available now"))
        elif key == "romanisim" and not _installed("romanisim"):
            out.append(_not_measured(key, "romanisim is not installed (pip install "
                                          "'scenesim[peers]')"))
        elif key.startswith("stcal") and not _installed("stcal"):
            out.append(_not_measured(key, "stcal is not installed (pip install "
                                          "'scenesim[peers]')"))
        else:
            out.append(dict(peer=key, label=_LABELS[key], status="run"))
    return out


def _ng_too_big(frames):
    avail = _available_bytes()
    return avail is not None and ng_peak_bytes(frames) > _NG_MEMORY_SHARE * avail


def prepare_peer_input(key, name, case, directory):
    """Write the input a peer shares with the scenesim case (once); return its spec.

    ``directory`` holds the run's inputs (``rate_<size>.npy``, ``pca0.fits``, and the
    fit cube of :func:`scenesim.bench.workloads.prepare_fit`).
    """
    from scenesim.bench.workloads import fit_input, prepare_fit, roman_scene
    if key == "ng":
        path = os.path.join(directory, "pca0.fits")
        if not os.path.exists(path):
            import noise
            from astropy.io import fits
            from noise.template import template_for
            tpl = template_for(noise.preset("H2RG"))
            fits.PrimaryHDU(np.asarray(tpl, np.float32)).writeto(path)
        return dict(frames=int(case), pca0=path)
    if key == "romanisim":
        path = os.path.join(directory, f"rate_{case}.npy")
        _, ro, rate = roman_scene(case)
        if not os.path.exists(path):
            np.save(path, rate)
        return dict(rate=path, seed=7,
                    ma_table=[[r[0], len(r)] for r in ro.resultants])
    # stcal
    kw = prepare_fit(case, directory)
    _, meta = fit_input(0)
    return dict(cube=kw["cube"], algorithm=key.split("-", 1)[1],
                t_frame=meta["t_frame"], read_noise=meta["read_noise"])


def run_peer(plan, name, case, directory, *, ng_path=None):
    """Run one planned peer in its own process; return its measurement.

    Parameters
    ----------
    plan : dict
        One entry of :func:`peer_plan` with ``status = 'run'``.
    name, case :
        The scenesim case it stands beside.
    directory : str
        The run's input directory (the peer's working directory too).
    ng_path : str or None

    Returns
    -------
    dict
        ``plan`` plus, when the peer ran: ``status = 'measured'``, ``wall``,
        ``cpu``, ``load_before``, ``load_after`` (whole process), ``peak_rss_mb``
        (the process's own high-water mark, reported by it as ``own_peak_rss_mb``,
        or its process tree's sampled peak if larger: :mod:`scenesim.bench.process`),
        ``inprocess`` (the peer's own work, s), ``version`` and ``detail``; when it
        failed: ``status`` = :data:`NOT_MEASURED` and the ``reason`` (the end of its
        error output).
    """
    key = plan["peer"]
    spec = prepare_peer_input(key, name, case, directory)
    tag = f"{key}_{name}_{_slug(case)}"
    spec.update(result=os.path.join(directory, tag + ".json"),
                output=os.path.join(directory, tag + ".out"), out_dir=directory)
    if key == "ng":
        spec["path"] = ng_path
    spec_path = os.path.join(directory, tag + ".spec.json")
    with open(spec_path, "w") as f:
        json.dump(spec, f)
    script = "import runpy; runpy.run_path(%r, run_name='__main__')" % _SCRIPT
    argv = [sys.executable, "-c", script, key.split("-")[0], spec_path]
    err = os.path.join(directory, tag + ".stderr")
    m = run_process(argv, cwd=directory, stdout_path=os.path.join(directory, tag + ".stdout"),
                    stderr_path=err)
    for p in (spec["output"],):
        if os.path.exists(p):
            os.unlink(p)
    out = dict(plan)
    if m["returncode"] != 0 or not os.path.exists(spec["result"]):
        out.update(status=NOT_MEASURED, load_before=m["load_before"],
                   reason=f"{plan['label']} failed (exit {m['returncode']}): "
                          + (tail(err, 1) or "no error output"))
        return out
    with open(spec["result"]) as f:
        res = json.load(f)
    out.update(m, status="measured", **res)
    # as scenesim's: the peer's own high-water mark, or its tree's if it forks
    out.update(own_peak_rss_mb=res["peak_rss_mb"],
               peak_rss_mb=peak_memory(res["peak_rss_mb"], m["tree_pss_peak_mb"]))
    return out


def _slug(case):
    return "".join(c if c.isalnum() else "_" for c in str(case)).strip("_")
