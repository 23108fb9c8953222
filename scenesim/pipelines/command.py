"""``scenesim pipeline jwst|roman`` and the pipeline products of ``scenesim run``.

``scenesim run SCENE --uncal --l1 --reffiles`` writes, beside the exposure
``stem.fits``: ``stem_uncal.fits`` (JWST uncal,
:func:`scenesim.pipelines.jwst.write_uncal`, with the zero frame of
:mod:`scenesim.pipelines.zeroframe` when the pattern has one), ``stem_l1.asdf`` (Roman L1,
:func:`scenesim.pipelines.roman.write_l1`) and the directory ``stem_refs/`` of
reference files: ``jwst_<type>.fits`` for a JWST-sized detector read with a
MULTIACCUM pattern, ``roman_<type>.asdf`` with ``--l1`` or when no JWST set fits
(:func:`reference_families`).  Every path, and every optional extra these need
(:func:`require_extra`: one line naming the extra to install), is checked before the
run starts (:func:`check_run_products`).  Nothing here imports a pipeline package
until a product or ``scenesim pipeline`` asks for it.

``scenesim pipeline jwst UNCAL --refs DIR [--truth TRUTH --exposure EXP]`` runs
Detector1 offline (:func:`scenesim.pipelines.jwst.run_detector1`) and, given the
truth, prints ``compare``'s report of the rate file; ``scenesim pipeline roman L1
--refs DIR`` does the same with romancal's ramp fit
(:func:`scenesim.pipelines.roman.run_ramp_fit`).
"""

import os

from noise.errors import ParameterError

__all__ = ["pipeline_command", "write_run_products", "check_run_products",
           "product_paths", "reference_paths", "require_extra", "reference_families",
           "EXTRAS"]

#: The optional extras of the pipeline loops and the modules each provides.
EXTRAS = {"jwst": ("stdatamodels", "jwst", "stpipe"),
          "roman": ("roman_datamodels", "romancal", "stpipe")}


def require_extra(extra, what):
    """Raise a one-line :class:`~noise.errors.ParameterError` naming the optional
    ``extra`` to install when one of its modules cannot be imported (``what``: the
    product or command that needs it).  Imports nothing else."""
    import importlib
    for module in EXTRAS[extra]:
        try:
            importlib.import_module(module)
        except ImportError as exc:
            raise ParameterError(
                f"{what} needs the optional '{extra}' extra ({module} is not "
                f"installed): pip install -e '.[{extra}]'") from exc


def reference_families(detector, readout, *, l1=False):
    """``(jwst, roman)``: which reference files ``--reffiles`` writes.  JWST FITS
    for a JWST-sized detector (at most 2048 x 2048, 1 or 4 outputs) read with a
    MULTIACCUM pattern; Roman ASDF with ``--l1`` or when no JWST set fits."""
    jwst_sized = (detector.n_out_active in (1, 4)
                  and max(detector.naxis1, detector.naxis2) <= 2048)
    jwst = jwst_sized and readout.is_multiaccum
    return jwst, bool(l1) or not jwst


def _stem(path):
    path = os.fspath(path)
    for ext in (".fits.gz", ".fits", ".asdf"):
        if path.lower().endswith(ext):
            return path[:-len(ext)]
    return path


def product_paths(exposure):
    """``{'uncal', 'l1', 'reffiles'}`` paths derived from the exposure path
    (``stem_uncal.fits``, ``stem_l1.asdf``, ``stem_refs``)."""
    stem = _stem(exposure)
    return {"uncal": stem + "_uncal.fits",      # never compressed: jwst reads it
            "l1": stem + "_l1.asdf", "reffiles": stem + "_refs"}


def check_run_products(scene, output=None, *, uncal=False, l1=False, reffiles=False,
                       overwrite=False):
    """Check, before a run starts, that the asked-for products can be written: the
    extras are installed, the ramp file is kept, and no file would be replaced
    without ``overwrite`` (:func:`scenesim.outputs.check_outputs`)."""
    if not (uncal or l1 or reffiles):
        return
    from scenesim.outputs import check_outputs
    cfg = scene.output
    if not cfg.ramp:
        raise ParameterError("--uncal, --l1 and --reffiles need the ramp file "
                             "([output] ramp = true)")
    paths = product_paths(output if output is not None else cfg.path)
    det, ro = scene.detector, scene.readout.build()
    jwst_refs, roman_refs = reference_families(det, ro, l1=l1) if reffiles else (
        False, False)
    if uncal or jwst_refs:
        require_extra("jwst", "--uncal" if uncal else "--reffiles (JWST reference files)")
    if l1 or roman_refs:
        require_extra("roman", "--l1" if l1 else "--reffiles (Roman reference files)")
    if uncal or jwst_refs:          # the instrument's fields (exp_type prefix), first
        from scenesim.pipelines.instrument import resolve_instrument
        name = resolve_instrument(scene.instrument, det, ro.name)["name"]
        if scene.instrument.subarray:
            from scenesim.pipelines.jwst import check_subarray_name
            check_subarray_name(scene.instrument.subarray, det, name)
    if uncal:
        from scenesim.pipelines.jwst import check_uncal_readout
        try:
            check_uncal_readout(ro, "the scene")
        except ParameterError as exc:
            raise ParameterError(f"--uncal: {exc}") from exc
    if uncal and (det.n_out_active not in (1, 4) or max(det.naxis1, det.naxis2) > 2048):
        raise ParameterError(
            f"--uncal: a JWST uncal needs a detector of at most 2048 x 2048 read through "
            f"1 or 4 outputs; {det.name!r} is {det.naxis2} x {det.naxis1} with "
            f"{det.n_out_active} outputs (use --l1 for a Roman detector)")
    if (uncal or jwst_refs) and det.interleave is not None:
        from scenesim.pipelines.instrument import resolve_instrument
        from scenesim.pipelines.jwst import check_irs2_detector
        ident = resolve_instrument(scene.instrument, det, ro.name)
        check_irs2_detector(det, ident["detector"])
    if l1 and ro.nints != 1:
        raise ParameterError(f"--l1: a Roman L1 file holds one integration; the scene "
                             f"has nints = {ro.nints}")
    if l1:
        from scenesim.pipelines.roman import check_amp33_detector
        check_amp33_detector(det)
    from scenesim.outputs import check_not_dangling, scene_inputs
    inputs = scene_inputs(scene)               # never written, even with overwrite
    check_outputs({"JWST uncal": paths["uncal"] if uncal else None,
                   "Roman L1": paths["l1"] if l1 else None},
                  inputs=inputs, overwrite=overwrite)
    if reffiles:
        refs = check_not_dangling("--reffiles", paths["reffiles"])
        if os.path.exists(refs) and not os.path.isdir(refs):
            raise ParameterError(f"the reference directory {refs!r} is a file; remove it "
                                 f"or write the exposure under another name")
        inside = [p for p in inputs
                  if os.path.realpath(p).startswith(os.path.realpath(refs) + os.sep)]
        if inside:
            raise ParameterError(
                f"the reference directory {refs!r} holds {inside[0]!r}, a file this run "
                f"reads: its files are never replaced, even with --overwrite; write the "
                f"exposure under another name")
        if os.path.exists(refs) and not overwrite:
            raise ParameterError(f"reference directory {refs!r} exists; pass "
                                 f"--overwrite to replace its files")


def _reference_names(prefix):
    """``(types, required, extension)`` of the reference files of ``prefix``
    (``'jwst'`` or ``'roman'``) as their writers name them."""
    if prefix == "jwst":
        from scenesim.pipelines.jwst import REFERENCE_TYPES, REQUIRED_TYPES
        return REFERENCE_TYPES + ("refpix",), REQUIRED_TYPES, ".fits"
    if prefix == "roman":
        from scenesim.pipelines.roman import REFERENCE_TYPES, REQUIRED_TYPES
        return REFERENCE_TYPES, REQUIRED_TYPES, ".asdf"
    raise ParameterError(f"'prefix' must be 'jwst' or 'roman', got {prefix!r}")


def reference_paths(directory, prefix):
    """``{reftype: path}`` of the reference files in the ``--refs`` ``directory``:
    exactly the names their writers give them, ``jwst_<type>.fits``
    (:func:`scenesim.pipelines.jwst.write_reference_files`) or ``roman_<type>.asdf``
    (:func:`scenesim.pipelines.roman.write_reference_files`), one name per type;
    any other file (``jwst_dark.fits.bak``, ``roman_gain.asdf~``) is not a
    reference.  Raises a one-line :class:`~noise.errors.ParameterError` naming
    ``--refs`` when the directory does not exist, is a file, holds none of them, or
    lacks a type the pipeline needs (:data:`scenesim.pipelines.jwst.REQUIRED_TYPES`,
    :data:`scenesim.pipelines.roman.REQUIRED_TYPES`; Roman's ``linearity`` and
    ``inverselinearity`` go together)."""
    types, required, ext = _reference_names(prefix)
    directory = os.fspath(directory)
    make = ("write the reference files with 'scenesim run SCENE --reffiles' (into "
            "STEM_refs/)")
    if not os.path.exists(directory):
        raise ParameterError(f"'--refs' directory {directory!r} does not exist; {make}")
    if not os.path.isdir(directory):
        raise ParameterError(f"'--refs' {directory!r} is a file, not a directory of "
                             f"reference files; give the directory "
                             f"'scenesim run SCENE --reffiles' writes (STEM_refs/)")
    found = {}
    for t in types:
        path = os.path.join(directory, f"{prefix}_{t}{ext}")
        if os.path.isfile(path):
            found[t] = path
    if not found:
        raise ParameterError(f"'--refs' directory {directory!r} holds no {prefix} "
                             f"reference files ({prefix}_<type>{ext}); {make}")
    missing = [f"{prefix}_{t}{ext}" for t in required if t not in found]
    if missing:
        raise ParameterError(f"'--refs' directory {directory!r} lacks {missing}; {make}")
    if prefix == "roman" and ("linearity" in found) != ("inverselinearity" in found):
        have, lack = (("linearity", "inverselinearity") if "linearity" in found
                      else ("inverselinearity", "linearity"))
        raise ParameterError(f"'--refs' directory {directory!r} holds roman_{have}.asdf "
                             f"but not roman_{lack}.asdf (romancal's linearity step "
                             f"reads both); {make}")
    return found


def write_run_products(scene, result, *, uncal=False, l1=False, reffiles=False,
                       options=None, overwrite=False):
    """The pipeline products of a finished run (module notes).

    Parameters
    ----------
    scene : scenesim.scene.Scene
        The scene run (its seed is taken from the run when it had none).
    result : scenesim.run.RunResult
    uncal, l1, reffiles : bool, keyword-only
    options : scenesim.engine.EngineOptions or None, keyword-only
        The run's engine options: a NIRCam uncal with ``NFRAMES > 1`` takes its zero
        frame from the run (``result.zero_frame``, kept when ``run_scene`` was told
        ``products=('uncal',)``), or else from a re-run with these options
        (:mod:`scenesim.pipelines.zeroframe`).
    overwrite : bool, keyword-only

    Returns
    -------
    list of str
        Paths written (a directory for the references).
    """
    if not (uncal or l1 or reffiles):
        return []
    if result.exposure is None:
        raise ParameterError("the pipeline products need the ramp file ([output] "
                             "ramp = true)")
    engine = result.engine
    if scene.seed is None:
        scene = scene.replace(seed=int(engine.entropy))
    det = engine.detector
    jwst_refs, roman_refs = reference_families(det, engine.readout, l1=l1)
    written = []
    paths = product_paths(result.exposure)
    from scenesim.pipelines.reffiles import detector_reference, reference_id
    ref = detector_reference(scene, engine)     # its id ties the products together
    if uncal:
        from scenesim.io.exposure import Exposure
        from scenesim.pipelines.instrument import resolve_instrument
        from scenesim.pipelines.jwst import write_uncal
        from scenesim.pipelines.zeroframe import has_zero_frame, zero_frames
        exposure = Exposure.read(result.exposure)
        zero = None
        ident = resolve_instrument(scene.instrument, det, engine.readout.name)
        if has_zero_frame(engine.readout, ident["name"]):
            # kept by the run itself (run_scene(products=('uncal',))); a result
            # from a run without it is re-run with the first group split
            zero = result.zero_frame
            if zero is None:
                zero = zero_frames(scene, exposure.sci, options=options)
        written.append(write_uncal(exposure, paths["uncal"], zero_frame=zero,
                                   overwrite=overwrite, reference_id=reference_id(ref)))
        del exposure, zero
    if l1:
        from scenesim.pipelines.roman import write_l1
        written.append(write_l1(result.exposure, paths["l1"], overwrite=overwrite,
                                reference_id=reference_id(ref)))
    if reffiles:
        directory = paths["reffiles"]
        if jwst_refs:
            from scenesim.pipelines.jwst import write_reference_files
            write_reference_files(ref, engine.readout, det.frame_time, directory,
                                  instrument=getattr(scene, "instrument", None),
                                  overwrite=overwrite)
        if roman_refs:
            from scenesim.pipelines.roman import write_reference_files as write_roman
            write_roman(ref, directory, overwrite=overwrite)
        written.append(directory)
    return written


def pipeline_command(args):
    """``scenesim pipeline jwst|roman``: run the pipeline offline, then compare.

    Everything is checked before the pipeline runs: the input's kind, the references,
    ``--truth`` and ``--exposure`` (and that the truth is the input's exposure: its
    identity cards, :data:`scenesim.validate.compare.SAME_SOURCE_CARDS`, and its
    size), and the products (never one of those files, even with ``--overwrite``)."""
    from noise.validate import check_existing_file
    require_extra(args.pipeline, f"'scenesim pipeline {args.pipeline}'")
    if args.pipeline == "jwst":
        from scenesim.pipelines.jwst import check_uncal_file as check_input
        from scenesim.pipelines.jwst import uncal_identity as identity
        kind = "uncal"
    else:
        from scenesim.pipelines.roman import check_l1_file as check_input
        from scenesim.pipelines.roman import l1_identity as identity
        kind = "L1"
    source = check_input(args.input)
    refs = reference_paths(args.refs, args.pipeline)
    ident = identity(source)
    if args.pipeline == "jwst" and "NRS_NORM" in ident[0] and "refpix" not in refs:
        raise ParameterError(f"uncal {source!r} is an IRS2 uncal: the '--refs' directory "
                             f"{os.fspath(args.refs)!r} lacks its 'jwst_refpix.fits'; "
                             f"write the IRS2 references with 'scenesim run SCENE "
                             f"--reffiles' of the IRS2 detector")
    read = [check_existing_file(opt, path) for opt, path in
            (("--truth", args.truth), ("--exposure", args.exposure)) if path]
    if args.truth:          # a truth of the wrong kind or of another exposure (the
        # input's identity cards and size) is found before the run, not after it
        from scenesim.validate.compare import check_compare_inputs
        check_compare_inputs(args.truth, exposure=args.exposure,
                             source=(kind, source, *ident))
    # run_detector1 / run_ramp_fit check the input's kind and their products against
    # every file read (these too) before the pipeline runs
    if args.pipeline == "jwst":
        from scenesim.pipelines.jwst import run_detector1
        out_dir = args.output or os.path.dirname(os.path.abspath(args.input))
        out = run_detector1(source, refs, out_dir, overwrite=args.overwrite,
                            inputs=read)
        product = out["rate"]
    else:
        from scenesim.pipelines.roman import run_ramp_fit
        stem = _stem(args.input)
        stem = stem[:-len("_l1")] if stem.endswith("_l1") else stem
        product = args.output or stem + "_l2.asdf"
        run_ramp_fit(source, refs, product, overwrite=args.overwrite, inputs=read)
    print(f"wrote {product}")
    if args.truth:
        from scenesim.validate.compare import compare_files
        report = compare_files(product, args.truth, exposure=args.exposure)
        print(report.format())
    return 0


