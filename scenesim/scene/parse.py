"""Scene files in: TOML (or a mapping) parsed and validated into a :class:`Scene`.

:func:`load_scene` reads a file with the standard library (:mod:`tomllib`; ``tomli``
on Python 3.10); :func:`parse_scene` takes the mapping.  Both reject unknown keys
with the nearest valid name and the table path, resolve relative file paths against
the scene's directory, build the dataclasses of :mod:`scenesim.scene.schema` (which
check the values), then :func:`check_files` opens every file the scene names, once,
and the readout is built, so an unknown pattern name or a bad MA table fails at load
time.
"""

import dataclasses
import os
from contextlib import contextmanager

try:
    import tomllib
except ModuleNotFoundError:  # Python 3.10
    import tomli as tomllib

from noise.clock import Detector, Subarray, preset as detector_preset
from noise.errors import FileFormatError, ParameterError, ParameterTypeError
from noise.params import NIRSPEC_DEFAULTS, ZERO_NOISE, NoiseParams
from noise.validate import (check_bool, check_choice, check_existing_file, check_int,
                            check_path, check_str, describe, is_real, suggest)

from scenesim.scene.schema import (LIGHT_CURVE_OPTIONAL, LIGHT_CURVE_REQUIRED, curve_table,
                                   PSF_COMMON_KEYS, PSF_KEYS, READOUT_FORMS,
                                   check_nonlinearity_range,
                                   EffectsConfig, LightCurveConfig, OutputConfig,
                                   PSFConfig, ReadoutConfig, Scene, SourcesConfig,
                                   StarConfig)
from scenesim.pipelines.instrument import InstrumentConfig
from scenesim.sky.maps import FITS_EXTENSIONS, check_map_file, load_map

__all__ = ["NOISE_PRESETS", "parse_scene", "load_scene", "check_files"]

#: Noise presets selectable with ``[noise] preset``.
NOISE_PRESETS = {"nirspec": NIRSPEC_DEFAULTS, "none": ZERO_NOISE}


# ============================================================================ helpers
def _check_keys(table, allowed, where, *, elsewhere=()):
    """Reject keys of ``table`` not in ``allowed``, suggesting the nearest valid name.

    ``elsewhere`` are keys that exist in the same table for another ``kind``: they get a
    message saying they do not apply rather than "unknown".
    """
    for key in table:
        if key in allowed:
            continue
        if key in elsewhere:
            raise ParameterError(
                f"key {key!r} does not apply in {where}; allowed keys here: "
                f"{', '.join(sorted(allowed))}")
        hint = suggest(key, allowed)
        if not hint:
            hint = f"; allowed keys: {', '.join(sorted(allowed))}"
        raise ParameterError(f"unknown key {key!r} in {where}{hint}")


def _table(where, value):
    if not isinstance(value, dict):
        raise ParameterTypeError(f"{where} must be a table, got {describe(value)}")
    return value


@contextmanager
def _section(where):
    """Prefix the messages of ParameterError/FileFormatError raised inside with a table."""
    try:
        yield
    except (ParameterError, FileFormatError) as exc:
        raise type(exc)(f"{where} {exc}") from exc


def _resolve(base_dir, value):
    """Resolve a path string relative to ``base_dir``; other values pass through."""
    if isinstance(value, str):
        return os.path.abspath(os.path.join(base_dir, os.path.expanduser(value)))
    return value


# ============================================================================ tables
_TOP_KEYS = ("seed", "description", "detector", "noise", "readout", "sources",
             "effects", "output", "instrument")
_INSTRUMENT_KEYS = tuple(f.name for f in dataclasses.fields(InstrumentConfig))
_DETECTOR_FIELDS = tuple(f.name for f in dataclasses.fields(Detector)
                         if f.name != "subarray")
_NOISE_FIELDS = tuple(f.name for f in dataclasses.fields(NoiseParams))
_READOUT_KEYS = ("pattern", "ngroups", "nframes", "groupgap", "nskip", "ma_table",
                 "resultants", "nints", "reset", "name")
_SOURCES_KEYS = ("dark_current", "hot_pixel_fraction", "hot_pixel_rate", "background",
                 "catalogue", "psf", "stars", "light_curves")
_EFFECTS_KEYS = tuple(f.name for f in dataclasses.fields(EffectsConfig))
_OUTPUT_KEYS = tuple(f.name for f in dataclasses.fields(OutputConfig))


def _parse_detector(tab):
    where = "[detector]"
    _check_keys(tab, ("preset",) + _DETECTOR_FIELDS + ("subarray",), where)
    with _section(where):
        name = check_str("preset", tab.get("preset", "H2RG"))
        if "name" in tab:
            check_str("name", tab["name"], label=True)
        if "reverse_scan" in tab:
            check_bool("reverse_scan", tab["reverse_scan"])
        changes = {k: tab[k] for k in _DETECTOR_FIELDS if k in tab}
        det = detector_preset(name, **changes)
    if "subarray" in tab:
        where = "[detector.subarray]"
        sub = _table(where, tab["subarray"])
        _check_keys(sub, ("kind", "x0", "y0", "nx", "ny", "name"), where)
        with _section(where):
            kind = check_choice("kind", sub.get("kind", "window"), ("window", "stripe"))
            for key in ("ny",) + (("nx",) if kind == "window" else ()):
                if key not in sub:
                    raise ParameterError(f"{key!r} is required for a {kind!r} subarray")
            x0 = check_int("x0", sub.get("x0", 0), minimum=0)
            y0 = check_int("y0", sub.get("y0", 0), minimum=0)
            nx = check_int("nx", sub.get("nx", det.naxis1 if kind == "stripe" else None),
                           minimum=1)
            ny = check_int("ny", sub["ny"], minimum=1)
            subarray = Subarray(kind, x0, y0, nx, ny, check_str("name", sub.get("name", ""), label=True))
            det = dataclasses.replace(det, subarray=subarray)
    return det


def _parse_noise(tab, base_dir):
    where = "[noise]"
    _check_keys(tab, ("preset",) + _NOISE_FIELDS, where)
    with _section(where):
        name = check_choice("preset", tab.get("preset", "nirspec"), tuple(NOISE_PRESETS),
                            ignore_case=True)   # as [detector] preset is
        changes = {k: tab[k] for k in _NOISE_FIELDS if k in tab}
        for key in ("rd_noise", "u_pink", "acn"):
            if isinstance(changes.get(key), list) and \
                    not all(is_real(v) for v in changes[key]):
                raise ParameterError(
                    f"{key!r} per-output values must be numbers, got {changes[key]!r}")
        if "pca0_file" in changes:
            changes["pca0_file"] = check_existing_file(
                "pca0_file",
                _resolve(base_dir, check_str("pca0_file", changes["pca0_file"])),
                FITS_EXTENSIONS)
        try:
            return NOISE_PRESETS[name].replace(**changes)
        except (TypeError, ValueError) as exc:
            if isinstance(exc, (ParameterError, FileFormatError)):
                raise
            raise ParameterError(f"invalid value: {exc}") from exc


def _parse_readout(tab):
    where = "[readout]"
    _check_keys(tab, _READOUT_KEYS, where)
    with _section(where):
        given = [f for f in READOUT_FORMS if f in tab]
        if len(given) != 1:
            raise ParameterError(
                f"needs exactly one of {', '.join(map(repr, READOUT_FORMS))}; got "
                f"{' and '.join(map(repr, given)) if given else 'none'}")
        for key in ("groupgap", "nskip"):
            if key in tab and given[0] != "nframes":
                raise ParameterError(
                    f"{key!r} applies only with 'nframes', not with {given[0]!r}")
        return ReadoutConfig(**{k: tab[k] for k in _READOUT_KEYS if k in tab})


def _parse_psf(tab, base_dir):
    where = "[sources.psf]"
    all_keys = set(PSF_COMMON_KEYS).union(*PSF_KEYS.values())
    _check_keys(tab, all_keys, where)
    with _section(where):
        kind = check_choice("kind", tab.get("kind", "gaussian"), tuple(PSF_KEYS))
    allowed = PSF_COMMON_KEYS + PSF_KEYS[kind]
    _check_keys(tab, allowed, f"{where} of kind {kind!r}", elsewhere=all_keys)
    values = dict(tab)
    if "file" in values:
        values["file"] = _resolve(base_dir, values["file"])
    with _section(where):
        return PSFConfig(**values)


def _parse_light_curves(tab, base_dir):
    curves = []
    all_keys = {"kind"}.union(*LIGHT_CURVE_REQUIRED.values(),
                              *LIGHT_CURVE_OPTIONAL.values())
    for name, spec in tab.items():
        where = curve_table(name)
        spec = _table(where, spec)
        _check_keys(spec, all_keys, where)
        with _section(where):
            if "kind" not in spec:
                raise ParameterError(f"'kind' is required (one of "
                                     f"{', '.join(map(repr, LIGHT_CURVE_REQUIRED))})")
            kind = check_choice("kind", spec["kind"], tuple(LIGHT_CURVE_REQUIRED))
        allowed = ("kind",) + LIGHT_CURVE_REQUIRED[kind] + LIGHT_CURVE_OPTIONAL[kind]
        _check_keys(spec, allowed, f"{where} of kind {kind!r}", elsewhere=all_keys)
        values = dict(spec)
        if "file" in values:
            values["file"] = _resolve(base_dir, values["file"])
        with _section(where):
            curves.append(LightCurveConfig(name=name, **values))
    return tuple(curves)


def _parse_stars(stars):
    if not isinstance(stars, list):
        raise ParameterError(
            f"[sources] 'stars' must be an array of tables ([[sources.stars]]), "
            f"got {stars!r}")
    parsed = []
    for i, star in enumerate(stars):
        where = f"[[sources.stars]] #{i}"
        star = _table(where, star)
        _check_keys(star, ("x", "y", "flux", "light_curve"), where)
        with _section(where):
            for key in ("x", "y", "flux"):
                if key not in star:
                    raise ParameterError(f"{key!r} is required")
            parsed.append(StarConfig(**star))
    return tuple(parsed)


def _parse_sources(tab, base_dir):
    where = "[sources]"
    _check_keys(tab, _SOURCES_KEYS, where)
    values = {k: tab[k] for k in ("dark_current", "hot_pixel_fraction", "hot_pixel_rate",
                                  "background", "catalogue") if k in tab}
    for key in ("dark_current", "background", "catalogue"):
        if key in values:
            values[key] = _resolve(base_dir, values[key])
    if "psf" in tab:
        values["psf"] = _parse_psf(_table("[sources.psf]", tab["psf"]), base_dir)
    if "light_curves" in tab:
        values["light_curves"] = _parse_light_curves(
            _table("[sources.light_curves]", tab["light_curves"]), base_dir)
    if "stars" in tab:
        values["stars"] = _parse_stars(tab["stars"])
    with _section(where):
        return SourcesConfig(**values)


def _parse_effects(tab, base_dir):
    where = "[effects]"
    _check_keys(tab, _EFFECTS_KEYS, where)
    with _section(where):
        if "ipc_kernel" in tab and ("ipc_alpha" in tab or "ipc_alpha_diag" in tab):
            raise ParameterError("give either 'ipc_alpha' (and 'ipc_alpha_diag') or "
                                 "'ipc_kernel', not both")
        values = dict(tab)
        for key in ("full_well", "flat"):
            if key in values:
                values[key] = _resolve(base_dir, values[key])
        return EffectsConfig(**values)


def _parse_instrument(tab):
    where = "[instrument]"
    _check_keys(tab, _INSTRUMENT_KEYS, where)
    with _section(where):
        return InstrumentConfig(**tab)


def _parse_output(tab):
    where = "[output]"
    _check_keys(tab, _OUTPUT_KEYS, where)
    with _section(where):
        return OutputConfig(**tab)


# ======================================================================== the scene
def check_files(scene):
    """Open every file ``scene`` names, once, and check its contents.

    :func:`load_scene` and :func:`parse_scene` call it; call it on a scene built or
    changed in memory to get the same checks before a run (the run's readers check
    the files again when they use them).

    * FITS maps (``[noise] pca0_file``, ``[sources] dark_current``, ``background``,
      ``[effects] full_well``, ``flat``): the shape, from the header, is the full
      array or the read-out image (values are checked when the run loads them);
    * the catalogue: its columns and values, and that every ``light_curve`` name is
      defined;
    * ``file`` light curves: read as the run reads them;
    * an ``image`` PSF: read and checked;
    * a nonlinearity with a full-well *map*: monotonic up to the map's largest value
      (the map is loaded, so its values are checked too).

    Raises
    ------
    FileFormatError, ParameterError
        Prefixed with the scene table, e.g. ``[sources] 'catalogue' ...``.
    """
    det = scene.detector
    if scene.noise.pca0_file is not None:
        with _section("[noise]"):
            check_map_file("pca0_file", scene.noise.pca0_file, det)
    src = scene.sources
    eff = scene.effects
    for where, files in (("[sources]", src.map_files), ("[effects]", eff.map_files)):
        with _section(where):
            for name, path in files.items():
                check_map_file(name, path, det)
    if src.catalogue is not None:
        with _section("[sources]"):
            src.star_table()
    for curve in src.light_curves:
        if curve.kind == "file":
            with _section(curve_table(curve.name)):
                curve.build()
    if src.psf.kind == "image":
        with _section("[sources.psf]"):
            src.psf.build()
    nl = eff.nonlinearity_model()
    if isinstance(eff.full_well, str) and not nl.is_linear:
        with _section("[effects]"):
            full_well = load_map(eff.full_well, det, name="full_well", allow_zero=False)
            check_nonlinearity_range(nl, float(full_well.max()))


def _parse(mapping, base_dir, path):
    top = _table("the scene", mapping)
    _check_keys(top, _TOP_KEYS, "the top level of the scene")
    base_dir = os.path.abspath(os.fspath(base_dir))
    sections = {}
    for key in ("detector", "noise", "readout", "sources", "effects", "output"):
        sections[key] = _table(f"[{key}]", top.get(key, {}))
    if "readout" not in top:
        raise ParameterError(
            f"the scene needs a [readout] table with one of "
            f"{', '.join(map(repr, READOUT_FORMS))}")
    scene = Scene(
        detector=_parse_detector(sections["detector"]),
        noise=_parse_noise(sections["noise"], base_dir),
        readout=_parse_readout(sections["readout"]),
        sources=_parse_sources(sections["sources"], base_dir),
        effects=_parse_effects(sections["effects"], base_dir),
        output=_parse_output(sections["output"]),
        instrument=_parse_instrument(_table("[instrument]", top.get("instrument", {}))),
        seed=top.get("seed"),
        description=top.get("description", ""),
        path=path,
    )
    with _section("[readout]"):
        scene.readout.build()
    check_files(scene)
    return scene


def parse_scene(mapping, *, base_dir="."):
    """Validate a scene given as a mapping (e.g. the result of ``tomllib.load``).

    Parameters
    ----------
    mapping : dict
        Tables and keys as in a scene file.
    base_dir : str or path-like, keyword-only
        Directory that relative file paths in the scene are resolved against.

    Returns
    -------
    Scene
        With ``path=None``.

    Raises
    ------
    ParameterError
        Unknown key (with the nearest valid name), bad type or value, inconsistent
        settings, or a readout that :mod:`scenesim.detector.readout` rejects.
    FileFormatError
        A file named by the scene is missing or has the wrong layout.
    """
    return _parse(mapping, check_path("base_dir", base_dir), None)


def load_scene(path):
    """Read and validate a TOML scene file.

    Parameters
    ----------
    path : str or path-like
        The scene file.  Relative paths inside it are resolved against its directory.

    Returns
    -------
    Scene
        With ``path`` the absolute path of the file.

    Raises
    ------
    FileFormatError
        The file is missing or not valid TOML, or a file it names is missing or
        malformed.
    ParameterError
        As :func:`parse_scene`.  Messages start with the scene file's path.
    """
    path = os.path.abspath(check_path("path", path))
    try:
        with open(path, "rb") as fh:
            mapping = tomllib.load(fh)
    except FileNotFoundError as exc:
        raise FileFormatError(f"scene file {path!r} does not exist") from exc
    except OSError as exc:
        raise FileFormatError(f"scene file {path!r} cannot be read: {exc}") from exc
    except tomllib.TOMLDecodeError as exc:
        raise FileFormatError(f"scene file {path!r} is not valid TOML: {exc}") from exc
    except UnicodeDecodeError as exc:         # TOML is UTF-8 (a Latin-1 editor's file)
        raise FileFormatError(f"scene file {path!r} is not valid TOML: byte "
                              f"{exc.start} is not UTF-8 text (TOML files are UTF-8)") \
            from exc
    try:
        return _parse(mapping, os.path.dirname(path), path)
    except (ParameterError, FileFormatError) as exc:
        raise type(exc)(f"{path}: {exc}") from exc
