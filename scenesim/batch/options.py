"""The options of ``scenesim batch``, kept apart so that the command line is built
without importing the batch machinery (:mod:`scenesim.cli` imports this module)."""

__all__ = ["add_batch_arguments"]


def add_batch_arguments(p):
    """The options of ``scenesim batch`` on the argparse parser ``p``."""
    p.add_argument("scene", help="scene file (N realisations) or batch file (grid)")
    p.add_argument("--out", required=True, help="output directory (resumable)")
    p.add_argument("-n", "--realisations", type=int, default=None,
                   help="realisations per grid point (default: the batch file's, or 1)")
    p.add_argument("--seed", type=int, default=None,
                   help="batch seed (default: the batch file's, else the scene's)")
    p.add_argument("--fit", action="append", default=None,
                   help="fitter: cds, ols, gls, stcal-ols_c, stcal-likely (repeat, or "
                        "comma-separated; default the scene's [output] fit)")
    p.add_argument("--compare", action="store_true", default=None,
                   help="grade every fit against the truth and pool over realisations")
    p.add_argument("--no-ramp", dest="ramp", action="store_false", default=None,
                   help="keep only the fits and the truth (no ramp files)")
    p.add_argument("--refpix", choices=("none", "median", "jwst", "irs2"), default=None,
                   help="reference correction before the fits (default: the batch "
                        "file's, else the scene's [output] refpix)")
    p.add_argument("--scheduler", default=None,
                   help="dask scheduler address (tcp://HOST:8786) or scheduler file; "
                        "default a local cluster")
    p.add_argument("--workers", type=int, default=None,
                   help="local cluster: worker processes (default: the cores)")
    p.add_argument("--threads", type=int, default=None,
                   help="threads per task (default: cores // workers locally, else 1)")
    p.add_argument("--retries", type=int, default=2,
                   help="times a failed task is run again (default 2)")
    p.add_argument("--connect-timeout", type=float, default=10.0,
                   help="seconds to wait for the scheduler (default 10)")
    p.add_argument("--force", action="store_true",
                   help="run even when the tasks left need more memory (local "
                        "workers) or disk than this machine has")
    p.add_argument("-q", "--quiet", action="store_true")
