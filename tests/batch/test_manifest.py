"""The manifest's periodic writes take a bounded share of the driver's time; what a
batch with failed tasks says of the others."""

import time

from scenesim.batch.manifest import WRITE_SHARE, Manifest
from scenesim.batch.plan import plan_batch
from scenesim.batch.runner import _failed_message


def test_periodic_writes_wait_for_their_share(small_scene, tmp_path):
    # a 100000-task manifest took 3.1 s to write: written every second, it took most
    # of the driver's time; now the next periodic write waits cost / WRITE_SHARE
    out = tmp_path / "o"
    out.mkdir()
    plan = plan_batch(small_scene, out=out, realisations=3)
    m = Manifest(plan, plan.tasks())
    assert m.write(every=1.0)                       # the first: always
    assert not m.write(every=1.0)                   # within the second
    m._written -= 1.5
    m._cost = 1.0                                   # as if it took 1 s to write
    assert 1.5 < 1.0 / WRITE_SHARE and not m.write(every=1.0)
    m._written = time.monotonic() - 1.0 / WRITE_SHARE - 0.1
    assert m.write(every=1.0)
    assert m.write()                                # unconditional writes: always


def test_the_failure_message_counts_the_finished_tasks():
    # it said "the others are finished" when every task had failed
    msg = _failed_message(["a", "b"], 2, "boom", "m.json")
    assert msg.startswith("2 of 2 tasks failed (first: a: boom). Errors are in m.json")
    assert "finished" not in msg
    assert "; the other task is finished." in _failed_message(["a"], 2, "x", "m")
    assert "; the other 3 are finished." in _failed_message(["a"], 4, "x", "m")
