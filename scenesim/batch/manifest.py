"""The batch manifest: one row per task, written atomically, and what is finished.

``OUT/batch.json`` holds the batch's identity (scene file and its checksum, every
grid point's keys, the batch seed, fitters, preparation, outputs), its seed and
where it came from, and one row per task: its grid point and the scene keys it sets, spawn key, seed, status
(``pending``, ``done``, ``failed``), files (relative names, sizes, checksums),
run time and error.  It is rewritten atomically (:func:`noise.fitsio.atomic_file`)
as tasks finish, at most about once a second, and at the end.

The per-task records that workers write last (``r0007.json``) are the ground truth:
a task is finished when its record exists, belongs to this batch (same seed and
spawn key) and every file it lists still has its size and modification time (or
its checksum).  So a manifest that lags behind (the batch was killed before it was
written) loses nothing: re-running the batch skips every finished task and redoes
failed, missing or damaged ones.

A second batch in the same directory is refused while the first runs
(``OUT/.batch.lock``, an advisory ``flock``), and a manifest of another batch
(different identity) is refused before anything starts.  The identity's file names
are compared relative to the scene's folder, their contents by checksum: a project
moved or copied whole resumes its batch.
"""

import contextlib
import fcntl
import json
import os
import time

from noise.errors import ParameterError
from noise.fitsio import atomic_file, output_error, package_version
from scenesim.batch.plan import identity_digest
from scenesim.batch.tasks import RECORD_FORMAT, files_match

__all__ = ["MANIFEST_NAME", "MANIFEST_FORMAT", "Manifest", "batch_lock", "load_record",
           "read_manifest", "check_same_batch"]

MANIFEST_NAME = "batch.json"
MANIFEST_FORMAT = "scenesim-batch 1"
_LOCK_NAME = ".batch.lock"


def read_manifest(out_dir, *, what="'out'", advice="use another output directory"):
    """The manifest of ``out_dir`` as a dict, or None when there is none.

    Raises
    ------
    noise.errors.ParameterError
        The file exists but is not a scenesim batch manifest.
    """
    path = os.path.join(out_dir, MANIFEST_NAME)
    if not os.path.exists(path):
        return None
    try:
        with open(path, encoding="utf-8") as fh:
            data = json.load(fh)
    except (OSError, ValueError) as exc:
        raise ParameterError(f"{what}: {path!r} is not a readable scenesim batch "
                             f"manifest ({exc}); {advice}") from exc
    if not isinstance(data, dict) or data.get("format") != MANIFEST_FORMAT:
        raise ParameterError(f"{what}: {path!r} is not a scenesim batch manifest (format "
                             f"{MANIFEST_FORMAT!r}); {advice}")
    return data


def _describe(identity):
    pts = identity.get("points") or [[]]
    return (f"scene {os.path.basename(identity.get('scene', '?'))}, seed "
            f"{identity.get('seed')}, fit {identity.get('fit')}, {len(pts)} grid "
            f"point(s)")


def _portable(identity):
    """``identity`` with its file names relative to the scene's folder: a project
    moved or copied whole (scene, the files it reads, the output directory) is the
    same batch; the files' contents are compared by their checksums."""
    if not isinstance(identity, dict) or not isinstance(identity.get("scene"), str):
        return identity
    out = dict(identity)
    home = os.path.dirname(identity["scene"])
    out["scene"] = os.path.basename(identity["scene"])
    inputs = identity.get("inputs_sha256")
    if isinstance(inputs, dict):
        out["inputs_sha256"] = {os.path.relpath(f, home) if isinstance(f, str) and
                                os.path.isabs(f) else f: v for f, v in inputs.items()}
    return out


def check_same_batch(existing, identity, out_dir):
    """Refuse ``existing`` (a manifest) when it belongs to another batch (the same
    batch in a moved project is not another: :func:`_portable`)."""
    old = _portable(existing.get("identity", {}))
    identity = _portable(identity)
    if old == identity:
        return
    if not isinstance(old, dict):
        old = {}
    differs = sorted(k for k in set(old) | set(identity) if old.get(k) != identity.get(k))
    raise ParameterError(
        f"'out': {out_dir!r} holds the manifest of another batch ({_describe(old)}); "
        f"this one differs in {', '.join(differs)}.  Use another output directory, or "
        f"remove {os.path.join(out_dir, MANIFEST_NAME)!r} and its files to start afresh")


def load_record(task):
    """The task's record if the task is finished (record of this batch, files as
    recorded), else None."""
    paths = task.path
    try:
        with open(paths["record"], encoding="utf-8") as fh:
            rec = json.load(fh)
    except (OSError, ValueError):
        return None
    if not isinstance(rec, dict) or rec.get("format") != RECORD_FORMAT:
        return None
    if (rec.get("seed") != task.seed or rec.get("batch_seed") != task.batch_seed
            or tuple(rec.get("spawn_key", ())) != tuple(task.spawn_key)):
        return None
    files = rec.get("files")
    want = {k for k in paths if k != "record"}
    if not isinstance(files, dict) or set(files) != want:
        return None
    return rec if files_match(files, paths) else None


@contextlib.contextmanager
def batch_lock(out_dir):
    """Hold ``OUT/.batch.lock`` for the duration of a batch; refuse a second one."""
    path = os.path.join(out_dir, _LOCK_NAME)
    try:
        fd = os.open(path, os.O_RDWR | os.O_CREAT, 0o666)
    except OSError as exc:                   # e.g. a read-only file system
        raise output_error(path, exc) from exc
    try:
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError as exc:
            raise ParameterError(f"'out': another scenesim batch is running in "
                                 f"{out_dir!r}; wait for it or use another output "
                                 f"directory") from exc
        yield
    finally:
        os.close(fd)


#: At most this share of the driver's time goes to the periodic manifest writes.
WRITE_SHARE = 0.05


class Manifest:
    """The manifest being kept: rows per task, written atomically.

    Parameters
    ----------
    plan : scenesim.batch.plan.BatchPlan
    tasks : list of scenesim.batch.plan.Task
    existing : dict or None
        The manifest found in the directory (same batch), whose rows of tasks not
        in ``tasks`` (a batch run with fewer realisations) are kept.
    """

    def __init__(self, plan, tasks, existing=None):
        self.path = os.path.join(plan.out_dir, MANIFEST_NAME)
        identity = plan.identity()
        self.data = {
            "format": MANIFEST_FORMAT, "batch_id": identity_digest(identity),
            "identity": identity, "source": plan.source, "batch_seed": plan.batch_seed,
            "seed_source": plan.seed_source,
            "seeds": "realisation seed = top 63 bits of one uint64 from "
                     "SeedSequence(batch_seed, spawn_key=key); key (k,) or (point, k)",
            "scenesim": package_version(),
            "created": (existing or {}).get("created", time.strftime("%Y-%m-%dT%H:%M:%S")),
            "realisations": plan.realisations, "compare": plan.compare,
            "points": [{"index": p.index, "label": p.label,
                        "params": [[k, v] for k, v in p.params]} for p in plan.points],
            "tasks": {}, "pooled": {},
        }
        rows = dict((existing or {}).get("tasks", {}))
        params = {p.index: [[k, v] for k, v in p.params] for p in plan.points}
        for t in tasks:
            row = rows.get(t.name, {})
            rows[t.name] = {"point": t.point, "params": params[t.point],
                            "realisation": t.realisation,
                            "spawn_key": list(t.spawn_key), "seed": t.seed,
                            "status": row.get("status", "pending"),
                            "outputs": {k: os.path.relpath(v, plan.out_dir)
                                        for k, v in t.paths},
                            "files": row.get("files", {}),
                            "seconds": row.get("seconds"), "error": row.get("error")}
        self.data["tasks"] = dict(sorted(rows.items()))
        self._written = 0.0
        self._cost = 0.0

    def done(self, name, record):
        """Mark task ``name`` finished with its ``record``."""
        row = self.data["tasks"][name]
        row.update(status="done", error=None, seconds=record.get("seconds"),
                   files={k: {"size": v["size"], "sha256": v.get("sha256")}
                          for k, v in record.get("files", {}).items()})

    def failed(self, name, error):
        """Mark task ``name`` failed with the one-line ``error``."""
        self.data["tasks"][name].update(status="failed", error=str(error))

    def pending(self, name):
        """Mark task ``name`` pending (to be run)."""
        self.data["tasks"][name].update(status="pending", error=None)

    def counts(self):
        """``{status: number of tasks}``."""
        out = {}
        for row in self.data["tasks"].values():
            out[row["status"]] = out.get(row["status"], 0) + 1
        return out

    def write(self, *, every=None):
        """Write the manifest atomically (not if written less than ``every`` s ago,
        nor less than :data:`WRITE_SHARE` inverse times its last write's duration: a
        100000-task manifest, 36 MB, took 3.1 s to write, and written every second
        it took most of the driver's time)."""
        now = time.monotonic()
        if every is not None and now - self._written < max(every,
                                                           self._cost / WRITE_SHARE):
            return False
        self.data["updated"] = time.strftime("%Y-%m-%dT%H:%M:%S")
        with atomic_file(self.path, overwrite=True) as fh:
            fh.write(json.dumps(self.data, indent=1, allow_nan=True).encode())
        self._written = time.monotonic()
        self._cost = self._written - now
        return True
