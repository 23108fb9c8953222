"""Every numeric scene key against hostile values, case by class.

The keys are enumerated from the schema (the dataclass fields of
:mod:`scenesim.scene.schema`, :class:`noise.clock.Detector`, ``Subarray`` and
:class:`noise.params.NoiseParams`, and the schema's tables of PSF kinds, light-curve
kinds and readout forms), not listed by hand, so a key added to the schema is
covered; :func:`test_every_key_is_classified` fails for a key that is neither numeric,
a list of numbers, a boolean nor a known string key.  Each key is set, in a small valid
scene that uses it (the readout form, PSF kind and light-curve kind it belongs to),
to one value of each class of :data:`VALUES`; list keys (``cosmic_ray_charge``,
``ipc_kernel``, ``ma_table``, a light curve's ``time``, ...) also get each class in
one of their entries.  Then

* :func:`parse_scene` either accepts the value (0 where 0 is allowed, a negative
  position or bias, ...) or raises ``ParameterError``/``FileFormatError`` with a
  one-line message naming the key and its table -- never another exception, and no
  warning (warnings are errors in this suite);
* an accepted scene goes through :func:`scenesim.budget.check_budget` (the run's own
  size check) with no other exception; the ``huge`` and ``zero`` values it accepts
  are run end to end (16 x 16 pixels) and must not fail except with the project's
  error;
* through the command, one subprocess per class (a refused key of that class, chosen
  in turn from the list): ``python -m scenesim.cli run bad.toml -o out.fits`` exits 2
  with exactly one stderr line naming the key, no ``Traceback``, no file created.

Before issue 12, e.g. ``dt = 1e300`` or ``[sources] dark_current = 1e300`` reached
numpy's Poisson sampler ("lam value too large"), ``pixel_pitch = 1e300`` raised
OverflowError, ``f_min = 1e300`` warned "invalid value in sqrt", ``c_pink = 1e300``
overflowed to inf with only a RuntimeWarning, ``[readout] ngroups = 10**18`` hung the
parser, ``cosmic_ray_charge = [1000, 50]`` named the internal ``'charge_mean'``,
``[sources.psf] radius = 1e300`` overflowed, a transit at ``t0 = 1e300`` failed at run
time naming ``'time'``, and subarray keys were named ``'subarray.nx'``.
"""

import copy
import dataclasses
import math
import os
import re
import subprocess
import sys
import time
import warnings

import numpy as np
import pytest
from astropy.io import fits

from noise.clock import Detector, Interleave, Subarray
from noise.errors import FileFormatError, ParameterError, ScenesimError, ScenesimWarning
from noise.params import NoiseParams
from scenesim.budget import check_budget
from scenesim.engine import EngineOptions
from scenesim.run import run_scene
from scenesim.scene import (EffectsConfig, LightCurveConfig, OutputConfig, PSFConfig,
                            ReadoutConfig, Scene, SourcesConfig, StarConfig, parse_scene)
from scenesim.scene.schema import (LIGHT_CURVE_OPTIONAL, LIGHT_CURVE_REQUIRED, PSF_KEYS,
                                   READOUT_FORMS)

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))

#: One value of each class.
VALUES = {
    "negative": -1,
    "negative_float": -1.5,
    "zero": 0,
    "nan": math.nan,
    "inf": math.inf,
    "huge": 1e300,
    "huge_int": 2 ** 62,
    "string": "abc",
    "bool": True,
    "list": [1.0],
    "table": {"a": 1},
}
#: Classes whose accepted values are also run end to end.
RUN_CLASSES = ("huge", "huge_int", "zero")

#: The light-curve entries of the base scene, one per analytic or table kind.
CURVES = {"transit": "tr", "step": "st", "flare": "fl", "table": "tb"}

# Which table each schema class fills (the scene's table path of its keys).
TABLES = [
    (Scene, ()),
    (Detector, ("detector",)),
    (Subarray, ("detector", "subarray")),
    (Interleave, ("detector", "interleave")),
    (NoiseParams, ("noise",)),
    (ReadoutConfig, ("readout",)),
    (SourcesConfig, ("sources",)),
    (PSFConfig, ("sources", "psf")),
    (StarConfig, ("sources", "stars", 0)),
    (EffectsConfig, ("effects",)),
    (OutputConfig, ("output",)),
]
#: String keys (a value of another type is a wrong type, covered by the string class
#: of the numeric keys' tests and by tests/scene).
STRING_KEYS = {"name", "description", "path", "kind", "pattern", "reset", "file",
               "catalogue", "light_curve", "pca0_file", "fit", "refpix", "preset"}
#: Fields that are not scene keys (nested tables, or set by the loader).
#: ([instrument] holds string keys only, checked against JWST's lists in
#: tests/pipelines/test_reffiles.py::test_instrument_defaults_and_checks.)
NOT_KEYS = {"detector", "noise", "readout", "sources", "effects", "output", "subarray",
            "psf", "stars", "light_curves", "path", "instrument", "interleave"}


def _type(field):
    return str(field.type)


def _is_numeric(field):
    t = _type(field)
    return ("float" in t or "int" in t) and "bool" not in t


def _is_list(field):
    t = _type(field)
    return "tuple" in t and not _is_numeric(field)


def _base(context=""):
    """A small valid scene (as parse_scene takes it) that uses every table, with the
    readout form / PSF kind / IPC form of ``context``."""
    m = {
        "seed": 1,
        "detector": {"naxis1": 32, "naxis2": 32, "ref_border": 2,
                     "subarray": {"kind": "window", "x0": 0, "y0": 0, "nx": 16,
                                  "ny": 16}},
        "noise": {"preset": "nirspec", "rd_noise": [5.0],
                  "pink_spectrum": [[1.0, 1.0], [100.0, 0.01]]},
        "readout": {"pattern": "RAPID", "ngroups": 2, "nints": 1},
        "sources": {"dark_current": 0.1, "background": 0.5, "hot_pixel_fraction": 0.01,
                    "hot_pixel_rate": [1.0, 10.0],
                    "psf": {"kind": "gaussian", "fwhm": 2.0, "min_rate": 0.0},
                    "stars": [{"x": 8.0, "y": 8.0, "flux": 100.0, "light_curve": "tr"}],
                    "light_curves": {
                        "tr": {"kind": "transit", "t0": 0.05, "duration": 0.04,
                               "depth": 0.1, "ingress": 0.01},
                        "st": {"kind": "step", "t_on": 0.05, "before": 1.0, "after": 2.0},
                        "fl": {"kind": "flare", "t0": 0.05, "amplitude": 1.0,
                               "rise": 0.01, "decay": 0.1},
                        "tb": {"kind": "table", "time": [0.0, 1.0], "flux": [1.0, 2.0]}}},
        "effects": {"cosmic_ray_rate": 5.0, "cosmic_ray_charge": [1000.0, 0.7],
                    "full_well": 1e5, "nonlinearity": [-1e-7], "ipc_alpha": 0.01,
                    "ipc_alpha_diag": 0.001, "flat": 1.0, "gain": 2.0, "adc_bits": 16},
        "output": {"path": "out.fits", "truth": True, "save_charge": False,
                   "save_noise": False, "ramp": True, "compare": False},
    }
    form, _, kind = context.partition(":")
    if form == "nframes":
        m["readout"] = {"nframes": 1, "ngroups": 2, "groupgap": 0, "nskip": 0}
    elif form == "ma_table":
        m["readout"] = {"ma_table": [[0, 1], [1, 2]]}
    elif form == "resultants":
        m["readout"] = {"resultants": [[0], [1, 2]]}
    elif form == "psf":
        m["sources"]["psf"] = {"kind": kind, **{
            "gaussian": {"fwhm": 2.0}, "airy": {"radius": 2.0},
            "image": {"file": "psf.fits", "oversample": 1, "normalize": True}}[kind]}
    elif form == "interleave":
        # IRS2-style interleaved reference samples: 8 columns per output, 2 excursions
        m["detector"] = {"naxis1": 32, "naxis2": 32, "ref_border": 2,
                         "interleave": {"normal": 4, "reference": 2, "jump": 1}}
        m["noise"]["rd_noise"] = [5.0] * 4               # 4 outputs, no window
    elif form == "ipc_kernel":
        del m["effects"]["ipc_alpha"], m["effects"]["ipc_alpha_diag"]
        m["effects"]["ipc_kernel"] = [[0.0, 0.01, 0.0], [0.01, 0.96, 0.01],
                                      [0.0, 0.01, 0.0]]
    return m


def _context(table, key):
    if table == ("readout",):
        if key in READOUT_FORMS:
            return key
        if key in ("groupgap", "nskip"):            # the 'nframes' form's options
            return "nframes"
    if table == ("sources", "psf"):
        kind = next(k for k, keys in PSF_KEYS.items() if key in keys) \
            if any(key in keys for keys in PSF_KEYS.values()) else "gaussian"
        return f"psf:{kind}"
    if key == "ipc_kernel":
        return "ipc_kernel"
    if table == ("detector", "interleave"):
        return "interleave"
    return ""


def _curve_tables():
    """``(table, key)`` of every light-curve key, per kind of the base scene."""
    for kind, name in CURVES.items():
        for key in LIGHT_CURVE_REQUIRED[kind] + LIGHT_CURVE_OPTIONAL[kind]:
            yield ("sources", "light_curves", name), key


def _leaves(value, path=()):
    """Index paths of the numbers inside a nested list."""
    if isinstance(value, list):
        for i, v in enumerate(value):
            yield from _leaves(v, path + (i,))
    else:
        yield path


def _keys():
    """``(table, key, entry, context)`` of every numeric key, and of one or two
    entries of every list key (``entry``: an index path, ``()`` for the whole key)."""
    out = []
    fields = [(t, f) for cls, t in TABLES for f in dataclasses.fields(cls)]
    fields += [(t, next(f for f in dataclasses.fields(LightCurveConfig) if f.name == key))
               for t, key in _curve_tables()]
    for table, f in fields:
        if f.name in NOT_KEYS and table != ("sources", "light_curves", "tb"):
            continue
        ctx = _context(table, f.name)
        if _is_numeric(f):
            out.append((table, f.name, (), ctx))
        if _is_numeric(f) or _is_list(f):
            base = _get(_base(ctx), table).get(f.name)
            if isinstance(base, list):
                leaves = list(_leaves(base))
                for entry in dict.fromkeys([leaves[0], leaves[-1]]):
                    out.append((table, f.name, entry, ctx))
    return out


def _get(m, table):
    for p in table:
        m = m[p]
    return m


def _with(table, key, entry, ctx, value):
    m = _base(ctx)
    t = _get(m, table)
    if entry:
        target = t[key]
        for i in entry[:-1]:
            target = target[i]
        target[entry[-1]] = value
    else:
        t[key] = value
    return m


def _where(table):
    """The table as messages name it."""
    if not table:
        return ""
    if table[:2] == ("sources", "stars"):
        return "[[sources.stars]]"
    if table == ("detector", "interleave"):
        return "[detector]"                  # [detector] 'interleave.normal' ...
    return "[" + ".".join(table) + "]"


def _label(table, key, entry):
    return ".".join(map(str, table + (key,))) + "".join(f"[{i}]" for i in entry)


KEYS = _keys()
CASES = [pytest.param(t, k, e, c, cls, id=f"{_label(t, k, e)}-{cls}")
         for t, k, e, c in KEYS for cls in VALUES]


@pytest.fixture(scope="module")
def scene_dir(tmp_path_factory):
    """The base scene's directory: an image PSF for the 'image' kind."""
    d = tmp_path_factory.mktemp("scene_keys")
    yy, xx = np.mgrid[-4:5, -4:5]
    psf = np.exp(-(xx ** 2 + yy ** 2) / 4.0)
    fits.writeto(d / "psf.fits", psf / psf.sum())
    return d


def _parse(m, scene_dir):
    return parse_scene(m, base_dir=scene_dir)


def test_every_key_is_classified():
    """A new scene key must be numeric, a list of numbers, a boolean or a known string
    key, so this suite (or tests/scene) covers it."""
    fields = [f for cls, _ in TABLES for f in dataclasses.fields(cls)]
    fields += list(dataclasses.fields(LightCurveConfig))
    odd = [f.name for f in fields
           if not (_is_numeric(f) or _is_list(f) or "bool" in _type(f)
                   or f.name in STRING_KEYS or f.name in NOT_KEYS)]
    assert not odd, odd


def test_the_base_scenes_are_valid(scene_dir):
    for ctx in {c for *_, c in KEYS}:
        _parse(_base(ctx), scene_dir)


def test_the_enumeration_reaches_every_table():
    tables = {t for t, *_ in KEYS}
    assert {(), ("detector",), ("detector", "subarray"), ("noise",), ("readout",),
            ("sources",), ("sources", "psf"), ("sources", "stars", 0), ("effects",),
            ("sources", "light_curves", "tb")} <= tables
    assert len(KEYS) >= 70, len(KEYS)


@pytest.mark.parametrize("table, key, entry, ctx, cls", CASES)
def test_parse_accepts_or_names_the_key(table, key, entry, ctx, cls, scene_dir):
    m = _with(table, key, entry, ctx, copy.deepcopy(VALUES[cls]))
    try:
        scene = _parse(m, scene_dir)
    except (ParameterError, FileFormatError) as exc:
        msg = str(exc)
        assert "\n" not in msg, msg
        assert re.search(rf"\b{re.escape(key)}\b", msg), msg
        assert _where(table) in msg, msg
        return
    # accepted: the run's size check works on it (refusing it is fine)
    try:
        check_budget(scene)
    except ParameterError as exc:
        assert "--force" in str(exc)


@pytest.mark.parametrize("table, key, entry, ctx, cls",
                         [c for c in CASES if c.values[-1] in RUN_CLASSES])
def test_accepted_huge_and_zero_values_run(table, key, entry, ctx, cls, scene_dir,
                                           tmp_path):
    """What the parser and the size check accept runs (16 x 16 pixels), or fails with
    the project's error -- never a numpy error, an overflow or a warning other than
    the project's own (a star a huge distance off the array is named in a
    SceneWarning)."""
    m = _with(table, key, entry, ctx, copy.deepcopy(VALUES[cls]))
    try:
        scene = _parse(m, scene_dir)
        check_budget(scene)
    except ScenesimError:
        return
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        try:
            run_scene(scene, output=str(tmp_path / "out.fits"), progress=False,
                      options=EngineOptions(threads=1))
        except ScenesimError as exc:
            assert "\n" not in str(exc)
    for w in caught:
        assert issubclass(w.category, ScenesimWarning), w
        assert "\n" not in str(w.message)


# ---------------------------------------------------------------- the command
def _toml(value):
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, (int, float)):
        if isinstance(value, float) and math.isnan(value):
            return "nan"
        if isinstance(value, float) and math.isinf(value):
            return "inf" if value > 0 else "-inf"
        return repr(value)
    if isinstance(value, str):
        return '"' + value.replace("\\", "\\\\").replace('"', '\\"') + '"'
    if isinstance(value, list):
        return "[" + ", ".join(_toml(v) for v in value) + "]"
    if isinstance(value, dict):
        return "{" + ", ".join(f"{k} = {_toml(v)}" for k, v in value.items()) + "}"
    raise TypeError(value)


def _toml_text(m):
    lines = [f"{k} = {_toml(v)}" for k, v in m.items() if not isinstance(v, dict)]
    for k, v in m.items():
        if isinstance(v, dict):
            lines.append(f"[{k}]")
            lines += [f"{kk} = {_toml(vv)}" for kk, vv in v.items()]
    return "\n".join(lines) + "\n"


def _refused_case(cls, scene_dir):
    """A key whose value of class ``cls`` the parser refuses, chosen in turn."""
    start = list(VALUES).index(cls) * 7
    order = KEYS[start % len(KEYS):] + KEYS[:start % len(KEYS)]
    for table, key, entry, ctx in order:
        if ctx.startswith("psf:image"):
            continue                 # the command's scene directory has no PSF file
        m = _with(table, key, entry, ctx, copy.deepcopy(VALUES[cls]))
        try:
            _parse(m, scene_dir)
        except ScenesimError:
            return table, key, m
    raise AssertionError(f"no key refuses a {cls} value")


@pytest.mark.parametrize("cls", list(VALUES))
def test_command_refuses_a_bad_key_in_one_line(cls, scene_dir, tmp_path):
    table, key, m = _refused_case(cls, scene_dir)
    (tmp_path / "bad.toml").write_text(_toml_text(m))
    before = sorted(os.listdir(tmp_path))
    res = subprocess.run([sys.executable, "-m", "scenesim.cli", "run", "bad.toml", "-o",
                          "out.fits", "-q"], cwd=tmp_path, capture_output=True,
                         text=True, timeout=120,
                         env={**os.environ, "PYTHONPATH": ROOT})
    lines = res.stderr.strip().splitlines()
    assert res.returncode == 2, res.stderr
    assert len(lines) == 1, res.stderr
    assert "Traceback" not in res.stderr
    assert re.search(rf"\b{re.escape(key)}\b", lines[0]), lines[0]
    assert sorted(os.listdir(tmp_path)) == before


# -------------------------------------------------- issue 12, one test per defect
def _small(**tables):
    m = {"seed": 1, "detector": {"naxis1": 16, "naxis2": 16, "ref_border": 2},
         "readout": {"pattern": "RAPID", "ngroups": 2}}
    for name, values in tables.items():
        m.setdefault(name, {}).update(values)
    return m


def test_noise_that_clips_every_pixel_is_refused():
    # before: c_pink = 1e300 was accepted; the run overflowed to inf with only a
    # RuntimeWarning ("overflow encountered in cast") and wrote a clipped exposure
    with pytest.raises(ParameterError, match=r"^\[noise\] 'c_pink' = 1e\+300 e- .*"
                                             r"<= 1e\+30 e-"):
        parse_scene(_small(noise={"c_pink": 1e300}))
    # the noise's rms spread s must fit 10 times in the ADC range (gain 1 e-/DN x
    # 65535 DN) less the bias pattern's span: on this 16 x 16 array the synthetic
    # template spans -0.695 to 3.763 (noise.template_for), 500 e- of it 2229.2 e-, so
    # s <= (65535 - 2229.2) / 10 = 6330.58 e-
    with pytest.raises(ParameterError, match=r"\[noise\] 'c_pink' = 10000000.0 e- is too "
                                             r"large for the ADC.*s <= 6330\.58 e-"):
        parse_scene(_small(noise={"c_pink": 1e7}))
    # c_pink = 3000 e- within a 4.9 ms frame wanders 1.9 x that over the process
    # (noise.realised_psd): s = sqrt(5699^2 + ~30^2) = 5699 e- fits, with the bias at
    # mid-range (32767.5 - 348 and 65535 - 32767.5 - 1882 both >= 5 s = 28495)
    parse_scene(_small(noise={"c_pink": 3000.0, "bias_offset": 32767.5}))
    # a 4-bit ADC (15 DN x 2 e-/DN = 30 e-) cannot hold the paper's 500 e- of bias
    # structure (its largest amplitude), whose pattern alone spans 2229 e- here
    with pytest.raises(ParameterError, match=r"'bias_amp' = 500\.0 e- is too large .*"
                                             r"'adc_bits' 4.*pattern alone spans"):
        parse_scene(_small(effects={"gain": 2.0, "adc_bits": 4}))
    # only RTN pixels see rtn_amp, but their high state clips as surely (before: it
    # was accepted, and those pixels sat at the top code); without RTN pixels, fine
    with pytest.raises(ParameterError, match=r"\[noise\] 'rtn_amp' = 1e\+20 e- puts "
                                             r"the high state of the RTN pixels"):
        parse_scene(_small(noise={"rtn_amp": 1e20, "rtn_fraction": 0.01}))
    parse_scene(_small(noise={"rtn_amp": 1e20, "rtn_fraction": 0.0}))
    with pytest.raises(ParameterError, match=r"'bias_offset' = -100000000\.0 e- puts 100 % "
                                             r"of the reads .* below code 0"):
        parse_scene(_small(noise={"bias_offset": -1e8}))
    # the reference pixels' white noise names both keys
    with pytest.raises(ParameterError, match=r"'ref_ratio' x 'rd_noise' = .* too large"):
        parse_scene(_small(noise={"ref_ratio": 1e6}))


def test_f_min_beyond_nyquist_is_refused():
    # before: f_min = 1e300 was accepted; the run warned "invalid value in sqrt"
    with pytest.raises(ParameterError, match=r"\[noise\] 'f_min' = 1e\+300 Hz must be "
                                             r"below the Nyquist frequency .*\[detector\] "
                                             r"'dt'"):
        parse_scene(_small(noise={"f_min": 1e300}))


def test_too_wide_cosmic_ray_charge_names_the_scene_key():
    # before: "'charge_mean' must be finite, got np.float64(inf)" at run time, after
    # overflow warnings, with no scene key
    with pytest.raises(ParameterError) as info:
        parse_scene(_small(effects={"cosmic_ray_charge": [1000.0, 50.0]}))
    msg = str(info.value)
    assert msg.startswith("[effects] 'cosmic_ray_charge' = [1000.0, 50.0]")
    assert "charge_mean" not in msg and "sigma_ln <= 7.72" in msg


def test_rates_beyond_the_engine_are_refused_with_their_key():
    # before: numpy's "lam value too large" (or the engine's 'lam') at run time
    for table, key, extra in (("sources", "dark_current", {}),
                              ("sources", "background", {}),
                              ("effects", "flat", {"sources": {"background": 1.0}})):
        m = _small(**{table: {key: 1e300}}, **extra)
        with pytest.raises(ParameterError, match=rf"'{key}'.* at most 9\.01e\+15 e-"):
            parse_scene(m)


def test_huge_readouts_are_refused_without_building_them():
    # before: ngroups = 10**18 hung the parser while it built the read lists
    for readout, key in (({"pattern": "RAPID", "ngroups": 10 ** 18}, "ngroups"),
                         ({"ma_table": [[10 ** 18, 1]]}, "ma_table"),
                         ({"resultants": [[0], [10 ** 18]]}, "resultants")):
        m = _small()
        m["readout"] = readout
        t0 = time.perf_counter()
        with pytest.raises(ParameterError, match=rf"\[readout\] '{key}'"):
            parse_scene(m)
        assert time.perf_counter() - t0 < 0.5


def test_a_light_curve_that_cannot_be_represented_names_its_keys():
    # before: accepted; the run failed naming the internal 'time'
    m = _small(sources={"light_curves": {"tr": {"kind": "transit", "t0": 1e300,
                                                "duration": 1.0, "depth": 0.1}}})
    with pytest.raises(ParameterError, match=r"\[sources\.light_curves\.tr\] light curve "
                                             r"'tr' \('t0' = 1e\+300"):
        parse_scene(m)


def test_psf_size_limits():
    # before: radius = 1e300 overflowed ("overflow encountered in square") at run time
    for kind, key in (("airy", "radius"), ("gaussian", "fwhm")):
        with pytest.raises(ParameterError, match=rf"\[sources\.psf\] '{key}' must be <= "):
            parse_scene(_small(sources={"psf": {"kind": kind, key: 1e300}}))
    with pytest.raises(ParameterError, match=r"'radius' must be >= 0\.1 pixels"):
        parse_scene(_small(sources={"psf": {"kind": "airy", "radius": 0.01}}))


def _bad_fits(directory):
    """A bad file of each kind: empty, not FITS, truncated, a cube (no 2-D image)."""
    (directory / "empty.fits").write_bytes(b"")
    (directory / "text.fits").write_text("hello\n")
    fits.writeto(directory / "whole.fits", np.full((50, 50), 1 / 2500.0))
    (directory / "truncated.fits").write_bytes((directory / "whole.fits").read_bytes()[:4000])
    fits.writeto(directory / "cube.fits", np.full((2, 5, 5), 0.02))
    fits.writeto(directory / "negative.fits", -np.ones((5, 5)))
    return ("empty", "text", "truncated", "cube", "negative")


def test_psf_and_map_file_errors_name_the_file(tmp_path):
    # before: a bad PSF image's values were reported without the file, and a
    # truncated file printed astropy's WARNING line besides the error
    for name in _bad_fits(tmp_path):
        path = str(tmp_path / f"{name}.fits")
        with pytest.raises((ParameterError, FileFormatError)) as info:
            parse_scene(_small(sources={"psf": {"kind": "image", "file": path}}),
                        base_dir=tmp_path)
        msg = str(info.value)
        assert msg.startswith("[sources.psf] 'file'") and path in msg, msg
        assert "\n" not in msg
        if name == "negative":
            continue
        with pytest.raises(FileFormatError) as info:
            parse_scene(_small(sources={"dark_current": path}), base_dir=tmp_path)
        assert "'dark_current'" in str(info.value) and path in str(info.value)


#: Scene strings written into FITS headers or tables (labels): ``(table, key,
#: context)``.  The light-curve names are the keys of [sources.light_curves].
LABEL_KEYS = [
    (("detector",), "name", ""),
    (("detector", "subarray"), "name", ""),
    (("readout",), "name", "resultants"),
    (("sources", "stars", 0), "light_curve", ""),
    (("instrument",), "detector", ""),
    (("instrument",), "exp_type", ""),
    (("instrument",), "subarray", ""),
]


@pytest.mark.parametrize("value", ["é", "SCA\n01", "tab\there", "\x7f"])
@pytest.mark.parametrize("table, key, ctx", LABEL_KEYS + [
    (("sources", "light_curves"), None, "")])
def test_labels_are_printable_ascii(table, key, ctx, value, scene_dir):
    """A label that FITS cannot hold (before, it passed the parser and failed with a
    traceback while the files were written, for a light curve after the whole run) is
    refused by the parser, naming the key."""
    m = _base(ctx)
    if key is None:                                  # a light curve named ``value``
        curves = m["sources"]["light_curves"]
        curves[value] = curves.pop("tr")
        m["sources"]["stars"][0]["light_curve"] = value
    else:
        m.setdefault(table[0], {})
        _get(m, table)[key] = value
    with pytest.raises(ParameterError, match="printable ASCII") as err:
        _parse(m, scene_dir)
    assert "\n" not in str(err.value).replace(repr(value), "")
    assert key is None or repr(key) in str(err.value)


@pytest.mark.parametrize("table, key, ctx", LABEL_KEYS)
def test_printable_labels_are_accepted(table, key, ctx, scene_dir):
    m = _base(ctx)
    if key == "light_curve":
        m["sources"]["light_curves"]["SN 2026-ab (R)"] = m["sources"]["light_curves"]["tr"]
    value = {"exp_type": "NRS_DARK", "detector": "NRS1", "subarray": "SUB2048"}.get(
        key, "SN 2026-ab (R)")
    m.setdefault(table[0], {})
    _get(m, table)[key] = value
    _parse(m, scene_dir)


@pytest.mark.parametrize("readout, key", [
    ({"ma_table": [[0, 2], [1, 2]]}, "'ma_table'"),
    ({"ma_table": [[0, 0]]}, "'ma_table'"),
    ({"resultants": [[1], [0]]}, "'resultants'"),
    ({"resultants": [[0, 0]]}, "'resultants'"),
])
def test_readout_errors_name_the_scene_keys(readout, key, scene_dir):
    # not the library's argument names ('table', 'read_lists')
    m = _base()
    m["readout"] = readout
    with pytest.raises(ParameterError) as err:
        _parse(m, scene_dir)
    msg = str(err.value)
    assert key in msg and "'table'" not in msg and "'read_lists'" not in msg, msg


def test_numbers_in_messages_are_shown_as_written():
    # a numpy scalar is shown as the number, not as np.float64(-0.5)
    from noise.validate import check_float, check_int
    for check, value in ((check_float, np.float64(-0.5)), (check_int, np.int64(-3)),
                         (check_float, np.float32(np.inf))):
        with pytest.raises(ParameterError) as err:
            check(name="x", value=value, minimum=0)
        assert "np." not in str(err.value), str(err.value)


@pytest.mark.parametrize("times", [[-1e308, 1e308], [0.0, 2e12], [-2e12, 0.0]])
def test_light_curve_times_beyond_the_bound_are_refused(times, scene_dir):
    """Node times far from the exposure (before: [-1e308, 1e308] overflowed in the
    charge integrals, warned, and failed at run time naming an internal 'lam')."""
    from scenesim.sky.lightcurve import MAX_TIME, LightCurve
    m = _base()
    m["sources"]["light_curves"]["tb"]["time"] = times
    with pytest.raises(ParameterError, match=r"\[sources\.light_curves\.tb\].*'time' must "
                                             r"lie within \+-1e\+12 s"):
        _parse(m, scene_dir)
    with pytest.raises(ParameterError, match=r"'time' must lie within"):
        LightCurve(times, [1.0, 1.0])
    LightCurve([-MAX_TIME, MAX_TIME], [1.0, 1.0])


def test_list_keys_name_the_element_and_refuse_booleans():
    """cosmic_ray_charge = [1000, -0.5] said "'cosmic_ray_charge' must be >= 0"
    without saying which element; a boolean ipc_kernel was taken as weights (found by
    a hostile probe)."""
    with pytest.raises(ParameterError, match=r"\[effects\] 'cosmic_ray_charge\[1\] "
                                             r"\(sigma_ln\)' must be >= 0, got -0\.5"):
        parse_scene(_small(effects={"cosmic_ray_charge": [1000.0, -0.5]}))
    kernel = [[False, False, False], [False, True, False], [False, False, False]]
    with pytest.raises(ParameterError, match=r"'ipc_kernel' must be a 3x3 array of "
                                             r"numbers"):
        parse_scene(_small(effects={"ipc_kernel": kernel}))
