"""The work of each ``scenesim`` subcommand (the parser and the signal handling are
in :mod:`scenesim.cli`, which imports this module once its handlers are installed).

Each command imports what it uses when it runs: ``scenesim noise`` needs the noise
generator and the FITS writer, not the scene, engine, fitting and pipeline modules
(with astropy.table, scipy.special and asdf among their imports), and a user waits for
the whole process.
"""


import dataclasses
import shlex
import sys
import time

from noise.errors import ParameterError

__all__ = ["noise_command", "run_command", "fit_command", "compare_command",
           "bench_command", "preset_detector"]


def preset_detector(name, naxis, n_out):
    """The detector ``noise.preset(name)`` with the ``--naxis`` and ``--n-out``
    options that were given (None: the preset's own), applied together (``--n-out``
    may be what makes ``--naxis`` valid); errors name the options as typed."""
    import noise
    from noise.validate import check_int
    det = noise.preset(name)
    changes, given = {}, []
    for opt, value, fields in (("--naxis", naxis, ("naxis1", "naxis2")),
                               ("--n-out", n_out, ("n_out",))):
        if value is not None:
            check_int(opt, value, minimum=1)
            changes.update({f: value for f in fields})
            given.append(f"'{opt}' {value}")
    if not changes:
        return det
    try:
        return dataclasses.replace(det, **changes)
    except ParameterError as exc:
        raise type(exc)(f"{', '.join(given)}: {exc}") from exc


def _least_gain(params, det, adc_bits):
    """``(gain, e-)``: the smallest gain (e-/DN) at which ``params``' reads without
    charge fit an ADC of ``adc_bits`` bits (:meth:`noise.NoiseParams.check_adc`), and
    the range they need; or None."""
    from noise.params import BIAS_SPREAD_SIGMA as k
    top = 2 ** adc_bits - 1
    s = params.spread(det)
    b_lo, b_hi = params.bias_pattern_range(det)
    high = params.bias_offset + b_hi + k * s + (params.rtn_amp if params.rtn_fraction
                                                 else 0.0)
    need = max(2 * k * s + b_hi - b_lo, high)
    least = need / top * (1 + 1e-9)
    try:
        params.check_adc(least, adc_bits, det)
    except ParameterError:
        return None
    return least, need


def noise_command(args):
    """``scenesim noise``: write an empty (noise-only) ramp."""
    import noise
    from scenesim.budget import check_noise_budget, one_line_warnings
    from scenesim.outputs import FITS_ENDINGS, check_outputs, clean_stale_temps
    from scenesim.progress import progress_bar
    from noise.validate import check_float, check_int
    from noise.generator import MAX_FRAMES, MAX_FRAMES_TOTAL
    # the options by the names the user typed, before any work
    check_int("--frames", args.frames, minimum=1, maximum=MAX_FRAMES)
    check_int("--nints", args.nints, minimum=1, maximum=MAX_FRAMES)
    if args.frames * args.nints > MAX_FRAMES_TOTAL:
        raise ParameterError(f"'--frames' x '--nints' = {args.frames} x {args.nints}: "
                             f"at most {MAX_FRAMES_TOTAL} frames per file")
    if args.threads is not None:
        check_int("--threads", args.threads, minimum=1)
    if args.seed is not None:                # as a scene's seed: a FITS integer card
        from noise.streams import MAX_SEED
        check_int("--seed", args.seed, minimum=0, maximum=MAX_SEED)
    if args.gain is not None:
        check_float("--gain", args.gain, minimum=0.0, strict_min=True)
        if args.unit != "DN":
            raise ParameterError(f"'--gain' {args.gain:g} applies only with '--unit DN' "
                                 f"(the frames are in electrons with '--unit e')")
    gain = 1.0 if args.gain is None else args.gain
    det = preset_detector(args.preset, args.naxis, args.n_out)
    # white: the paper's read noise on its bias, which keeps the DN file off code 0
    nominal = noise.NoiseParams()
    params = nominal if args.noise == "nirspec" else noise.ZERO_NOISE.replace(
        rd_noise=nominal.rd_noise, bias_offset=nominal.bias_offset)
    try:                                   # by the options, not the library's names
        params.check_detector(det)
    except ParameterError as exc:
        text = str(exc).replace("set 'acn' to 0", "use '--noise white' (no ACN)") \
            .replace("'naxis1'/'n_out'/the subarray", "'--naxis'/'--n-out'")
        raise type(exc)(text) from exc
    if args.unit == "DN":                  # no noise clipped or lost at the 16-bit ADC
        try:
            params.check_adc(gain, 16, det)
        except ParameterError as exc:
            least = _least_gain(params, det, 16)
            if least is not None and gain < least[0]:
                # the amplitudes it names are not options here: say what to change
                raise type(exc)(
                    f"'--gain' {gain:g} e-/DN is too small for '--noise {args.noise}' "
                    f"at the 16-bit ADC: the reads of a pixel without charge need "
                    f"{least[1]:.6g} e- (its bias, pattern and 5 x the noise's rms), "
                    f"more than 65535 x {gain:g} = {65535 * gain:.6g} e-; '--gain' must "
                    f"be >= {least[0]:.4g} e-/DN"
                    + ("" if args.noise == "white" else " (or use '--noise white')")
                    ) from exc
            raise type(exc)(f"'--unit DN' (16-bit ADC): {exc}") from exc
    check_outputs({"output": args.output}, overwrite=args.overwrite,
                  endings={"output": FITS_ENDINGS})
    budget = check_noise_budget(det, params, args.frames, nints=args.nints,
                                unit=args.unit, path=args.output, force=args.force)
    with one_line_warnings("scenesim noise"):
        budget.warn()
        if args.unit == "DN":
            params.warn_quantisation(gain, "'--gain'")
    gen = noise.NoiseGenerator(det, params, rng=args.seed, threads=args.threads)
    cleaned = clean_stale_temps([args.output])
    if cleaned and not args.quiet:
        print(cleaned)
    t0 = time.perf_counter()
    bar = None
    cb = None
    total = args.frames * args.nints
    if not args.quiet and total >= 3:
        bar = progress_bar(total, "frame", "noise")

        def cb(n):
            bar.update(n - bar.n)          # drawn at most every 0.1 s
    try:
        noise.write_noise_fits(args.output, gen, args.frames, nints=args.nints,
                               unit=args.unit, gain=gain, progress=cb,
                               overwrite=args.overwrite)
    finally:
        if bar is not None:
            bar.close()
    if not args.quiet:
        print(f"wrote {args.output}: {args.nints} x {args.frames} frames of "
              f"{det.ny}x{det.nx} ({det.name}, {det.n_out_active} outputs, "
              f"t_frame={det.frame_time:.5f} s) in {time.perf_counter() - t0:.1f} s; "
              f"seed entropy {gen.entropy}")
    return 0


def run_command(args):
    """``scenesim run``: simulate a scene (then fit and compare)."""
    from scenesim.budget import one_line_warnings
    from scenesim.engine import EngineOptions
    from scenesim.pipelines.command import check_run_products, write_run_products
    from scenesim.run import run_scene
    from scenesim.scene import load_scene
    scene = load_scene(args.scene)
    options = EngineOptions(threads=args.threads, gauss_above=args.gauss_above,
                            arrivals=args.arrivals)
    products = dict(uncal=getattr(args, "uncal", False), l1=getattr(args, "l1", False),
                    reffiles=getattr(args, "reffiles", False))
    check_run_products(scene, args.output, overwrite=args.overwrite, **products)
    with one_line_warnings("scenesim run"):
        res = run_scene(scene, output=args.output, seed=args.seed, options=options,
                        progress=not args.quiet, fit=args.fit, refpix=args.refpix,
                        compare=True if args.compare else None, plots=args.plots,
                        overwrite=args.overwrite, force=args.force,
                        products=tuple(k for k, v in products.items() if v))
    written = write_run_products(scene if args.seed is None else scene.replace(
        seed=args.seed), res, options=options, overwrite=args.overwrite, **products)
    if res.cleaned and not args.quiet:
        print(res.cleaned)
    if not args.quiet:
        eng = res.engine
        print(f"scene {args.scene}: {eng.detector.ny}x{eng.detector.nx}, "
              f"{eng.readout.nints} int x {eng.readout.ngroups} resultants "
              f"({eng.readout.name}), seed entropy {eng.entropy}, "
              f"{res.seconds:.1f} s")
        for label, path in (("exposure", res.exposure), ("truth", res.truth),
                            ("fit", res.fit)):
            if path:
                print(f"  {label}: {path}")
        for path in written:
            print(f"  pipeline: {path}")
        if res.report is not None:
            print(res.report.format())
    return 0


#: What ``scenesim fit --fitter`` takes (any case).
FIT_CHOICES = ("cds", "ols", "gls", "stcal-ols_c", "stcal-likely")


def fit_command(args):
    """``scenesim fit``: fit the slopes of an exposure."""
    from scenesim.adapters.stcal import fit_exposure_stcal
    from scenesim.calib.prepare import PrepareOptions, fit_exposure_file
    from scenesim.outputs import (FITS_ENDINGS, check_outputs, clean_stale_temps,
                                  fit_path_for)
    from noise.validate import check_choice, check_float
    # 'GLS' as 'gls', 'STCAL-likely' as 'stcal-likely'; the stcal names in the list
    args.fitter = check_choice("--fitter", args.fitter, FIT_CHOICES, ignore_case=True)
    if args.jump_threshold is not None and args.fitter.startswith("stcal-"):
        # it would change nothing: say so (before, silently ignored)
        raise ParameterError(
            f"'--jump-threshold' {args.jump_threshold:g} applies to scenesim's fitters "
            f"(cds, ols, gls): {args.fitter} "
            + ("detects jumps with stcal's own 4.5 sigma" if args.fitter.endswith("likely")
               else "fits without jump detection (stcal's jump step is not run)"))
    if args.jump_threshold is None:
        args.jump_threshold = 5.0
    check_float("--jump-threshold", args.jump_threshold, minimum=0.0)
    out = args.output or fit_path_for(args.exposure, args.fitter)
    check_outputs({"slope file": out}, inputs=[args.exposure], overwrite=args.overwrite,
                  endings={"slope file": FITS_ENDINGS})
    cleaned = clean_stale_temps([out])          # e.g. a killed fit's prepared cube
    if cleaned and not args.quiet:
        print(cleaned)
    if args.fitter.lower().startswith("stcal-"):
        fit_exposure_stcal(args.exposure, out, algorithm=args.fitter[6:].upper(),
                           options=PrepareOptions(refpix=args.refpix),
                           overwrite=args.overwrite)
    else:
        fit_exposure_file(args.exposure, out, fitter=args.fitter,
                          options=PrepareOptions(refpix=args.refpix),
                          jump_threshold=args.jump_threshold, overwrite=args.overwrite)
    if not args.quiet:
        print(f"wrote {out}")
    return 0


def compare_command(args):
    """``scenesim compare``: grade a slope file against the truth (or, with
    ``--pool DIR``, print the comparisons of a batch pooled over realisations)."""
    from scenesim.batch.command import pool_command
    from scenesim.outputs import check_plot_dir, made_directory
    from scenesim.validate.compare import compare_files
    if getattr(args, "pool", None) is not None:
        if args.fit is not None or args.plots or args.exposure:
            raise ParameterError("'--pool' reads the batch directory alone; give no "
                                 "FIT, TRUTH, --exposure or --plots with it")
        return pool_command(args)
    if args.fit is None or args.truth is None:
        raise ParameterError("compare needs a slope file and a truth file (FIT TRUTH), "
                             "or --pool DIR for a batch")
    plots = args.plots or None
    if plots:
        inputs = [p for p in (args.fit, args.truth, args.exposure) if p is not None]
        check_plot_dir(plots, inputs=inputs, overwrite=args.overwrite)
    with made_directory(plots):
        report = compare_files(args.fit, args.truth, plots=plots,
                               exposure=args.exposure)
    print(report.format())
    return 0


def bench_command(args):
    """``scenesim bench``: run the benchmarks (and, with ``--peers``, their peers)."""
    from scenesim.bench import main as bench_main
    return bench_main(args.workloads, quick=args.quick, out_dir=args.out,
                      threads=args.threads, peers=args.peers, ng=args.ng,
                      scaling=args.scaling, command=shlex.join(["scenesim"] + sys.argv[1:]),
                      fit_sizes=_int_list("--fit-sizes", args.fit_sizes),
                      fit_resultants=_int_list("--fit-resultants", args.fit_resultants),
                      pairs=args.pairs, overwrite=args.overwrite)


def _int_list(option, text):
    """``'5,10,20'`` as ``[5, 10, 20]`` (None stays None)."""
    if text is None:
        return None
    try:
        return [int(v) for v in text.split(",") if v.strip()]
    except ValueError as exc:
        raise ParameterError(f"'{option}' must be comma-separated integers, got "
                             f"{text!r}") from exc
