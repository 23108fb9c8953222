"""``scenesim calibrate`` (also ``scenesim noise calibrate``) and ``scenesim psd``.

``calibrate`` fits the noise model to one or more dark ramps
(:func:`noise.calibrate.calibrate_darks`) and writes a ``[noise]`` table that a
scene file takes as it is.  ``psd`` draws the averaged periodogram of each file in
readout time order (the paper's Fig. 2/6), log-log, with the model fitted to the
first file overlaid, component by component.  Both check every output before any
work and never replace a file without ``--overwrite``.  Their arguments are in
:mod:`scenesim.calibrate_options` (imported by the command line without this module).
"""

import os

import numpy as np

from noise.calibrate import calibrate_darks, load_darks
from noise.errors import ParameterError
from noise.fitsio import atomic_path
from scenesim.commands import preset_detector
from scenesim.outputs import check_outputs

__all__ = ["calibrate_command", "psd_command", "plot_psd"]


def _detector(args):
    if args.preset is None:
        if args.naxis is not None or args.n_out is not None:
            raise ParameterError("'--naxis' and '--n-out' need '--preset'")
        return None
    return preset_detector(args.preset, args.naxis, args.n_out)


def _check_options(args, files):
    """``--f-min``, ``--template`` and every input file, checked before any dark is
    read (a probe: a bad ``--f-min`` or a missing second file failed only after the
    first had been read and fitted)."""
    from noise.validate import check_existing_file, check_float
    check_float("--f-min", args.f_min, minimum=0.0, strict_min=True)
    if args.template is not None:
        check_existing_file("--template", args.template)
    for path in files:
        check_existing_file("dark ramp", path)


def calibrate_command(args):
    """``scenesim calibrate DARK.fits [...] -o noise.toml``."""
    check_outputs({"output": args.output}, inputs=[os.path.abspath(d) for d in args.darks],
                  overwrite=args.overwrite, endings={"output": (".toml",)})
    _check_options(args, args.darks)
    ramps = load_darks(args.darks, detector=_detector(args), gain=args.gain)
    template = None if args.template is None else os.path.abspath(args.template)
    res = calibrate_darks(ramps, f_min=args.f_min, template_file=template)
    text = res.to_toml(sources=args.darks)
    with atomic_path(args.output, overwrite=args.overwrite) as tmp:
        with open(tmp, "w", encoding="utf-8") as f:
            f.write(text)
    if not args.quiet:
        for name, est in res.estimates.items():
            if est.value is None:
                extra = f"upper bound {est.upper:.4g}" if est.upper is not None else "-"
                print(f"  {name:12s} not fitted: {extra}  ({est.note})")
            else:
                sig = f" +- {est.sigma:.3g}" if est.sigma is not None else ""
                up = f" (upper bound {est.upper:.4g})" if est.upper is not None else ""
                print(f"  {name:12s} {est.value:12.5g}{sig}{up}")
        print(f"wrote {args.output}: [noise] fitted to {len(args.darks)} file(s), "
              f"{res.n_int} integrations, {res.n_diff} CDS differences")
    return 0


def psd_command(args):
    """``scenesim psd FILE... [--plot psd.png]``."""
    if args.plot is not None:
        check_outputs({"plot": args.plot}, inputs=[os.path.abspath(f) for f in args.files],
                      overwrite=args.overwrite, endings={"plot": (".png",)})
    _check_options(args, args.files)
    det = _detector(args)
    results = []
    for path in args.files:
        ramps = load_darks([path], detector=det, gain=args.gain)
        results.append(calibrate_darks(ramps, f_min=args.f_min, template_file=args.template))
    if args.plot is not None:
        plot_psd(args.plot, results, [os.path.basename(f) for f in args.files])
        print(f"wrote {args.plot}")
    else:                   # one table per file, in the order given
        for k, (path, res) in enumerate(zip(args.files, results)):
            psd = res.psd
            print(("\n" if k else "") + "# f_Hz  PSD_auto(e-^2/Hz)  sigma  model   "
                  f"(CDS differences / 2, {path})")
            for f, m, s, mod in zip(psd["freq"], psd["auto"]["mean"],
                                    psd["auto"]["sigma"], psd["auto"]["model"]):
                print(f"{f:12.5g} {m:12.5g} {s:10.3g} {mod:12.5g}")
    return 0


def plot_psd(path, results, labels):
    """Draw the averaged PSDs of ``results`` (:class:`noise.calibrate.CalibrationResult`)
    into the PNG ``path``: the regular pixels' periodogram of every file, the fitted
    model of the first (total and components), and, when present, the periodogram
    common to all outputs (cross) and the reference pixels'."""
    try:
        import matplotlib
        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
    except ImportError as exc:
        raise ParameterError("'--plot' needs matplotlib (pip install scenesim[plot])") \
            from exc
    first = results[0].psd
    keys = [k for k in ("auto", "cross", "ref") if k in first]
    titles = {"auto": "regular pixels, per output",
              "cross": "common to all outputs (cross-periodogram)",
              "ref": "reference pixels"}
    fig, axes = plt.subplots(len(keys), 1, figsize=(7, 3.2 * len(keys)), squeeze=False)
    colors = plt.rcParams["axes.prop_cycle"].by_key()["color"]
    for ax, key in zip(axes[:, 0], keys):
        shown = []              # what sets the y range: the data and the total model
        for i, (res, label) in enumerate(zip(results, labels)):
            psd = res.psd
            if key not in psd:
                continue
            f = psd["freq"]
            ok = f > 0
            ax.errorbar(f[ok], psd[key]["mean"][ok], yerr=psd[key]["sigma"][ok], fmt=".",
                        ms=4, color=colors[i % len(colors)], label=label)
            shown.append(psd[key]["mean"][ok])
        f = first["freq"]
        ok = f > 0
        ax.plot(f[ok], first[key]["model"][ok], "k-", lw=1.2, label="model fitted to "
                + labels[0])
        shown.append(first[key]["model"][ok])
        values = np.concatenate(shown)
        values = values[np.isfinite(values) & (values > 0)]
        if values.size:     # a component far below the data (a pedestal's zero) is
            ax.set_ylim(values.min() / 3.0, values.max() * 3.0)    # cut, not the data
        for j, (name, comp) in enumerate(first[key]["components"].items()):
            if np.any(comp[ok] > 0):
                ax.plot(f[ok], np.where(comp[ok] > 0, comp[ok], np.nan), "--", lw=0.8,
                        color=colors[(j + 3) % len(colors)], label=name)
        ax.set_xscale("log")
        ax.set_yscale("log")
        ax.set_title(titles[key], fontsize=9)
        ax.set_ylabel("PSD (e-$^2$/Hz)")
        ax.legend(fontsize=6, ncol=2)
    axes[-1, 0].set_xlabel("frequency in readout time order (Hz)")
    fig.suptitle("CDS differences / 2, averaged: " + ", ".join(labels), fontsize=9)
    fig.tight_layout()
    with atomic_path(path, overwrite=True) as tmp:        # checked before any work
        fig.savefig(tmp, format="png", dpi=110)
    plt.close(fig)
    return path
