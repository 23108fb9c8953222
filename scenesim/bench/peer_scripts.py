"""The peers' side of ``scenesim bench --peers``: one program run per process.

This file is run as a script in a fresh interpreter (``runpy.run_path``, with the
run's input directory as the working directory), never imported by scenesim: it
imports only the standard library, numpy and the peer, so the peer's process pays
for nothing of scenesim's.  Usage::

    python -c "import runpy; runpy.run_path(PATH, run_name='__main__')" PEER SPEC.json

``SPEC.json`` names the inputs (prepared by :mod:`scenesim.bench.peers`) and the
output; the script writes ``SPEC.json``'s ``result`` file: ``inprocess`` (seconds of
the peer's own work: set-up, simulation or fit, and its write), the peer's
``version``, a ``detail`` line and ``peak_rss_mb``, the process's own resident
high-water mark at its end (``VmHWM``: ``wait4``'s ``ru_maxrss`` would start at the
parent's, :mod:`scenesim.bench.process`).  The whole-process time and CPU are
measured by the parent (``os.wait4``).

Peers
-----
``ng``
    The original NG program (Rauscher 2015), ``nghxrg.py`` from the user's path:
    ``HXRGNoise(naxis3=frames, pca0_file=...)`` with its own default clocking and
    noise parameters (those of scenesim's ``noise`` workload), then
    ``mknoise(None)`` and a write of the HDU it returns as uint16 FITS.  (NG's own
    write passes ``clobber=``, which astropy no longer accepts; the HDU is written
    here with ``overwrite=True`` instead: the same bytes.)  Its picture-frame
    template is scenesim's synthetic one, written to ``pca0.fits`` by the parent
    (NG's ``nirspec_pca0.fits`` is not distributed with it).
``romanisim``
    romanisim's L1 (:func:`romanisim.l1.make_l1` with its defaults: read noise,
    gain, pedestal, IPC, saturation) on the same MA table (read indices; romanisim
    spaces reads by its own ``read_time``) and the same rate map (the interior
    inside romanisim's reference border), after a Poisson draw of each pixel's
    total count at the last read, then ``make_asdf`` to an ASDF file (full size
    only; other sizes write the resultants and DQ as a plain ASDF tree, because
    ``make_asdf`` is fixed to 4088 + 2 x 4 pixels).
``stcal``
    stcal's ``ramp_fit_data`` (``OLS_C`` or ``LIKELY``) on the very cube the fit
    workload fits (a ``.npy`` of e-, taken as DN with gain 1), with the conventions
    of :mod:`scenesim.adapters.stcal`: ``readnoise_2d = sqrt(2) * read noise``,
    MULTIACCUM metadata of one read per group, ``read_pattern`` for ``LIKELY``.
    The slopes and variances are saved as ``.npy`` (scenesim's fit saves its own).
"""

import json
import os
import sys
import time

__all__ = []


def _ng(spec):
    import importlib.util
    t0 = time.perf_counter()
    mod_spec = importlib.util.spec_from_file_location("nghxrg", spec["path"])
    mod = importlib.util.module_from_spec(mod_spec)
    mod_spec.loader.exec_module(mod)
    t_import = time.perf_counter() - t0
    t0 = time.perf_counter()
    ng = mod.HXRGNoise(naxis3=int(spec["frames"]), pca0_file=spec["pca0"], verbose=False)
    hdu = ng.mknoise(None)
    if hdu is None:
        raise RuntimeError("this nghxrg.py's mknoise() returns no HDU (NG >= 2.6 does); "
                           "it cannot be timed without its clobber= write")
    hdu.writeto(spec["output"], overwrite=True)
    return dict(inprocess=time.perf_counter() - t0, import_seconds=t_import,
                version=str(getattr(mod.HXRGNoise, "nghxrg_version", "unknown")),
                detail=f"{spec['frames']} frames, NG defaults, uint16 FITS")


def _romanisim(spec):
    t0 = time.perf_counter()
    import numpy as np
    import galsim
    import romanisim
    from romanisim import l1
    from romanisim.models import parameters
    t_import = time.perf_counter() - t0
    rate = np.load(spec["rate"])
    t0 = time.perf_counter()
    nb = parameters.nborder
    rate = rate[nb:-nb, nb:-nb]
    read_pattern = [list(range(first, first + n)) for first, n in spec["ma_table"]]
    t_last = parameters.read_time * read_pattern[-1][-1]
    g = np.random.default_rng(int(spec["seed"]))
    counts = galsim.Image(g.poisson(rate * t_last).astype(np.int32))
    res, dq = l1.make_l1(counts, read_pattern, rng=galsim.UniformDeviate(int(spec["seed"])))
    full = rate.shape == (parameters.n_pix, parameters.n_pix)
    if full:
        l1.make_asdf(res, dq, filepath=spec["output"])
    else:
        import asdf
        asdf.AsdfFile({"data": res.astype(np.uint16), "dq": dq}).write_to(spec["output"])
    return dict(inprocess=time.perf_counter() - t0, import_seconds=t_import,
                version=str(romanisim.__version__),
                detail=(f"{rate.shape[0]}x{rate.shape[1]} + border "
                        f"{'make_asdf' if full else 'plain ASDF'}, read_time "
                        f"{parameters.read_time} s"))


def _stcal(spec):
    t0 = time.perf_counter()
    import numpy as np
    import stcal
    from stcal.ramp_fitting.ramp_fit import ramp_fit_data
    from stcal.ramp_fitting.ramp_fit_class import RampData
    t_import = time.perf_counter() - t0
    cube = np.load(spec["cube"])
    t0 = time.perf_counter()
    alg, tf, rn = spec["algorithm"], float(spec["t_frame"]), float(spec["read_noise"])
    ngroups, ny, nx = cube.shape
    data = cube.reshape(1, ngroups, ny, nx)
    rd = RampData()
    rd.set_arrays(data, np.zeros(data.shape, np.uint8), np.zeros((ny, nx), np.uint32),
                  np.zeros((ny, nx), np.float32))
    rd.set_meta(name="H2RG", frame_time=tf, group_time=tf, groupgap=0, nframes=1,
                drop_frames1=0)
    rd.algorithm = alg
    rd.set_dqflags({"GOOD": 0, "DO_NOT_USE": 1, "SATURATED": 2, "JUMP_DET": 4,
                    "PERSISTENCE": 2 ** 5, "CHARGELOSS": 2 ** 7,
                    "NO_GAIN_VALUE": 2 ** 19, "UNRELIABLE_SLOPE": 2 ** 24})
    rd.start_row = 0
    rd.num_rows = ny
    rd.suppress_one_group_ramps = True
    if alg == "LIKELY":
        rd.read_pattern = [np.array([(k + 1) * tf]) for k in range(ngroups)]
    readnoise_2d = np.full((ny, nx), np.sqrt(2.0) * rn, np.float32)
    gain_2d = np.ones((ny, nx), np.float32)
    image, _, _ = ramp_fit_data(rd, False, readnoise_2d, gain_2d, alg, "optimal", "none")
    np.save(os.path.join(spec["out_dir"], "slope.npy"),
            np.asarray(image["slope"], np.float32))
    np.save(os.path.join(spec["out_dir"], "var.npy"),
            np.asarray(image["var_rnoise"], np.float32)
            + np.asarray(image["var_poisson"], np.float32))
    slope = np.asarray(image["slope"], np.float64)
    return dict(inprocess=time.perf_counter() - t0, import_seconds=t_import,
                version=str(stcal.__version__), median_slope=float(np.nanmedian(slope)),
                detail=f"{alg}, {ny}x{nx}x{ngroups}")


_PEERS = {"ng": _ng, "romanisim": _romanisim, "stcal": _stcal}


def _peak_rss_mb():
    """This process's resident high-water mark, MB (``VmHWM``; reset by ``exec``)."""
    with open("/proc/self/status") as f:
        for line in f:
            if line.startswith("VmHWM:"):
                return int(line.split()[1]) / 1024.0
    raise OSError("no VmHWM in /proc/self/status")


def _main(argv):
    peer, spec_path = argv
    with open(spec_path) as f:
        spec = json.load(f)
    out = _PEERS[peer](spec)
    out["peak_rss_mb"] = _peak_rss_mb()
    with open(spec["result"], "w") as f:
        json.dump(out, f)
    return 0


if __name__ == "__main__":
    sys.exit(_main(sys.argv[1:]))
