"""The ``scenesim`` command.

Subcommands::

    scenesim noise --preset H2RG --frames 5 -o dark.fits     empty ramp (noise only)
    scenesim run SCENE.toml [-o OUT] [--seed N]              simulate a scene (+fit, compare)
        [--uncal] [--l1] [--reffiles]                        + JWST uncal, Roman L1, references
    scenesim fit EXPOSURE.fits [-o OUT] [--refpix none|median|jwst|irs2] [--fitter cds|ols|gls]
    scenesim compare FIT.fits TRUTH.fits [--plots DIR]       fit vs. injected truth
    scenesim bench [WORKLOAD ...] [--quick] [--peers [--ng PATH]] [--scaling [--pairs N]]
        [--fit-sizes N,... --fit-resultants N,...]           the fit's scaling grid
    scenesim pipeline jwst|roman INPUT --refs DIR [--truth T]  the real pipelines, offline
    scenesim batch SCENE.toml --realisations N --out DIR     many realisations on dask
    scenesim compare --pool DIR                              pooled over a batch
    scenesim calibrate DARK.fits [...] -o noise.toml         noise model fitted to darks
    scenesim psd FILE... [--plot psd.png]                    averaged PSD + fitted model

Errors in the input are reported in one line (exit status 2) before any work starts.
No existing file is replaced without ``--overwrite``, and never a file the command
reads (:mod:`scenesim.outputs`).  An interrupted command (Ctrl-C, SIGTERM, SIGHUP)
removes its temporary files, prints one line and exits with 128 + the signal number
(130 for Ctrl-C).
"""

import argparse
import importlib
import os
import signal
import sys

from noise.errors import ScenesimError
from scenesim.batch.options import add_batch_arguments
from scenesim.calibrate_options import add_calibrate_arguments, add_psd_arguments
from noise.fast.memory import keep_freed_memory

__all__ = ["main"]


def _parser():
    """The command line.  Each subcommand names the function that does its work as
    ``set_defaults(target="module:function")``; the module is imported only when
    that subcommand runs (see :func:`main`)."""
    p = argparse.ArgumentParser(prog="scenesim", description=__doc__.split("\n\n")[0])
    sub = p.add_subparsers(dest="command", required=True)

    q = sub.add_parser("noise", help="write an empty (noise-only) HxRG ramp")
    q.add_argument("--preset", default="H2RG",
                   help="detector preset: H1RG, H2RG, H4RG-10, H4RG-15, NIRCAM, NIRSPEC, "
                        "NIRSPEC-IRS2 or WFI (noise.clock.PRESETS)")
    q.add_argument("--frames", type=int, default=5, help="read frames per integration")
    q.add_argument("--nints", type=int, default=1, help="integrations")
    q.add_argument("--naxis", type=int, default=None,
                   help="square array size (default: the preset's)")
    q.add_argument("--n-out", type=int, default=None,
                   help="outputs (default: the preset's)")
    q.add_argument("--noise", choices=("nirspec", "white"), default="nirspec",
                   help="paper defaults (all components) or white read noise only "
                        "(the paper's 5.2 e- per read on its 5000 e- bias)")
    q.add_argument("--unit", choices=("e", "DN"), default="e")
    q.add_argument("--gain", type=float, default=None,
                   help="e-/DN for --unit DN (default 1)")
    q.add_argument("--seed", type=int, default=None)
    q.add_argument("--threads", type=int, default=None)
    q.add_argument("-o", "--output", required=True)
    q.add_argument("-q", "--quiet", action="store_true")
    q.add_argument("--overwrite", action="store_true", help=_OVERWRITE)
    q.add_argument("--force", action="store_true", help=_FORCE)
    q.set_defaults(target="scenesim.commands:noise_command")

    r = sub.add_parser("run", help="simulate a scene file (TOML)")
    r.add_argument("scene")
    r.add_argument("-o", "--output", default=None, help="exposure file")
    r.add_argument("--seed", type=int, default=None)
    r.add_argument("--fit", choices=("cds", "ols", "gls"), default=None)
    r.add_argument("--refpix", choices=("none", "median", "jwst", "irs2"), default=None)
    r.add_argument("--compare", action="store_true", help="compare the fit with truth")
    r.add_argument("--plots", default=None, help="directory for comparison PNGs")
    r.add_argument("--gauss-above", type=float, default=None,
                   help="approximation: Gaussian instead of Poisson above this mean (e-)")
    r.add_argument("--arrivals", choices=("time", "2d"), default="time",
                   help="charge arrivals: 'time' (exact, Poisson per read) or '2d' (the "
                        "paper's fast shortcut: one Poisson image spread over the reads)")
    r.add_argument("--threads", type=int, default=None)
    r.add_argument("--uncal", action="store_true",
                   help="also write the JWST uncal file STEM_uncal.fits (needs the "
                        "[jwst] extra)")
    r.add_argument("--l1", action="store_true",
                   help="also write the Roman L1 file STEM_l1.asdf (needs the [roman] "
                        "extra)")
    r.add_argument("--reffiles", action="store_true",
                   help="also write the detector's reference files into STEM_refs/ "
                        "(JWST FITS and/or Roman ASDF)")
    r.add_argument("-q", "--quiet", action="store_true")
    r.add_argument("--overwrite", action="store_true", help=_OVERWRITE)
    r.add_argument("--force", action="store_true", help=_FORCE)
    r.set_defaults(target="scenesim.commands:run_command")

    f = sub.add_parser("fit", help="fit up-the-ramp slopes of an exposure")
    f.add_argument("exposure")
    f.add_argument("-o", "--output", default=None)
    f.add_argument("--refpix", choices=("none", "median", "jwst", "irs2"), default="jwst")
    f.add_argument("--fitter", default="gls",
                   help="cds, ols or gls; or stcal-ols_c / stcal-likely to run the JWST "
                        "calibration library's fitter (needs the [stcal] extra)")
    f.add_argument("--jump-threshold", type=float, default=None,
                   help="jump detection threshold in sigma (0 = off; default 5) of "
                        "scenesim's fitters (stcal-likely uses its own 4.5 sigma, "
                        "stcal-ols_c none)")
    f.add_argument("--overwrite", action="store_true", help=_OVERWRITE)
    f.add_argument("-q", "--quiet", action="store_true",
                   help="print nothing but errors (as run and noise)")
    f.set_defaults(target="scenesim.commands:fit_command")

    c = sub.add_parser("compare", help="compare a slope file with the truth file")
    c.add_argument("fit", nargs="?")
    c.add_argument("truth", nargs="?")
    c.add_argument("--pool", default=None, metavar="DIR",
                   help="instead: pool the comparisons of the batch in DIR over its "
                        "realisations (scenesim batch --compare)")
    c.add_argument("--exposure", default=None, help="exposure (for photometry errors)")
    c.add_argument("--plots", default=None)
    c.add_argument("--overwrite", action="store_true",
                   help="replace existing figures in --plots")
    c.set_defaults(target="scenesim.commands:compare_command")

    b = sub.add_parser("bench", help="benchmarks: run time against error; peers "
                                     "measured beside scenesim (--peers)")
    b.add_argument("workloads", nargs="*",
                   help="workloads (default: all): noise, jwst, roman, fit, timeseries, "
                        "options, pink, skips, batch; 'peers' = noise, roman and fit "
                        "with their peers")
    b.add_argument("--quick", action="store_true")
    b.add_argument("--out", default="bench_out",
                   help="directory for bench.json, bench.md (and bench.png)")
    b.add_argument("--overwrite", action="store_true",
                   help="replace the report files of an earlier run in --out")
    b.add_argument("--threads", type=int, default=None)
    b.add_argument("--peers", action="store_true",
                   help="time each case's peers (NG, romanisim, stcal) in their own "
                        "processes on the same input; absent ones print 'not measured'")
    b.add_argument("--ng", default=None, metavar="PATH/nghxrg.py",
                   help="the original NG program (not on the package index), with --peers")
    b.add_argument("--scaling", action="store_true",
                   help="run each case again on one thread (1- and N-thread times)")
    b.add_argument("--pairs", type=int, default=1, metavar="N",
                   help="with --scaling: N alternating N-thread/1-thread pairs of runs "
                        "per case; speed-ups are the medians of the pairs (default 1)")
    b.add_argument("--fit-sizes", default=None, metavar="N,N,...",
                   help="fit workload: only its scaling grid, at these array sizes "
                        "(default 512,1024,2048,4096)")
    b.add_argument("--fit-resultants", default=None, metavar="N,N,...",
                   help="fit workload: only its scaling grid, at these ramp lengths "
                        "(default 5,10,20,50,100,200)")
    b.set_defaults(target="scenesim.commands:bench_command")

    pl = sub.add_parser("pipeline", help="run JWST Detector1 or romancal's ramp fit "
                                         "offline on a scenesim exposure")
    pl.add_argument("pipeline", choices=("jwst", "roman"))
    pl.add_argument("input", help="JWST uncal (STEM_uncal.fits) or Roman L1 "
                                  "(STEM_l1.asdf), from 'scenesim run --uncal/--l1'")
    pl.add_argument("--refs", required=True,
                    help="reference directory from 'scenesim run --reffiles'")
    pl.add_argument("-o", "--output", default=None,
                    help="jwst: output directory (default: the input's); roman: the "
                         "L2 file (default STEM_l2.asdf)")
    pl.add_argument("--truth", default=None, help="truth file: compare the result")
    pl.add_argument("--exposure", default=None,
                    help="scenesim exposure (exact read times for compare)")
    pl.add_argument("--overwrite", action="store_true", help=_OVERWRITE)
    pl.set_defaults(target="scenesim.pipelines.command:pipeline_command")

    m = sub.add_parser("batch", help="many realisations or a grid of scenes on dask "
                                     "(needs the [batch] extra)")
    add_batch_arguments(m)
    m.set_defaults(target="scenesim.batch.command:batch_command")

    k = sub.add_parser("calibrate", help="fit the noise model to dark ramps: a [noise] "
                                         "table (also 'scenesim noise calibrate')")
    add_calibrate_arguments(k)
    k.set_defaults(target="scenesim.calib.calibrate_command:calibrate_command")

    d = sub.add_parser("psd", help="averaged PSD of dark ramps in readout time order, "
                                   "with the fitted model")
    add_psd_arguments(d)
    d.set_defaults(target="scenesim.calib.calibrate_command:psd_command")
    return p


_OVERWRITE = ("replace existing output files (never a file the command reads, never a "
              "read-only one)")
_FORCE = ("run even when the estimated memory or output exceeds what the machine has "
          "(checked before any work; scenesim.budget)")


class Interrupted(KeyboardInterrupt):
    """A termination signal (SIGTERM, SIGHUP) turned into an exception in the main
    thread, so the ``with`` blocks that own temporary files remove them; also the
    recorded signal (SIGINT too) when its exception surfaced as another one."""

    def __init__(self, signum):
        super().__init__(signal.Signals(signum).name)
        self.signum = signum


#: Signals delivered to the command, in order (its handlers record them).
_RECEIVED = []


def _raise_interrupted(signum, frame):
    _RECEIVED.append(signum)
    raise Interrupted(signum)


def _record_int(signum, frame):
    """SIGINT: recorded, then Python's own KeyboardInterrupt."""
    _RECEIVED.append(signum)
    signal.default_int_handler(signum, frame)


def _interrupt_of(exc):
    """The interrupt that ends the command, or None.

    A signal's exception is raised wherever the main thread happens to be, and
    there it can be replaced by another one: inside a lock's wait
    (``threading.Condition.wait`` in ``Future.result``) it came out as "cannot
    release un-acquired lock"; inside the import of a compiled extension as an
    ImportError that does not even keep it as context.  So the handlers record the
    signal, and a recorded signal decides how the command ends, whatever exception
    reached :func:`main`."""
    if isinstance(exc, KeyboardInterrupt):
        return exc
    if _RECEIVED:
        return Interrupted(_RECEIVED[0])
    return None


def main(argv=None):
    """Entry point of the ``scenesim`` console command."""
    # First thing: a SIGTERM or SIGHUP from now on ends the command in one line.
    _RECEIVED.clear()
    for sig in (signal.SIGTERM, signal.SIGHUP):
        signal.signal(sig, _raise_interrupted)
    if signal.getsignal(signal.SIGINT) is signal.default_int_handler:
        signal.signal(signal.SIGINT, _record_int)     # (an ignored SIGINT stays so)
    argv = sys.argv[1:] if argv is None else list(argv)
    if argv[:2] == ["noise", "calibrate"]:       # the same command, under 'noise'
        argv = argv[1:]
    fitsio = sys.modules.get("noise.fitsio")
    if fitsio is not None:        # an earlier command of this process (a library
        fitsio._REPLACING.clear()  # caller, tests): its outputs are not this one's
    try:
        args = _parser().parse_args(argv)
    except KeyboardInterrupt as exc:
        return _interrupted("", exc)
    try:
        # The ~0.7 s of imports run with the interrupt signals blocked: one that
        # arrives then is delivered when they are done (an interrupt inside the
        # import of a compiled extension can make Python exit through SIGINT even
        # when it is caught), so it is handled like any other.
        blocked = {signal.SIGINT, signal.SIGTERM, signal.SIGHUP}
        signal.pthread_sigmask(signal.SIG_BLOCK, blocked)
        module, name = args.target.split(":")
        try:
            command = getattr(importlib.import_module(module), name)
        finally:
            signal.pthread_sigmask(signal.SIG_UNBLOCK, blocked)
        keep_freed_memory()        # process-wide malloc policy: see noise.fast.memory
        return command(args)
    except BaseException as exc:
        code = _ending(args.command, exc)
        if code is None:
            raise
        return code


def _ending(command, exc):
    """The exit status of a command that raised ``exc``, its one line printed; None for
    an exception that is a bug (its traceback is shown)."""
    interrupt = _interrupt_of(exc)
    if interrupt is not None:
        # the interrupt decides, whatever exception it turned into on the way out
        return _interrupted(f" {command}", interrupt)
    if isinstance(exc, ScenesimError):
        # an OutputError (disk full, file-size limit): what was finished stays
        kept = _kept(f" {command}") if isinstance(exc, OSError) and \
            command != "batch" else ""
        print(f"scenesim {command}: error: {exc}{'; ' + kept if kept else ''}",
              file=sys.stderr)
        return 2
    if isinstance(exc, MemoryError):
        # Reached only past the size check (scenesim.budget), e.g. with --force or
        # when other processes took the memory; the temporary files are already gone.
        hint = ("see the size estimate: run without --force, or on a smaller array"
                if command in ("run", "noise", "batch") else "try a smaller input")
        print(f"scenesim {command}: error: out of memory; no partial output was "
              f"left ({hint})", file=sys.stderr)
        return 1
    if isinstance(exc, BrokenPipeError):
        # stdout closed early (``scenesim ... | head``): not an error of the command.
        # Point stdout at /dev/null so that Python's exit flush does not fail again.
        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, sys.stdout.fileno())
        return 128 + int(signal.SIGPIPE)
    return None


def _kept(command):
    """What a stopped command leaves finished, for its one line: the files it had
    renamed into place, or a batch's finished tasks, and the existing files it was
    to replace and had not; '' when none."""
    fitsio = sys.modules.get("noise.fitsio")          # imported by every writer
    done = fitsio.completed_outputs() if fitsio is not None else []
    stale = fitsio.stale_outputs() if fitsio is not None else []
    if command == " batch":           # its workers' files are in its manifest
        return "the finished tasks are kept (the same command resumes the batch)" \
            if done else ""
    parts = []
    if done:
        names = ", ".join(repr(p) for p in done[:4])
        more = f" and {len(done) - 4} more" if len(done) > 4 else ""
        parts.append(f"the files it had finished are complete and kept ({names}{more})")
    if stale:
        names = ", ".join(repr(os.path.relpath(p)) for p in stale[:4])
        more = f" and {len(stale) - 4} more" if len(stale) > 4 else ""
        parts.append(f"{names}{more} {'was' if len(stale) == 1 else 'were'} not "
                     f"rewritten and {'is' if len(stale) == 1 else 'are'} still an "
                     f"earlier run's")
    return "; ".join(parts)


def _interrupted(command, exc):
    """The one line of an interrupted command; its exit status (128 + signal)."""
    signum = getattr(exc, "signum", signal.SIGINT)
    kept = _kept(command)
    print(f"scenesim{command}: interrupted ({signal.Signals(signum).name}); "
          f"{kept + '; ' if kept else ''}no partial output was left", file=sys.stderr)
    return 128 + int(signum)


def console_main():
    """The ``scenesim`` console script and ``python -m scenesim.cli``: :func:`main`,
    then the interrupt signals ignored while the interpreter shuts down (0.3-0.4 s
    after the work: a Ctrl-C or SIGTERM then ended a finished command with status
    130 or 143 and no line, its outputs complete; a probe)."""
    code = main()
    for sig in (signal.SIGINT, signal.SIGTERM, signal.SIGHUP):
        signal.signal(sig, signal.SIG_IGN)
    return code


if __name__ == "__main__":
    sys.exit(console_main())
