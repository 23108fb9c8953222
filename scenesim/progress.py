"""The progress bar of the commands (kept out of :mod:`scenesim.run` so that
``scenesim noise`` does not import the scene machinery to draw one)."""

from tqdm import tqdm

__all__ = ["progress_bar"]


def progress_bar(total, unit, desc):
    """A tqdm bar refreshed by our callbacks, without tqdm's monitor thread.

    The monitor only matters for bars that stop being updated; ours are updated after
    every read (and drawn at most every 0.1 s).  Without it the process keeps a single
    thread, so small frames may use the
    forked helper of :mod:`noise.fast.producer` (which refuses to fork a multi-threaded
    process).
    """
    interval = tqdm.monitor_interval
    tqdm.monitor_interval = 0
    try:
        # miniters=1: no dynamic skipping (which needs the monitor to recover)
        return tqdm(total=total, unit=unit, desc=desc, leave=False, miniters=1)
    finally:
        tqdm.monitor_interval = interval
