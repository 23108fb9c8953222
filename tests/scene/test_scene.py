"""Tests of scenesim.scene: TOML scene files validated into frozen dataclasses."""

import dataclasses
import glob
import math
import os
import pickle
import textwrap

import numpy as np
import pytest
from astropy.io import fits
from astropy.table import Table

from noise.clock import Detector, Subarray
from noise.errors import FileFormatError, ParameterError
from noise.params import NIRSPEC_DEFAULTS, NoiseParams
from scenesim.scene import (EffectsConfig, LightCurveConfig, OutputConfig, PSFConfig,
                            ReadoutConfig, Scene, SourcesConfig, StarConfig, load_scene,
                            parse_scene)
from scenesim.sky.maps import load_map

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
SCENES_DIR = os.path.join(ROOT, "scenes")

RAPID = '[readout]\npattern = "RAPID"\nngroups = 3\n'


def write(directory, text, name="scene.toml"):
    path = directory / name
    path.write_text(textwrap.dedent(text))
    return path


def load_text(tmp_path, text):
    return load_scene(write(tmp_path, text))


# ------------------------------------------------------------------ full scene
FULL = """\
seed = 987654321
description = "every table and key"

[detector]
preset = "H2RG"
naxis1 = 64
naxis2 = 64
n_out = 4
nroh = 8
nfoh = 2
dt = 2e-5
ref_border = 4
reverse_scan = true
pixel_pitch = 15.0

[detector.subarray]
kind = "window"
x0 = 8
y0 = 4
nx = 16
ny = 12
name = "SUB16"

[noise]
preset = "none"
rd_noise = [6.0]
c_pink = 1.5
ktc = 20.0
bias_offset = 200.0      # >= 5 rms spreads (~21 e-) above code 0
pink_spectrum = [[1.0, 1.0], [100.0, 0.01]]
pca0_file = "data/full.fits"

[readout]
nframes = 2
ngroups = 3
groupgap = 1
nskip = 1
nints = 2
reset = "global"
name = "MYPATT"

[sources]
dark_current = "data/full.fits"
hot_pixel_fraction = 0.01
hot_pixel_rate = [2.0, 50.0]
background = "data/window.fits"
catalogue = "data/cat.ecsv"

[sources.psf]
kind = "image"
file = "data/psf.fits"
oversample = 2
normalize = true
min_rate = 0.01

[[sources.stars]]
x = 3.25
y = 4.5
flux = 1000.0
light_curve = "transit"

[[sources.stars]]
x = -2.0
y = 30
flux = 5

[sources.light_curves.transit]
kind = "transit"
t0 = 100.0
duration = 50.0
depth = 0.01
ingress = 5.0

[sources.light_curves.jump]
kind = "step"
t_on = 3.0
after = 2.0

[sources.light_curves.burst]
kind = "flare"
t0 = 10.0
amplitude = 4.0
rise = 0.5
decay = 3.0

[sources.light_curves.tab]
kind = "table"
time = [0.0, 1.0, 2.5]
flux = [1.0, 0.5, 1.0]

[sources.light_curves.fromfile]
kind = "file"
file = "data/lc.ecsv"

[effects]
cosmic_ray_rate = 4.5
cosmic_ray_charge = [2000.0, 0.5]
full_well = "data/window.fits"
nonlinearity = [-1e-6, -1e-12]
ipc_kernel = [[0.0, 0.01, 0.0], [0.01, 0.96, 0.01], [0.0, 0.01, 0.0]]
flat = "data/window.fits"
gain = 1.8
adc_bits = 14

[output]
path = "out/run.fits"
truth = true
save_charge = true
save_noise = true
ramp = false
fit = "ols"
refpix = "none"
compare = true
"""


@pytest.fixture
def full_scene_dir(tmp_path):
    data = tmp_path / "data"
    data.mkdir()
    full = np.arange(64 * 64, dtype=np.float64).reshape(64, 64) * 1e-4
    fits.writeto(data / "full.fits", full)
    window = np.full((12, 16), 2.0e4)
    window[0, 0] = 3.0e4
    # Window map in an extension, after an empty primary HDU.
    fits.HDUList([fits.PrimaryHDU(), fits.ImageHDU(window)]).writeto(data / "window.fits")
    yy, xx = np.mgrid[-4:5, -4:5]
    psf = np.exp(-(xx**2 + yy**2) / 4.0)
    fits.writeto(data / "psf.fits", psf / psf.sum())
    Table({"x": [1.0, 10.5], "y": [2.0, 11.25], "flux": [10.0, 0.0],
           "light_curve": ["jump", ""]}).write(data / "cat.ecsv", format="ascii.ecsv")
    Table({"time": [0.0, 5.0, 9.0], "flux": [1.0, 1.2, 1.0]}).write(
        data / "lc.ecsv", format="ascii.ecsv")
    write(tmp_path, FULL)
    return tmp_path


def test_full_scene_round_trips(full_scene_dir, tmp_path_factory, monkeypatch):
    # Relative paths resolve against the scene's directory, not the working one.
    monkeypatch.chdir(tmp_path_factory.mktemp("elsewhere"))
    scene = load_scene(full_scene_dir / "scene.toml")
    data = str(full_scene_dir / "data")

    assert scene.path == str(full_scene_dir / "scene.toml")
    assert scene.seed == 987654321 and scene.description == "every table and key"
    assert scene.detector == Detector(
        name="H2RG", naxis1=64, naxis2=64, n_out=4, nroh=8, nfoh=2, dt=2e-5,
        ref_border=4, reverse_scan=True, pixel_pitch=15.0,
        subarray=Subarray("window", 8, 4, 16, 12, "SUB16"))
    assert isinstance(scene.noise, NoiseParams)
    assert scene.noise.rd_noise == (6.0,) and scene.noise.c_pink == 1.5
    assert scene.noise.ktc == 20.0 and scene.noise.acn == 0.0      # preset "none"
    assert scene.noise.pink_spectrum == ((1.0, 1.0), (100.0, 0.01))
    assert scene.noise.pca0_file == os.path.join(data, "full.fits")

    assert scene.readout == ReadoutConfig(nframes=2, ngroups=3, groupgap=1, nskip=1,
                                          nints=2, reset="global", name="MYPATT")
    readout = scene.readout.build()
    # MULTIACCUM: group g uses reads nskip + g (nframes + groupgap) + (0 .. nframes-1).
    assert readout.resultants == ((1, 2), (4, 5), (7, 8))
    assert readout.nints == 2 and readout.reset_mode == "global"
    assert readout.name == "MYPATT"

    src = scene.sources
    assert isinstance(src, SourcesConfig)
    assert src.dark_current == os.path.join(data, "full.fits")
    assert src.background == os.path.join(data, "window.fits")
    assert src.catalogue == os.path.join(data, "cat.ecsv")
    assert src.hot_pixel_fraction == 0.01 and src.hot_pixel_rate == (2.0, 50.0)
    assert src.psf == PSFConfig(kind="image", file=os.path.join(data, "psf.fits"),
                                oversample=2, normalize=True, min_rate=0.01)
    assert src.stars == (StarConfig(3.25, 4.5, 1000.0, "transit"),
                         StarConfig(-2.0, 30.0, 5.0))
    assert [c.name for c in src.light_curves] == ["transit", "jump", "burst", "tab",
                                                   "fromfile"]
    assert src.light_curve("transit") == LightCurveConfig(
        name="transit", kind="transit", t0=100.0, duration=50.0, depth=0.01,
        ingress=5.0)
    assert src.light_curve("jump").before == 1.0          # default
    assert src.light_curve("burst").rise == 0.5
    assert src.light_curve("tab").time == (0.0, 1.0, 2.5)
    lc = src.light_curve("fromfile").build()
    np.testing.assert_array_equal(lc.time, [0.0, 5.0, 9.0])
    np.testing.assert_array_equal(lc.flux, [1.0, 1.2, 1.0])
    stars = src.star_table()
    np.testing.assert_array_equal(stars["x"], [3.25, -2.0, 1.0, 10.5])
    np.testing.assert_array_equal(stars["flux"], [1000.0, 5.0, 10.0, 0.0])
    assert list(stars["light_curve"]) == ["transit", "", "jump", ""]

    eff = scene.effects
    assert eff.cosmic_ray_rate == 4.5 and eff.cosmic_ray_charge == (2000.0, 0.5)
    assert eff.full_well == os.path.join(data, "window.fits")
    assert eff.nonlinearity == (-1e-6, -1e-12)
    np.testing.assert_allclose(eff.ipc(), [[0, 0.01, 0], [0.01, 0.96, 0.01],
                                           [0, 0.01, 0]], rtol=1e-15)
    assert eff.gain == 1.8 and eff.adc_bits == 14
    assert scene.output == OutputConfig(path="out/run.fits", truth=True,
                                        save_charge=True, save_noise=True, ramp=False,
                                        fit="ols", refpix="none", compare=True)
    assert scene.output.truth_path == "out/run_truth.fits"

    # Maps: a full-array map is cut to the window, a window map is used as is.
    det = scene.detector
    dark = load_map(src.dark_current, det, name="dark_current")
    full = np.arange(64 * 64, dtype=np.float64).reshape(64, 64) * 1e-4
    np.testing.assert_array_equal(dark, full[4:16, 8:24])
    fw = load_map(eff.full_well, det, name="full_well", allow_zero=False)
    assert fw.shape == (12, 16) and fw[0, 0] == 3.0e4 and fw[5, 5] == 2.0e4
    assert load_map(0.5, det, name="background") == 0.5

    # Frozen values: hashable, picklable, comparable; replace re-validates.
    assert pickle.loads(pickle.dumps(scene)) == scene
    assert isinstance(hash(scene), int)
    with pytest.raises(dataclasses.FrozenInstanceError):
        scene.seed = 1
    assert scene.replace(seed=5).seed == 5
    with pytest.raises(ParameterError, match="seed"):
        scene.replace(seed=-5)
    from scenesim.outputs import scene_id
    assert scene.to_header_cards() == [
        ("SCENE", "scene.toml", "scene file"),
        ("SCENEID", scene_id(scene), "scene content digest (not seed, outputs)"),
        ("SEED", 987654321, "master seed (numpy SeedSequence entropy)")]
    # the digest: not the seed, the path or the outputs; the physics, and the
    # contents (not the paths) of the files the scene reads
    assert scene_id(scene.replace(seed=1)) == scene_id(scene)
    assert len(scene_id(scene)) == 16


def test_minimal_scene_defaults(tmp_path):
    scene = load_text(tmp_path, RAPID)
    assert scene.detector == Detector()                  # H2RG full frame
    assert scene.noise == NIRSPEC_DEFAULTS
    assert scene.readout.form == "pattern" and scene.readout.nints == 1
    assert scene.sources == SourcesConfig() and scene.sources.star_table()["x"].size == 0
    assert scene.effects == EffectsConfig() and scene.effects.ipc() is None
    assert scene.effects.nonlinearity_model().is_linear
    assert scene.output == OutputConfig()
    assert scene.seed is None
    seeded = scene.ensure_seed()
    assert 0 <= seeded.seed < 2**63 and seeded.ensure_seed() is seeded


def test_parse_scene_resolves_against_base_dir(tmp_path):
    fits.writeto(tmp_path / "dark.fits", np.full((2048, 2048), 0.01, dtype=np.float32))
    mapping = {"readout": {"pattern": "RAPID", "ngroups": 2},
               "sources": {"dark_current": "dark.fits"}}
    scene = parse_scene(mapping, base_dir=tmp_path)
    assert scene.path is None
    assert scene.sources.dark_current == str(tmp_path / "dark.fits")
    with pytest.raises(FileFormatError, match="does not exist"):
        parse_scene(mapping, base_dir=tmp_path / "nowhere")


# ------------------------------------------------------------- misspelt keys
@pytest.mark.parametrize("text, where, suggestion", [
    ("sed = 1\n" + RAPID, "the top level of the scene", "seed"),
    (RAPID + "[sourcse]\n", "the top level of the scene", "sources"),
    (RAPID + "[sources]\nbackgroud = 0.5\n", r"\[sources\]", "background"),
    (RAPID + "[detector]\nnaxis11 = 64\n", r"\[detector\]", "naxis1"),
    (RAPID + "[detector.subarray]\nkind = 'window'\nnx = 8\nnyy = 8\n",
     r"\[detector.subarray\]", "ny"),
    (RAPID + "[noise]\nrd_nosie = 3.0\n", r"\[noise\]", "rd_noise"),
    ('[readout]\npattern = "RAPID"\nngroup = 3\n', r"\[readout\]", "ngroups"),
    (RAPID + "[sources.psf]\nfwmh = 2.0\n", r"\[sources.psf\]", "fwhm"),
    (RAPID + "[[sources.stars]]\nx = 1\ny = 2\nflx = 3\n", r"\[\[sources.stars\]\] #0",
     "flux"),
    (RAPID + "[sources.light_curves.t]\nkind = 'transit'\nt0 = 1\nduration = 2\n"
             "dpeth = 0.1\n", r"\[sources.light_curves.t\]", "depth"),
    (RAPID + "[effects]\nfull_wel = 1e5\n", r"\[effects\]", "full_well"),
    (RAPID + "[output]\ncomapre = true\n", r"\[output\]", "compare"),
])
def test_misspelt_keys_suggest_nearest_name(tmp_path, text, where, suggestion):
    with pytest.raises(ParameterError,
                       match=rf"unknown key '\w+' in {where}; did you mean "
                             rf"'{suggestion}'\?"):
        load_text(tmp_path, text)


def test_unknown_key_far_from_any_lists_allowed_keys(tmp_path):
    with pytest.raises(ParameterError,
                       match=r"unknown key 'zzz' in \[output\]; allowed keys: compare, "):
        load_text(tmp_path, RAPID + "[output]\nzzz = 1\n")


def test_key_of_another_kind_is_rejected(tmp_path):
    with pytest.raises(ParameterError,
                       match=r"'fwhm' does not apply in \[sources.psf\] of kind 'airy'"):
        load_text(tmp_path, RAPID + "[sources.psf]\nkind = 'airy'\nfwhm = 2.0\n")
    with pytest.raises(ParameterError,
                       match=r"'depth' does not apply in \[sources.light_curves.s\] "
                             r"of kind 'step'"):
        load_text(tmp_path, RAPID + "[sources.light_curves.s]\nkind = 'step'\n"
                                    "t_on = 1\nafter = 2\ndepth = 0.1\n")


def test_bad_choice_suggests(tmp_path):
    with pytest.raises(ParameterError, match=r"\[sources.psf\] 'kind' .* got 'gausian'; "
                                             r"did you mean 'gaussian'\?"):
        load_text(tmp_path, RAPID + "[sources.psf]\nkind = 'gausian'\n")
    with pytest.raises(ParameterError, match=r"did you mean 'H2RG'\?"):
        load_text(tmp_path, RAPID + "[detector]\npreset = 'H2GR'\n")


# ----------------------------------------------------------- values and ranges
@pytest.mark.parametrize("section, key, value", [
    ("sources", "dark_current", "-0.01"),
    ("sources", "dark_current", "nan"),
    ("sources", "background", "-1.0"),
    ("sources", "background", "inf"),
    ("sources", "hot_pixel_rate", "[-1.0, 10.0]"),
    ("sources", "hot_pixel_rate", "nan"),
    ("sources", "hot_pixel_fraction", "1.5"),
    ("effects", "cosmic_ray_rate", "-5.0"),
    ("effects", "cosmic_ray_rate", "nan"),
    ("effects", "flat", "-1.0"),
    ("effects", "full_well", "0.0"),
    ("noise", "rd_noise", "-3.0"),
    ("noise", "c_pink", "nan"),
])
def test_negative_or_nan_values_name_the_key(tmp_path, section, key, value):
    with pytest.raises(ParameterError, match=rf"\[{section}\] '{key}' must be"):
        load_text(tmp_path, RAPID + f"[{section}]\n{key} = {value}\n")


def test_star_flux_and_position_checked(tmp_path):
    with pytest.raises(ParameterError, match=r"\[\[sources.stars\]\] #1 'flux' must be "
                                             r">= 0"):
        load_text(tmp_path, RAPID + "[[sources.stars]]\nx = 1\ny = 2\nflux = 3\n"
                                    "[[sources.stars]]\nx = 1\ny = 2\nflux = -3\n")
    with pytest.raises(ParameterError, match=r"#0 'x' must be finite"):
        load_text(tmp_path, RAPID + "[[sources.stars]]\nx = nan\ny = 2\nflux = 3\n")
    with pytest.raises(ParameterError, match=r"#0 'flux' is required"):
        load_text(tmp_path, RAPID + "[[sources.stars]]\nx = 1\ny = 2\n")


@pytest.mark.parametrize("gain", ["0.0", "-1.8", "nan", "'2'", "true"])
def test_bad_gain(tmp_path, gain):
    with pytest.raises(ParameterError, match=r"\[effects\] 'gain' must be"):
        load_text(tmp_path, RAPID + f"[effects]\ngain = {gain}\n")


@pytest.mark.parametrize("seed", ["-1", "1.5", "'42'", "true"])
def test_bad_seed(tmp_path, seed):
    with pytest.raises(ParameterError, match="'seed' must be"):
        load_text(tmp_path, f"seed = {seed}\n" + RAPID)


def test_wrong_types_of_tables(tmp_path):
    with pytest.raises(ParameterError, match=r"\[sources\] must be a table"):
        load_text(tmp_path, "sources = 3\n" + RAPID)
    with pytest.raises(ParameterError, match=r"'reverse_scan' must be true or false"):
        load_text(tmp_path, RAPID + "[detector]\nreverse_scan = 1\n")
    with pytest.raises(ParameterError, match=r"'nints' must be an integer"):
        load_text(tmp_path, RAPID + "nints = 2.0\n")


# -------------------------------------------------------------------- files
def test_missing_files_raise_file_format_error(tmp_path):
    for section, key in (("sources", "dark_current"), ("sources", "background"),
                         ("sources", "catalogue"), ("effects", "full_well"),
                         ("effects", "flat")):
        ext = "ecsv" if key == "catalogue" else "fits"
        with pytest.raises(FileFormatError,
                           match=rf"'{key}' file '.*missing.{ext}' does not exist"):
            load_text(tmp_path, RAPID + f"[{section}]\n{key} = 'missing.{ext}'\n")
    with pytest.raises(FileFormatError, match=r"\[sources.psf\] 'file' file .*psf.fits"):
        load_text(tmp_path, RAPID + "[sources.psf]\nkind = 'image'\nfile = 'psf.fits'\n")
    with pytest.raises(FileFormatError, match="does not exist"):
        load_text(tmp_path, RAPID + "[sources.light_curves.x]\nkind = 'file'\n"
                                    "file = 'lc.ecsv'\n")
    with pytest.raises(FileFormatError, match="'pca0_file' file"):
        load_text(tmp_path, RAPID + "[noise]\npca0_file = 'pca0.fits'\n")


def test_scene_file_itself(tmp_path):
    with pytest.raises(FileFormatError, match="does not exist"):
        load_scene(tmp_path / "nope.toml")
    with pytest.raises(FileFormatError, match="not valid TOML"):
        load_text(tmp_path, "[readout\npattern = 'RAPID'\n")
    # Errors name the scene file first.
    path = write(tmp_path, RAPID + "[effects]\ngain = 0\n", name="bad.toml")
    with pytest.raises(ParameterError, match=rf"^{path}: \[effects\]"):
        load_scene(path)


def test_map_shape_must_match_detector(tmp_path):
    fits.writeto(tmp_path / "small.fits", np.ones((10, 10)))
    with pytest.raises(FileFormatError, match=r"has shape \(10, 10\).*\(2048, 2048\)"):
        load_text(tmp_path, RAPID + "[sources]\ndark_current = 'small.fits'\n")


def test_map_values_checked_when_loaded(tmp_path):
    bad = np.ones((8, 8))
    bad[3, 5] = -1.0
    fits.writeto(tmp_path / "bad.fits", bad)
    det = Detector(naxis1=8, naxis2=8, ref_border=0)
    with pytest.raises(ParameterError, match=r"'background' map must be finite and >= 0 "
                                             r"everywhere; 1 pixels are not, e.g. "
                                             r"\[3, 5\] = -1.0 \(map file '.*bad.fits'\)"):
        load_map(str(tmp_path / "bad.fits"), det, name="background")


def test_catalogue_columns_checked(tmp_path):
    Table({"x": [1.0], "y": [2.0], "flx": [3.0]}).write(tmp_path / "c.ecsv")
    with pytest.raises(FileFormatError, match=r"no column 'flux'; did you mean 'flx'\?"):
        load_text(tmp_path, RAPID + "[sources]\ncatalogue = 'c.ecsv'\n")
    Table({"x": [1.0], "y": [2.0], "flux": [-3.0]}).write(tmp_path / "n.ecsv")
    with pytest.raises(ParameterError, match="'flux' must be finite and >= 0"):
        load_text(tmp_path, RAPID + "[sources]\ncatalogue = 'n.ecsv'\n")
    Table({"x": [1.0], "y": [2.0], "flux": [3.0], "light_curve": ["transt"]}).write(
        tmp_path / "l.ecsv")
    with pytest.raises(ParameterError,
                       match="light_curve 'transt', which is not defined"):
        load_text(tmp_path, RAPID + "[sources]\ncatalogue = 'l.ecsv'\n")
    (tmp_path / "c.csv").write_text("x,y,flux\n1,2,3\n")
    with pytest.raises(FileFormatError, match=r"'catalogue' file .*c.csv' must have one "
                                              r"of the extensions .ecsv, .fits"):
        load_text(tmp_path, RAPID + "[sources]\ncatalogue = 'c.csv'\n")


def test_fits_catalogue_with_light_curve_column(tmp_path):
    # FITS stores the empty light_curve name as a masked value: it means "constant".
    Table({"x": [1.0, 2.0], "y": [3.0, 4.0], "flux": [5.0, 6.0],
           "light_curve": ["jump", ""]}).write(tmp_path / "cat.fits")
    scene = load_text(tmp_path, RAPID + textwrap.dedent("""\
        [sources]
        catalogue = "cat.fits"
        [sources.light_curves.jump]
        kind = "step"
        t_on = 1.0
        after = 0.0
        """))
    stars = scene.sources.star_table()
    assert list(stars["light_curve"]) == ["jump", ""]
    np.testing.assert_array_equal(stars["flux"], [5.0, 6.0])


# ------------------------------------------------------------------ readout
def test_unknown_readout_pattern(tmp_path):
    with pytest.raises(ParameterError,
                       match=r"\[readout\] 'pattern' must be one of .*got 'MEDIUM9'; "
                             r"did you mean 'MEDIUM8'\?"):
        load_text(tmp_path, '[readout]\npattern = "MEDIUM9"\nngroups = 4\n')


def test_ma_table_with_non_increasing_reads(tmp_path):
    with pytest.raises(ParameterError, match=r"\[readout\] .*non-increasing"):
        load_text(tmp_path, "[readout]\nma_table = [[0, 2], [5, 3], [6, 1]]\n")
    with pytest.raises(ParameterError, match=r"\[readout\] .*increasing"):
        load_text(tmp_path, "[readout]\nresultants = [[0, 1], [1, 2]]\n")


def test_valid_ma_table_and_resultants(tmp_path):
    scene = load_text(tmp_path, "[readout]\nma_table = [[0, 1], [1, 2], [5, 3]]\n")
    assert scene.readout.build().resultants == ((0,), (1, 2), (5, 6, 7))
    scene = load_text(tmp_path, "[readout]\nresultants = [[0], [2, 3], [7]]\n")
    assert scene.readout.build().resultants == ((0,), (2, 3), (7,))


@pytest.mark.parametrize("body, match", [
    ('pattern = "RAPID"\nngroups = 3\nnframes = 2\n', "'pattern' and 'nframes'"),
    ('pattern = "RAPID"\nngroups = 3\nma_table = [[0, 1]]\n', "'pattern' and 'ma_table'"),
    ("ma_table = [[0, 1]]\nresultants = [[0]]\n", "'ma_table' and 'resultants'"),
    ("nints = 2\n", "got none"),
])
def test_exactly_one_readout_form(tmp_path, body, match):
    with pytest.raises(ParameterError,
                       match=rf"\[readout\] needs exactly one of .*{match}"):
        load_text(tmp_path, "[readout]\n" + body)


def test_readout_form_options(tmp_path):
    with pytest.raises(ParameterError, match="needs a \\[readout\\] table"):
        load_text(tmp_path, "seed = 1\n")
    with pytest.raises(ParameterError, match="'ngroups' is required with 'pattern'"):
        load_text(tmp_path, '[readout]\npattern = "RAPID"\n')
    with pytest.raises(ParameterError, match="'groupgap' applies only with 'nframes'"):
        load_text(tmp_path, '[readout]\npattern = "RAPID"\nngroups = 2\ngroupgap = 1\n')
    with pytest.raises(ParameterError, match="'ngroups' is implied by 'ma_table'"):
        load_text(tmp_path, "[readout]\nma_table = [[0, 1]]\nngroups = 1\n")
    with pytest.raises(ParameterError, match=r"'reset' must be one of .*'rolling'"):
        load_text(tmp_path, RAPID + "reset = 'rollin'\n")


# ------------------------------------------------------------ cross-checks
def test_light_curve_reference_must_exist(tmp_path):
    text = RAPID + textwrap.dedent("""\
        [[sources.stars]]
        x = 1
        y = 2
        flux = 3
        light_curve = "trnsit"
        [sources.light_curves.transit]
        kind = "transit"
        t0 = 1.0
        duration = 2.0
        depth = 0.5
        """)
    with pytest.raises(ParameterError, match=r"stars\[0\] uses light_curve 'trnsit', "
                                             r"which is not defined .*did you mean "
                                             r"'transit'\?"):
        load_text(tmp_path, text)


@pytest.mark.parametrize("spec, match", [
    ("kind = 'transit'\nt0 = 1\nduration = 2\n", "needs 'depth'"),
    ("kind = 'transit'\nt0 = 1\nduration = 2\ndepth = 1.5\n", "'depth' must be <= 1"),
    ("kind = 'transit'\nt0 = 1\nduration = 2\ndepth = 0.1\ningress = 1.5\n",
     "'ingress' must be <= 1"),
    ("kind = 'flare'\nt0 = 1\namplitude = 2\ndecay = 0\n", "'decay' must be > 0"),
    ("kind = 'table'\ntime = [0, 1, 1]\nflux = [1, 1, 1]\n", "strictly increasing"),
    ("kind = 'table'\ntime = [0, 1]\nflux = [1]\n", "same length"),
    ("kind = 'step'\nt_on = 1\nafter = -1\n", "'after' must be >= 0"),
    ("t0 = 1\n", "'kind' is required"),
])
def test_light_curve_parameters(tmp_path, spec, match):
    with pytest.raises(ParameterError, match=match):
        load_text(tmp_path, RAPID + "[sources.light_curves.lc]\n" + spec)


def test_nonlinearity_must_be_monotonic_below_full_well(tmp_path):
    # p'(q) = 1 + 2 c2 q vanishes at q = 1 / (2 * 1e-5) = 5e4 e- < 8e4 e-.
    with pytest.raises(ParameterError, match=r"\[effects\] 'nonlinearity' .* turns over "
                                             r"at 50000 e-"):
        load_text(tmp_path,
                  RAPID + "[effects]\nfull_well = 8e4\nnonlinearity = [-1e-5]\n")
    with pytest.raises(ParameterError, match="needs a 'full_well'"):
        load_text(tmp_path, RAPID + "[effects]\nnonlinearity = [-1e-6]\n")
    scene = load_text(tmp_path, RAPID + "[effects]\nfull_well = 4e4\nnonlinearity = "
                                        "[-1e-5]\n")
    assert scene.effects.nonlinearity_model().q_hi == pytest.approx(5e4, rel=1e-12)


def test_ipc_settings(tmp_path):
    scene = load_text(tmp_path, RAPID + "[effects]\nipc_alpha = 0.02\n")
    k = scene.effects.ipc()
    assert k[1, 1] == pytest.approx(0.92) and k[0, 1] == 0.02 and k[0, 0] == 0.0
    with pytest.raises(ParameterError, match="either 'ipc_alpha'"):
        load_text(tmp_path, RAPID + "[effects]\nipc_alpha = 0.02\n"
                                    "ipc_kernel = [[0, 0, 0], [0, 1, 0], [0, 0, 0]]\n")
    with pytest.raises(ParameterError, match="sum to 1"):
        load_text(tmp_path, RAPID + "[effects]\n"
                                    "ipc_kernel = [[0, 0, 0], [0, 0.9, 0], [0, 0, 0]]\n")
    with pytest.raises(ParameterError, match="3x3"):
        load_text(tmp_path, RAPID + "[effects]\nipc_kernel = [[1.0]]\n")


def test_output_consistency(tmp_path):
    with pytest.raises(ParameterError, match="'ramp = false' .* needs 'fit'"):
        load_text(tmp_path, RAPID + "[output]\nramp = false\n")
    with pytest.raises(ParameterError, match="'compare = true' .* needs 'fit'"):
        load_text(tmp_path, RAPID + "[output]\ncompare = true\n")
    with pytest.raises(ParameterError, match="'save_charge' .* needs 'truth = true'"):
        load_text(tmp_path, RAPID + "[output]\ntruth = false\nsave_charge = true\n")
    with pytest.raises(ParameterError, match="'fit' must be one of"):
        load_text(tmp_path, RAPID + "[output]\nfit = 'wls'\n")
    with pytest.raises(ParameterError, match=r"\.fits or \.fits\.gz"):
        load_text(tmp_path, RAPID + "[output]\npath = 'out.txt'\n")


def test_per_output_noise_must_match_active_outputs(tmp_path):
    with pytest.raises(ParameterError, match="'rd_noise' has 2 per-output values but "
                                             "the detector reads through 4"):
        load_text(tmp_path, RAPID + "[noise]\nrd_noise = [5.0, 6.0]\n")


def test_subarray_stripe_defaults_to_full_width(tmp_path):
    scene = load_text(tmp_path, RAPID + "[detector.subarray]\nkind = 'stripe'\n"
                                        "y0 = 100\nny = 32\n")
    assert scene.detector.subarray == Subarray("stripe", 0, 100, 2048, 32, "")
    assert scene.detector.n_out_active == 4


def test_dataclasses_validate_direct_construction():
    with pytest.raises(ParameterError, match="'fwhm' must be > 0"):
        PSFConfig(fwhm=0.0)
    with pytest.raises(ParameterError, match="'file' is required"):
        PSFConfig(kind="image")
    with pytest.raises(ParameterError, match="exactly one of"):
        ReadoutConfig()
    with pytest.raises(ParameterError, match="unique"):
        SourcesConfig(light_curves=(LightCurveConfig("a", "step", t_on=1.0, after=2.0),
                                    LightCurveConfig("a", "step", t_on=2.0, after=1.0)))
    with pytest.raises(ParameterError, match="'hot_pixel_rate' \\[min, max\\] needs"):
        SourcesConfig(hot_pixel_rate=(10.0, 1.0))
    assert math.isinf(EffectsConfig(full_well=1e5,
                                    nonlinearity=(1e-6, 1e-12)).nonlinearity_model().q_hi)
    with pytest.raises(ParameterError, match="'detector' must be a Detector"):
        Scene(detector=None, noise=NIRSPEC_DEFAULTS,
              readout=ReadoutConfig(pattern="RAPID", ngroups=2),
              sources=SourcesConfig(), effects=EffectsConfig(), output=OutputConfig())


# ------------------------------------------------------------ example scenes
SCENE_FILES = sorted(glob.glob(os.path.join(SCENES_DIR, "*.toml")))


def test_example_scenes_exist():
    names = {os.path.basename(p) for p in SCENE_FILES}
    assert {"nirspec_dark.toml", "h2rg_starfield.toml", "roman_h4rg.toml",
            "transit.toml", "cosmic_rays.toml", "bright_star.toml",
            "quick.toml"} <= names


@pytest.mark.parametrize("path", SCENE_FILES, ids=os.path.basename)
def test_example_scene_loads(path):
    scene = load_scene(path)
    assert scene.seed is not None and scene.description
    readout = scene.readout.build()
    assert len(readout.resultants) >= 1
    assert os.path.basename(scene.output.path) == \
        os.path.basename(path).replace(".toml", ".fits")
    # Every star of the example scenes lies on the read-out image.
    stars = scene.sources.star_table()
    ny, nx = scene.detector.shape
    assert np.all((stars["x"] >= 0) & (stars["x"] <= nx - 1))
    assert np.all((stars["y"] >= 0) & (stars["y"] <= ny - 1))


def test_starfield_catalogue_matches_its_generator():
    import importlib.util

    spec = importlib.util.spec_from_file_location(
        "make_starfield", os.path.join(SCENES_DIR, "data", "make_starfield.py"))
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    expected = module.make_table()
    stored = Table.read(os.path.join(SCENES_DIR, "data", "starfield.ecsv"))
    assert len(stored) == 200
    for col in ("x", "y", "flux"):
        np.testing.assert_array_equal(stored[col], expected[col])
    flux = np.asarray(stored["flux"])
    assert flux.min() >= 0.3 * (1 - 5e-4) and flux.max() <= 3000 * (1 + 5e-4)
    assert np.log10(flux.max() / flux.min()) > 3.5       # spans ~4 decades


def test_every_scene_key_is_documented():
    # The scenesim.scene docstring is the reference the README points to: every key
    # the parser accepts appears in it (as ``key`` or ``key = default``; tables as
    # their [header]).
    import re

    import scenesim.scene
    from noise.params import NoiseParams

    doc = scenesim.scene.__doc__
    tables = {"subarray": "[detector.subarray]", "psf": "[sources.psf]",
              "stars": "[[sources.stars]]", "light_curves": "[sources.light_curves.NAME]"}
    for cls in (Detector, Subarray, NoiseParams, ReadoutConfig, SourcesConfig, PSFConfig,
                StarConfig, LightCurveConfig, EffectsConfig, OutputConfig):
        for f in dataclasses.fields(cls):
            if f.name in tables:
                assert tables[f.name] in doc, f.name
            else:
                assert re.search(rf"``{f.name}( = [^`]+)?``", doc), (cls.__name__, f.name)
    for key in ("seed", "description", "preset"):
        assert f"``{key}``" in doc


def test_replace_reads_no_file_and_check_files_reads_them(full_scene_dir):
    # Files are read once, when the scene is loaded.  Before, the dataclasses'
    # __post_init__ re-read the catalogue, the light-curve file, the PSF image and the
    # maps' headers on every dataclasses.replace; now replacing only re-checks values.
    from scenesim.scene import check_files

    scene = load_scene(full_scene_dir / "scene.toml")
    for name in ("cat.ecsv", "lc.ecsv", "psf.fits", "window.fits", "full.fits"):
        (full_scene_dir / "data" / name).write_text("not a table or an image\n")
    assert scene.replace(seed=3).seed == 3
    assert dataclasses.replace(scene.sources, hot_pixel_fraction=0.5).catalogue == \
        scene.sources.catalogue
    assert dataclasses.replace(scene.effects, gain=2.0).full_well == scene.effects.full_well
    with pytest.raises(FileFormatError, match=r"\[noise\] 'pca0_file' file .*full.fits"):
        check_files(scene)
    with pytest.raises(FileFormatError):
        load_scene(full_scene_dir / "scene.toml")


def test_a_fit_of_an_integration_longer_than_the_fitter_takes_is_refused_first():
    """dt = 1e4 s per pixel: an 11-frame integration of a 256^2 array lasts 2.1e9 s,
    beyond the fitter's read times (1e9 s, scenesim.rampfit.times.MAX_READ_TIME):
    refused with the scene, not after the simulation (no fit: accepted)."""
    raw = {"detector": {"preset": "H2RG", "naxis1": 256, "naxis2": 256, "dt": 1e4},
           "noise": {"preset": "none"},
           "readout": {"pattern": "RAPID", "ngroups": 10},
           "output": {"path": "x.fits", "fit": "gls"}}
    with pytest.raises(ParameterError, match=r"\[output\] 'fit' = 'gls': an integration "
                                             r"lasts 2\.\d+e\+09 s .*up to 1e\+09 s"):
        parse_scene(raw)
    raw["output"]["fit"] = ""
    parse_scene(raw)


def test_a_window_scene_takes_its_outputs_value_of_per_output_noise():
    # the scene path of the generator's rule: [noise] rd_noise for the 4 outputs of
    # the full H2RG (512 columns each), a window on columns 1100-1163, output 2:
    # the scene's noise is that output's value
    sc = parse_scene({"detector": {"preset": "H2RG",
                                   "subarray": {"kind": "window", "x0": 1100, "y0": 8,
                                                "nx": 64, "ny": 64}},
                      "noise": {"preset": "none", "rd_noise": [5.0, 6.0, 7.0, 8.0],
                                "bias_offset": 1000.0},
                      "readout": {"pattern": "RAPID", "ngroups": 2}})
    assert sc.noise.rd_noise == (7.0,)


def test_the_noise_preset_is_case_insensitive_as_the_detector_preset_is():
    # a probe: [noise] preset = "NIRSPEC" was refused while [detector] preset takes
    # any case
    base = {"detector": {"preset": "h2rg", "naxis1": 64, "naxis2": 64},
            "readout": {"pattern": "RAPID", "ngroups": 2}}
    for name in ("NIRSPEC", "NirSpec"):
        sc = parse_scene({**base, "noise": {"preset": name}})
        assert sc.noise == parse_scene({**base, "noise": {"preset": "nirspec"}}).noise
    with pytest.raises(ParameterError, match=r"'preset' must be one of 'nirspec', "
                                             r"'none', got 'nirspex'"):
        parse_scene({**base, "noise": {"preset": "nirspex"}})
