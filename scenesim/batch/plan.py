"""A batch, planned: the scenes, the grid, the realisations, their seeds and files.

Two inputs, told apart by their top-level keys:

* a **scene file** (``scenes/quick.toml``): ``N`` realisations of that scene;
* a **batch file**: a ``scene`` key naming a scene file, plus grids over its keys and
  the detectors of one exposure::

      scene = "quick.toml"          # relative to the batch file
      seed = 2026                   # batch seed (default: the scene's)
      realisations = 4              # per grid point (default 1)
      fit = ["gls", "stcal-ols_c"]  # default: the scene's [output] fit
      compare = true                # default: the scene's [output] compare
      ramp = true                   # default: the scene's [output] ramp
      refpix = "jwst"               # default: the scene's [output] refpix

      [grid]                        # every combination of these values
      "sources.background" = [0.1, 1.0, 10.0]
      "noise.rd_noise" = [3.0, 5.2]

      [[detectors]]                 # optional: the detectors of one exposure
      name = "SCA01"
      "noise.rd_noise" = 5.0

  A grid or detector key is a dotted path of scene keys (``"sources.stars.0.flux"``
  reaches into the first ``[[sources.stars]]``; unquoted TOML dotted keys work too).
  Every grid point is a scene file with those keys set, validated like one: an
  unknown key is refused, naming the grid key and the nearest valid scene key,
  before anything runs.  ``seed`` and ``[output]`` keys are the batch's own, so a
  grid may not set them.  File paths given as grid values are relative to the scene
  file, as inside it.

Seeds
-----
Realisation ``k`` of grid point ``p`` draws from the batch seed's spawned child
``SeedSequence(batch_seed).spawn(P)[p].spawn(N)[k]``, i.e.
``SeedSequence(batch_seed, spawn_key=(p, k))``; a one-point batch (a scene file)
uses ``spawn(N)[k]``, key ``(k,)``.  The scene seed of the realisation is the first
63 bits that child generates (:func:`realisation_seed`), so it is a plain integer
seed: ``scenesim run SCENE --seed <that seed>`` repeats the realisation bit for bit,
and every output header records it (``SEED``) with the batch seed and the spawn key
(``BATCHSD``, ``BATCHKEY``).  Nothing depends on the number of workers, the order in
which tasks finish or how often one is retried; adding realisations or grid points
to the end leaves the seeds of the others unchanged.

Files
-----
Realisation ``k`` of a one-point batch writes ``OUT/r0007.fits`` (no ramp file with
``ramp = false``), ``OUT/r0007_truth.fits``, one slope file per fitter
(``OUT/r0007_gls.fits``, ``OUT/r0007_stcal-ols_c.fits``) and its record
``OUT/r0007.json``; grid point ``p`` puts its files in ``OUT/p003/``.
"""

import dataclasses
import hashlib
import importlib.util
import itertools
import json
import math
import os
import secrets
from dataclasses import dataclass

import numpy as np

try:
    import tomllib
except ModuleNotFoundError:  # Python 3.10
    import tomli as tomllib

from noise.errors import FileFormatError, ParameterError, ParameterTypeError
from noise.validate import (check_bool, check_choice, check_int, check_path, check_str,
                            describe, suggest)
from scenesim.calib.refpix import SCHEMES, applied_scheme
from scenesim.outputs import file_sha256, fit_path_for, scene_inputs
from scenesim.scene import load_scene, parse_scene
from scenesim.scene.schema import MAX_SEED

__all__ = ["FITTERS", "BatchPlan", "Point", "Task", "plan_batch", "realisation_seed",
           "spawn_key", "identity_digest", "MAX_POINTS", "MAX_TASKS"]

#: At most this many grid points (checked before the grid is built).
MAX_POINTS = 100000

#: At most this many runs (realisations times grid points) in one batch.
MAX_TASKS = 100000

#: Fitters a batch can run: scenesim's own and stcal's (the ``[stcal]`` extra).
FITTERS = ("cds", "ols", "gls", "stcal-ols_c", "stcal-likely")

_BATCH_KEYS = ("scene", "seed", "realisations", "fit", "compare", "ramp", "refpix",
               "description", "grid", "detectors")


# ---------------------------------------------------------------------- seeds
def spawn_key(point, realisation, npoints):
    """Spawn key of realisation ``realisation`` of grid point ``point`` under the batch
    seed: ``(realisation,)`` for a one-point batch, else ``(point, realisation)``."""
    return (int(realisation),) if npoints == 1 else (int(point), int(realisation))


def realisation_seed(batch_seed, key):
    """The integer scene seed of the realisation with spawn key ``key``.

    ``SeedSequence(batch_seed, spawn_key=key)`` (the child that
    ``SeedSequence(batch_seed).spawn`` gives at that position) generates one 64-bit
    word; its top 63 bits are the seed, in ``[0, 2**63 - 1]`` like every scene seed.

    Parameters
    ----------
    batch_seed : int
        In ``[0, 2**63 - 1]``.
    key : tuple of int
        See :func:`spawn_key`.

    Returns
    -------
    int
    """
    ss = np.random.SeedSequence(int(batch_seed), spawn_key=tuple(int(k) for k in key))
    return int(ss.generate_state(1, np.uint64)[0] >> np.uint64(1))


# ---------------------------------------------------------------------- plan
@dataclass(frozen=True)
class Point:
    """One grid point: its index, directory label ("" for a one-point batch), the
    keys it sets (``((dotted_key, value), ...)``) and the validated scene."""

    index: int
    label: str
    params: tuple
    scene: object


@dataclass(frozen=True)
class Task:
    """One realisation: what a worker needs to make it, and nothing large.

    ``scene`` has the realisation's seed and ``[output]`` set; ``paths`` maps
    ``'exposure'`` (absent with ``ramp = false``), ``'truth'``, each fitter and
    ``'record'`` to absolute paths; ``threads`` runs the engine and the fits.
    """

    name: str
    point: int
    realisation: int
    spawn_key: tuple
    seed: int
    batch_seed: int
    scene: object
    paths: tuple
    fitters: tuple
    compare: bool
    refpix: str
    threads: int | None = None
    detector: str = ""          # the point's [[detectors]] name ("" without them)

    @property
    def path(self):
        """``{kind: absolute path}`` of the task's files."""
        return dict(self.paths)


@dataclass(frozen=True)
class BatchPlan:
    """A validated batch: what runs, with which seeds, into which files.

    Attributes
    ----------
    source : str
        The scene or batch file (absolute).
    scene_path : str
        The scene file (absolute).
    points : tuple of Point
    realisations : int
        Per grid point.
    batch_seed : int
    seed_source : str
        Where the batch seed came from: ``'option'``, ``'batch file'``, ``'scene'``
        or ``'drawn'`` (fresh OS entropy, recorded in the manifest).
    fitters : tuple of str
    compare, ramp : bool
    refpix : str
    out_dir : str
        Absolute.
    """

    source: str
    scene_path: str
    points: tuple
    realisations: int
    batch_seed: int
    seed_source: str
    fitters: tuple
    compare: bool
    ramp: bool
    refpix: str
    out_dir: str

    def identity(self):
        """What makes two batches the same batch (JSON-able): the scene file and its
        contents and those of every file the scenes read, every point's keys, the seed
        (unless drawn), fitters, preparation and outputs.  Not the number of
        realisations: a batch may be extended."""
        with open(self.scene_path, "rb") as fh:
            digest = hashlib.sha256(fh.read()).hexdigest()
        # the files the scenes read too (catalogue, maps, PSF, light curves,
        # template): a batch resumed after one changed had mixed two scenes
        inputs = sorted({f for p in self.points for f in scene_inputs(p.scene)}
                        - {self.scene_path})
        out = {"scene": self.scene_path, "scene_sha256": digest,
               "points": [_jsonable(p.params) for p in self.points],
               "seed": None if self.seed_source == "drawn" else self.batch_seed,
               "fit": list(self.fitters), "ramp": self.ramp, "refpix": self.refpix}
        if inputs:
            out["inputs_sha256"] = {f: file_sha256(f) for f in inputs}
        return out

    def tasks(self, *, threads=None):
        """Every :class:`Task` of the batch, point by point, realisation by
        realisation."""
        out = []
        for p in self.points:
            folder = os.path.join(self.out_dir, p.label) if p.label else self.out_dir
            for k in range(self.realisations):
                key = spawn_key(p.index, k, len(self.points))
                seed = realisation_seed(self.batch_seed, key)
                stem = os.path.join(folder, f"r{k:04d}")
                # the task's files are ``paths`` (no exposure: ramp = false); the
                # scene's [output] only names them
                cfg = dataclasses.replace(p.scene.output, path=stem + ".fits",
                                          ramp=True, truth=True, fit="",
                                          compare=False, refpix=self.refpix)
                paths = {"truth": cfg.truth_path}
                if self.ramp:
                    paths["exposure"] = cfg.path
                for f in self.fitters:
                    paths[f] = fit_path_for(cfg.path, f)
                paths["record"] = stem + ".json"
                name = f"{p.label}/r{k:04d}" if p.label else f"r{k:04d}"
                out.append(Task(name=name, point=p.index, realisation=k,
                                spawn_key=key, seed=seed, batch_seed=self.batch_seed,
                                scene=p.scene.replace(seed=seed, output=cfg),
                                paths=tuple(paths.items()), fitters=self.fitters,
                                compare=self.compare, refpix=self.refpix,
                                threads=threads,
                                detector=dict(p.params).get("detector", "")))
        return out


def _jsonable(value):
    """``value`` with tuples as lists and numpy scalars as Python numbers."""
    if isinstance(value, (list, tuple)):
        return [_jsonable(v) for v in value]
    if isinstance(value, dict):
        return {str(k): _jsonable(v) for k, v in value.items()}
    if isinstance(value, np.generic):
        return value.item()
    return value


def _read_toml(path, what):
    try:
        with open(path, "rb") as fh:
            return tomllib.load(fh)
    except FileNotFoundError as exc:
        raise FileFormatError(f"{what} {path!r} does not exist") from exc
    except IsADirectoryError as exc:
        raise FileFormatError(f"{what} {path!r} is a directory, not a TOML file") from exc
    except OSError as exc:
        raise FileFormatError(f"{what} {path!r} cannot be read: {exc}") from exc
    except tomllib.TOMLDecodeError as exc:
        raise FileFormatError(f"{what} {path!r} is not valid TOML: {exc}") from exc
    except UnicodeDecodeError as exc:         # TOML is UTF-8 (a Latin-1 editor's file)
        raise FileFormatError(f"{what} {path!r} is not valid TOML: byte {exc.start} is "
                              f"not UTF-8 text (TOML files are UTF-8)") from exc


def _flatten(table, where, prefix=""):
    """``{dotted.key: value}`` of a TOML table (nested tables joined with dots).

    A key given both quoted (``"noise.rd_noise"``) and as TOML dotted keys or a
    table (``noise.rd_noise``) is two TOML keys but one scene key: refused (it had
    silently kept one of the two)."""
    flat = {}
    for key, value in table.items():
        full = f"{prefix}{key}"
        parts = _flatten(value, where, full + ".") if isinstance(value, dict) \
            else {full: value}
        for k, v in parts.items():
            if k in flat:
                raise ParameterError(
                    f"{where} {k!r} is given twice (once quoted, once as dotted keys or "
                    f"a table): give it once")
            flat[k] = v
    return flat


def _set_key(mapping, dotted, value, where):
    """Set ``dotted`` (``"sources.stars.0.flux"``) in the scene mapping, in place."""
    parts = dotted.split(".")
    if parts[0] == "seed":
        raise ParameterError(
            f"{where} {dotted!r}: each realisation's seed comes from the batch seed; "
            f"set 'seed' at the top of the batch file or with --seed")
    if parts[0] == "output":
        raise ParameterError(
            f"{where} {dotted!r}: the batch names and chooses its outputs; set 'fit', "
            f"'compare', 'ramp' or 'refpix' at the top of the batch file")
    node = mapping
    for i, part in enumerate(parts[:-1]):
        here = ".".join(parts[:i + 1])
        if isinstance(node, list):
            if not part.isdigit() or int(part) >= len(node):
                raise ParameterError(
                    f"{where} {dotted!r} is not a scene key: {here!r} indexes a list "
                    f"of {len(node)} tables (0 to {len(node) - 1})")
            node = node[int(part)]
        elif isinstance(node, dict):
            if part not in node:
                node[part] = {}
            node = node[part]
        else:
            raise ParameterError(f"{where} {dotted!r} is not a scene key: "
                                 f"{'.'.join(parts[:i])!r} is not a table")
        if not isinstance(node, (dict, list)):
            raise ParameterError(f"{where} {dotted!r} is not a scene key: {here!r} is a "
                                 f"value ({describe(node)}), not a table")
    if isinstance(node, list):
        raise ParameterError(f"{where} {dotted!r} is not a scene key: it names an "
                             f"element of a list of tables, not a key")
    node[parts[-1]] = value


def _scene_at(raw, scene_path, params, where):
    """The scene file's mapping with ``params`` set, validated into a Scene."""
    import copy
    mapping = copy.deepcopy(raw)
    for key, value in params:
        _set_key(mapping, key, value, f"{where} key")
    try:
        scene = parse_scene(mapping, base_dir=os.path.dirname(scene_path))
    except (ParameterError, FileFormatError) as exc:
        keys = ", ".join(repr(k) for k, _ in params)
        raise type(exc)(f"{where} with {keys}: {exc}") from exc
    return scene.replace(path=scene_path)


def _fitters(value, where):
    """The fitters of ``value``; ``where`` is ``--fit`` (the option, or ``fit=`` of
    :func:`plan_batch`) or the table that gave them."""
    prefix = "" if where.startswith("--") else f"{where} "
    if isinstance(value, str):
        value = [value] if value else []
    if not isinstance(value, (list, tuple)):
        raise ParameterTypeError(f"{prefix}'fit' must be a fitter name or a list of "
                                 f"them, got {describe(value)}")
    out = []
    for f in value:
        try:
            f = check_choice("fit", f.lower() if isinstance(f, str) else f, FITTERS)
        except ParameterError as exc:
            raise type(exc)(f"{prefix}{exc}") from exc
        if f in out:
            raise ParameterError(f"{prefix}'fit' lists {f!r} twice")
        out.append(f)
    return tuple(out)


def _grid_points(batch, where):
    """``[params, ...]``: every combination of the grid, times the detectors."""
    grid = batch.get("grid", {})
    if not isinstance(grid, dict):
        raise ParameterTypeError(f"{where} [grid] must be a table, got {describe(grid)}")
    axes = []
    for key, values in _flatten(grid, f"{where} [grid]").items():
        if not isinstance(values, list) or not values:
            raise ParameterError(f"{where} [grid] {key!r} must be a non-empty list of "
                                 f"values, got {describe(values)}")
        axes.append([(key, v) for v in values])
    dets = batch.get("detectors")
    ndet = len(dets) if isinstance(dets, list) else 1
    count = ndet * math.prod(len(a) for a in axes)
    if count > MAX_POINTS:       # before the product is built (10^7 took 1.2 GB)
        sizes = " x ".join(str(len(a)) for a in axes) + (
            f" x {ndet} detectors" if dets is not None else "")
        raise ParameterError(f"{where} the grid has {count} points ({sizes}); at most "
                             f"{MAX_POINTS}")
    points = [tuple(c) for c in itertools.product(*axes)]
    if dets is None:
        return points
    if not isinstance(dets, list) or not dets or not all(isinstance(d, dict)
                                                          for d in dets):
        raise ParameterTypeError(f"{where} 'detectors' must be an array of tables "
                                 f"([[detectors]]), got {describe(dets)}")
    names = []
    det_params = []
    for i, d in enumerate(dets):
        d = dict(d)
        name = check_str(f"{where} [[detectors]] #{i} 'name'", d.pop("name", f"det{i}"),
                         nonempty=True, label=True)
        if name in names:
            raise ParameterError(f"{where} [[detectors]] name {name!r} appears twice")
        names.append(name)
        flat = _flatten(d, f"{where} [[detectors]] {name!r}")
        both = sorted(set(flat) & {a[0][0] for a in axes})
        if both:
            # the grid's value had silently won over the detector's
            raise ParameterError(
                f"{where} [[detectors]] {name!r} sets {', '.join(map(repr, both))}, "
                f"which the [grid] also varies: set each key in one place")
        det_params.append((("detector", name),) + tuple(flat.items()))
    return [dp + gp for gp in points for dp in det_params]


def plan_batch(path, *, out, realisations=None, seed=None, fit=None, compare=None,
               ramp=None, refpix=None):
    """Read and validate a scene or batch file into a :class:`BatchPlan`.

    Every grid point's scene is built and validated here, so a bad key or value stops
    the batch before any task starts.

    Parameters
    ----------
    path : str or os.PathLike
        A scene file, or a batch file (top-level ``scene`` key).
    out : str or os.PathLike
        Output directory (created by the run if missing; its parent must exist).
    realisations : int, optional
        Per grid point (>= 1); overrides the batch file's (default 1).
    seed : int, optional
        Batch seed in ``[0, 2**63 - 1]``; default the batch file's, else the scene's,
        else fresh OS entropy.
    fit : str or sequence of str, optional
        Fitters among :data:`FITTERS`; default the batch file's, else the scene's
        ``[output] fit``.
    compare, ramp : bool, optional
        Grade every fit against the truth; write the ramp file.  Default the batch
        file's, else the scene's ``[output]``.
    refpix : {'none', 'median', 'jwst', 'irs2'}, optional
        Reference correction before the fits; default the batch file's, else the
        scene's ``[output] refpix``.  Checked against every grid point's readout
        (:func:`scenesim.calib.refpix.applied_scheme`).

    Returns
    -------
    BatchPlan

    Raises
    ------
    noise.errors.ParameterError, noise.errors.FileFormatError
        Naming the file, the key and the bad value.
    """
    source = os.path.abspath(check_path("scene", path))
    out_dir = os.path.abspath(check_path("out", out))
    raw = _read_toml(source, "scene or batch file")
    batch = raw if "scene" in raw else None
    where = f"batch file {source}:"
    if batch is None:
        scene_path = source
        scene = load_scene(source)
        points = (Point(0, "", (), scene),)
        file_real = 1
        file_seed = None
        defaults = {}
    else:
        for key in batch:
            if key not in _BATCH_KEYS:
                raise ParameterError(f"{where} unknown key {key!r}"
                                     f"{suggest(key, _BATCH_KEYS) or '; allowed: ' + ', '.join(_BATCH_KEYS)}")
        scene_path = os.path.abspath(os.path.join(
            os.path.dirname(source), check_str(f"{where} 'scene'", batch["scene"],
                                               nonempty=True)))
        scene_raw = _read_toml(scene_path, f"{where} scene file")
        base = load_scene(scene_path)
        combos = _grid_points(batch, where)
        if combos == [()]:
            points = (Point(0, "", (), base),)
        else:
            points = tuple(Point(i, f"p{i:03d}", c, _scene_at(scene_raw, scene_path, [
                kv for kv in c if kv[0] != "detector"], f"{where} grid point {i}"))
                for i, c in enumerate(combos))
        scene = base
        try:      # check_int quotes its name: the file goes before it
            file_real = check_int("realisations", batch.get("realisations", 1),
                                  minimum=1)
            file_seed = batch.get("seed")
            if file_seed is not None:
                file_seed = check_int("seed", file_seed, minimum=0, maximum=MAX_SEED)
        except ParameterError as exc:
            raise type(exc)(f"{where} {exc}") from exc
        defaults = {k: batch[k] for k in ("fit", "compare", "ramp", "refpix") if k in batch}
    cfg = scene.output
    n = check_int("realisations", realisations, minimum=1) if realisations is not None \
        else file_real
    if n * len(points) > MAX_TASKS:    # before any task is built (0.7 ms each)
        raise ParameterError(
            f"the batch has {n} realisations x {len(points)} grid points = "
            f"{n * len(points)} runs; at most {MAX_TASKS} (split it into batches)")
    if seed is not None:
        batch_seed, source_of_seed = check_int("seed", seed, minimum=0,
                                               maximum=MAX_SEED), "option"
    elif file_seed is not None:
        batch_seed, source_of_seed = file_seed, "batch file"
    elif scene.seed is not None:
        batch_seed, source_of_seed = scene.seed, "scene"
    else:
        batch_seed, source_of_seed = secrets.randbits(63), "drawn"
    fitters = _fitters(fit if fit is not None else defaults.get("fit", cfg.fit),
                       "--fit" if fit is not None else (where if "fit" in defaults
                                                        else "[output]"))
    def setting(key, given, check):
        """``check`` of the option, else the batch file's key, else the scene's
        [output] key; an error names the one that was used."""
        if given is not None:
            return check(given)
        try:
            return check(defaults.get(key, getattr(cfg, key)))
        except ParameterError as exc:
            raise type(exc)(f"{where if key in defaults else '[output]'} {exc}") \
                from exc

    compare = setting("compare", compare, lambda v: check_bool("compare", v))
    ramp = setting("ramp", ramp, lambda v: check_bool("ramp", v))
    refpix_from = ("--refpix" if refpix is not None else
                   f"{where} 'refpix'" if "refpix" in defaults else "[output] 'refpix'")
    refpix = setting("refpix", refpix,
                     lambda v: check_choice("refpix", v, SCHEMES))
    if compare and not fitters:
        raise ParameterError("'compare' grades fitted slopes, so it needs at least one "
                             f"fitter ('fit': {', '.join(FITTERS)})")
    if not ramp and not fitters:
        raise ParameterError("'ramp = false' keeps only the fits and the truth, so it "
                             f"needs at least one fitter ('fit': {', '.join(FITTERS)})")
    if any(f.startswith("stcal-") for f in fitters) and \
            importlib.util.find_spec("stcal") is None:
        raise ParameterError(f"'fit' {list(fitters)}: stcal is not installed; pip "
                             f"install 'scenesim[stcal]'")
    for p in points:
        if fitters:     # 'median' without reference rows, 'irs2' without interleaving
            try:
                applied_scheme(p.scene.detector, refpix)
            except ParameterError as exc:
                at = f" (grid point {p.index})" if p.label else ""
                raise ParameterError(f"{refpix_from}{at}: {exc}") from exc
        if fitters and not p.scene.output.fit:      # the scene's own check (a fit)
            try:
                p.scene.replace(output=dataclasses.replace(p.scene.output, fit="gls"))
            except ParameterError as exc:
                at = f" (grid point {p.index})" if p.label else ""
                raise ParameterError(f"'fit' {list(fitters)}{at}: {exc}") from exc
        if fitters and p.scene.readout.build().ngroups < 2:
            raise ParameterError(
                f"'fit' {list(fitters)}: a one-group exposure (ngroups = 1"
                f"{', grid point ' + str(p.index) if p.label else ''}) has no slope to fit")
    return BatchPlan(source=source, scene_path=scene_path, points=points, realisations=n,
                     batch_seed=batch_seed, seed_source=source_of_seed, fitters=fitters,
                     compare=compare, ramp=ramp, refpix=refpix, out_dir=out_dir)


def identity_digest(identity):
    """sha256 of an identity (:meth:`BatchPlan.identity`), canonical JSON."""
    return hashlib.sha256(json.dumps(identity, sort_keys=True).encode()).hexdigest()
