"""Command-line arguments of ``scenesim calibrate`` and ``scenesim psd``.

Kept apart from :mod:`scenesim.calib.calibrate_command` so that building the parser
imports nothing heavy (the command module is imported only when its subcommand runs).
"""

__all__ = ["add_calibrate_arguments", "add_psd_arguments"]


def _detector_arguments(p):
    p.add_argument("--preset", default=None,
                   help="detector of files without scenesim detector cards (e.g. JWST "
                        "uncal): H2RG, NIRSPEC, NIRCAM, H4RG-10, WFI, ...; a file "
                        "whose cards differ is refused")
    p.add_argument("--naxis", type=int, default=None,
                   help="square array size (with --preset; default the preset's)")
    p.add_argument("--n-out", type=int, default=None,
                   help="outputs (with --preset; default the preset's)")
    p.add_argument("--gain", type=float, default=None,
                   help="e-/DN of data in DN without a GAIN card (a file that "
                        "records another gain is refused)")
    p.add_argument("--f-min", type=float, default=1e-4,
                   help="Hz below which the model 1/f PSD is flat (not identifiable "
                        "from a ramp; default 1e-4)")
    p.add_argument("--template", default=None,
                   help="bias / picture-frame template FITS (default: the synthetic one)")


def add_calibrate_arguments(p):
    """The arguments of ``scenesim calibrate``."""
    p.add_argument("darks", nargs="+", help="dark ramps (FITS), fitted together")
    p.add_argument("-o", "--output", required=True, help="[noise] table (TOML) to write")
    _detector_arguments(p)
    p.add_argument("-q", "--quiet", action="store_true")
    p.add_argument("--overwrite", action="store_true",
                   help="replace an existing output (never an input)")


def add_psd_arguments(p):
    """The arguments of ``scenesim psd``."""
    p.add_argument("files", nargs="+",
                   help="dark ramps (FITS); the model is fitted to the first, the others "
                        "are overlaid")
    p.add_argument("--plot", default=None, metavar="PNG",
                   help="write the figure (needs matplotlib, the [plot] extra); without "
                        "it the binned PSD is printed")
    _detector_arguments(p)
    p.add_argument("--overwrite", action="store_true",
                   help="replace an existing figure (never an input)")
