"""What a command writes, and what it may replace: checked before any work starts.

Policy (the README's "Outputs" section):

* an existing file is never replaced unless asked (``--overwrite`` on the command line,
  ``overwrite=True`` in the library), as astropy and most tools behave;
* a file that the run reads (the scene file, its maps, catalogue, light curves, PSF
  image or template) is never written, even with ``--overwrite``; neither is a
  read-only file;
* two outputs of one run never share a path;
* all of this is checked for every output before any work starts, so a refused run
  leaves nothing behind and changes nothing.

Files are then written to hidden temporary files beside their targets and renamed into
place when complete (:func:`noise.fitsio.atomic_path`), so an interrupted run leaves no
partial file either.
"""

import contextlib
import os

from noise.errors import OutputError, ParameterError
from noise.fitsio import (check_output_name, derived_path, record_replacing,
                          remove_stale_temps, same_file)
from noise.validate import check_name_length, check_writable

__all__ = ["PLOT_FILES", "scene_inputs", "scene_id", "file_sha256", "check_outputs",
           "check_plot_dir", "fit_path_for", "clean_stale_temps", "check_not_dangling"]

#: The figures ``compare --plots DIR`` writes into ``DIR``.
PLOT_FILES = ("slope.png", "residuals.png", "noise_vs_flux.png")


def fit_path_for(exposure, fitter):
    """The default slope file of ``exposure`` fitted with ``fitter``:
    ``dir/stem_<fitter>.fits`` for ``dir/stem.fits`` (``stem_<fitter>.fits.gz`` for a
    compressed one; :func:`noise.fitsio.derived_path`); an exposure named otherwise
    (``x.dat``) gives ``x_<fitter>.fits``: the slope file is FITS."""
    path = derived_path(exposure, f"_{fitter}")
    if not path.lower().endswith(FITS_ENDINGS):
        path = os.path.splitext(path)[0] + ".fits"
    return path


def clean_stale_temps(paths):
    """Remove the temporary files that dead scenesim processes (killed by SIGKILL)
    left in the directories of ``paths``; return one line saying what was removed,
    or None (:func:`noise.fitsio.remove_stale_temps`)."""
    removed = []
    for directory in sorted({os.path.dirname(os.path.abspath(os.fspath(p)))
                             for p in paths if p is not None}):
        removed += remove_stale_temps(directory)
    if not removed:
        return None
    return (f"removed {len(removed)} temporary file(s) left by an interrupted run: "
            + ", ".join(os.path.basename(r) for r in removed))


def scene_inputs(scene):
    """Absolute paths of every file ``scene`` reads (its own file included)."""
    src, eff = scene.sources, scene.effects
    files = [scene.path, scene.noise.pca0_file, src.catalogue, src.psf.file]
    files += list(src.map_files.values()) + list(eff.map_files.values())
    files += [c.file for c in src.light_curves if c.kind == "file"]
    return [os.path.abspath(f) for f in files if isinstance(f, str)]


def scene_id(scene):
    """A 16-hex-digit digest of what a scene simulates: its detector, noise, readout,
    sources, effects and instrument, with every file it reads (catalogue, maps, PSF
    image, light curves, template) by its contents, not its path.  Not its seed (the
    ``SEED`` card says it), outputs or description.  Recorded as ``SCENEID`` in the
    exposure, the truth and the slope files, so that ``compare`` refuses a truth of
    another scene run with the same seed and readout (a probe's star of 500 e-/s
    graded against a 5000 e-/s truth: bias_opt -1.49, no word)."""
    import hashlib
    text = "|".join(repr(getattr(scene, name)) for name in
                    ("detector", "noise", "readout", "sources", "effects", "instrument"))
    own = os.path.abspath(scene.path) if scene.path else None
    for path in sorted(set(scene_inputs(scene)) - {own}, key=len, reverse=True):
        text = text.replace(repr(path), f"<file sha256 {file_sha256(path)}>")
    return hashlib.sha256(text.encode()).hexdigest()[:16]


def file_sha256(path):
    """sha256 (hex) of a file's bytes, read in 1 MB blocks."""
    import hashlib
    h = hashlib.sha256()
    with open(path, "rb") as fh:
        for block in iter(lambda: fh.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()


#: The name endings of a FITS output (``.gz``: written gzip-compressed).
FITS_ENDINGS = (".fits", ".fits.gz")


def check_outputs(outputs, *, inputs=(), overwrite=False, endings=None):
    """Check every output path of a run before any work starts.

    Parameters
    ----------
    outputs : dict
        ``{what: path}``, e.g. ``{"exposure": "x.fits", "truth": "x_truth.fits"}``;
        ``None`` paths are skipped.
    inputs : sequence of str
        Files the run reads: never written, even with ``overwrite``.
    overwrite : bool
        Replace existing outputs (not read-only ones, never inputs).
    endings : dict, optional
        ``{what: (ending, ...)}``: the name endings an output may have (compared
        without case), e.g. :data:`FITS_ENDINGS` for a FITS file.

    Returns
    -------
    dict
        ``{what: path}`` of the outputs that will be written.

    Raises
    ------
    noise.errors.ParameterError
        Naming the output and what is wrong: a compression scenesim does not write
        (``.bz2``, ...), its directory is missing or not writable, it is a directory,
        it is an input of the run, two outputs share it, or it exists (without
        ``overwrite``, or read-only).
    """
    checked = {}
    for what, path in outputs.items():
        if path is None:
            continue
        path = check_output_name(what, os.fspath(path))
        allowed = (endings or {}).get(what)
        if allowed and not path.lower().endswith(tuple(allowed)):
            raise ParameterError(
                f"the {what} {path!r} must end in {' or '.join(allowed)} (the format "
                f"it is written in)")
        for other, other_path in checked.items():
            if same_file(path, other_path):
                raise ParameterError(
                    f"the {what} and the {other} would both be written to {path!r}; "
                    f"give them different names")
        for src in inputs:
            if same_file(path, src):
                raise ParameterError(
                    f"the {what} {path!r} is a file this run reads; it is never "
                    f"overwritten, even with --overwrite: choose another output name")
        if os.path.islink(path) and not os.path.exists(path) and not overwrite:
            # a link to nothing is something there too (it had been replaced)
            raise ParameterError(
                f"the {what} {path!r} is a symbolic link (to {os.readlink(path)!r}, "
                f"which does not exist); pass --overwrite (overwrite=True) to replace "
                f"the link")
        if os.path.exists(path) and not os.path.isdir(path):
            if not overwrite:
                raise ParameterError(
                    f"the {what} {path!r} exists; pass --overwrite (overwrite=True) to "
                    f"replace it")
            # mode bits as well as access(): root may write anything
            if not os.access(path, os.W_OK) or not os.stat(path).st_mode & 0o222:
                raise ParameterError(
                    f"the {what} {path!r} exists and is read-only; it is not replaced")
        checked[what] = check_writable(what, path, overwrite=True)
    for path in checked.values():        # all checked: named if a stop leaves them
        if os.path.lexists(path):
            record_replacing(path)
    return checked


def check_not_dangling(name, path):
    """Refuse an output directory ``path`` that is a symbolic link to nothing: it
    neither exists (so it would be created) nor can be created (``makedirs`` fails on
    the link).  Returns ``path``."""
    if path is not None and os.path.islink(path) and not os.path.exists(path):
        raise ParameterError(
            f"{name!r} {os.fspath(path)!r} is a symbolic link to "
            f"{os.readlink(path)!r}, which does not exist; remove the link or name a "
            f"directory")
    return path


def check_plot_dir(directory, *, inputs=(), overwrite=False):
    """The figures ``compare`` would write into ``directory``, checked like outputs
    (:func:`check_outputs`: a figure that would replace one of ``inputs``, the files
    the run reads, is refused even with ``overwrite``).

    ``directory`` may not exist yet (it is created when the figures are written) but
    must not be a file.  Returns ``{name: path}`` of the figures.
    """
    directory = check_not_dangling("plots", os.fspath(directory))
    if os.path.exists(directory) and not os.path.isdir(directory):
        raise ParameterError(
            f"'plots' {directory!r} is a file; expected a directory for the figures")
    parent = os.path.dirname(os.path.abspath(directory))
    raw = os.path.dirname(os.path.expanduser(directory).rstrip(os.sep)) or "."
    if not os.path.isdir(parent) or not os.path.isdir(raw):    # 'missing/../plots'
        parent = parent if not os.path.isdir(parent) else raw
        raise ParameterError(
            f"'plots': the directory {parent!r} that would hold {directory!r} does not "
            f"exist")
    if not os.path.isdir(directory):
        # created later: a parent it cannot be made in, or a name too long, failed
        # with a traceback after the run (a probe)
        if not os.access(parent, os.W_OK):
            raise ParameterError(f"'plots': the directory {parent!r} that would hold "
                                 f"{directory!r} is not writable")
        check_name_length("plots", directory)
    if not os.path.isdir(directory):
        return {name: os.path.join(directory, name) for name in PLOT_FILES}
    return check_outputs({f"figure {name}": os.path.join(directory, name)
                          for name in PLOT_FILES}, inputs=inputs, overwrite=overwrite)


@contextlib.contextmanager
def made_directory(directory):
    """Create ``directory`` (for figures, pipeline products) if it is missing, and
    remove it again (if still empty) when the block fails: a refused command leaves
    nothing."""
    made = directory is not None and not os.path.isdir(directory)
    if made:
        try:
            os.makedirs(directory)
        except OSError as exc:
            raise OutputError(f"cannot create the directory {directory!r}: "
                              f"{exc.strerror or exc}", errno=exc.errno) from exc
    try:
        yield directory
    except BaseException:
        if made:
            try:
                os.rmdir(directory)
            except OSError:                # not empty: a figure was written
                pass
        raise
