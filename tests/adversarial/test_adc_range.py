"""Noise amplitudes that clip every pixel at the ADC, refused by every way in.

A noise amplitude above 100 times the ADC range in electrons (``gain * (2**bits -
1)``) puts every pixel at code 0 or the top code (a constant ``bias_offset``), or
leaves at most 0.4 % of a Gaussian component's values inside the range
(:meth:`noise.NoiseParams.check_adc`).  Before issue 12 ``c_pink = 1e300`` was
accepted with only an overflow RuntimeWarning, and ``c_pink = 1e7`` (or ``scenesim
noise --unit DN --gain 1e-5``, whose 5000 e- bias is 5e8 DN) wrote a ramp of clipped
pixels without a word.

Every amplitude of :class:`noise.NoiseParams` (its dataclass fields, less the options
of ``noise.params._OPTIONS`` and ``rtn_amp``, which reaches only the RTN pixels) is
set just above the limit, and (class ``float32``) far beyond the float32 frames, and
given to each way in: a scene mapping (:func:`parse_scene`), a scene file
(:func:`load_scene`), ``Scene.replace`` in the library, :func:`noise.write_noise_fits`
with ``unit='DN'``, and the commands ``scenesim run`` and ``scenesim noise``.  Each
must refuse it before any work in one line naming the key (and its table, for a
scene), and accept the value at the limit.  The constant ``bias_offset`` has the
tighter bound of the mean level (5 rms spreads of the other components beyond the
range, :data:`noise.params.BIAS_SPREAD_SIGMA`), tested on both sides.
"""

import dataclasses
import hashlib
import os
import subprocess
import sys

import pytest

import noise
from noise.errors import ParameterError
from noise.params import _OPTIONS
from scenesim.scene import load_scene, parse_scene

#: The amplitudes check_adc bounds (the ones that reach every pixel).
AMPLITUDES = [f.name for f in dataclasses.fields(noise.NoiseParams)
              if f.name not in _OPTIONS and f.name != "rtn_amp"]
GAIN, BITS = 2.0, 12
LIMIT = 100 * GAIN * (2 ** BITS - 1)            # 819000 e-
#: value classes: just above the ADC limit, and beyond the float32 frames (1e30)
VALUES = {"adc": 1.01 * LIMIT, "float32": 1e300}


def _mapping(key, value):
    return {"seed": 1, "detector": {"naxis1": 16, "naxis2": 16, "ref_border": 2},
            "noise": {"preset": "nirspec", key: value},
            "readout": {"pattern": "RAPID", "ngroups": 2},
            "effects": {"gain": GAIN, "adc_bits": BITS},
            "output": {"path": "out.fits"}}


def _toml(key, value):
    return (f'seed = 1\n[detector]\nnaxis1 = 16\nnaxis2 = 16\nref_border = 2\n'
            f'[noise]\npreset = "nirspec"\n{key} = {value!r}\n'
            f'[readout]\npattern = "RAPID"\nngroups = 2\n'
            f'[effects]\ngain = {GAIN!r}\nadc_bits = {BITS}\n[output]\npath = "out.fits"\n')


def _check(msg, key):
    assert "\n" not in msg, msg
    assert f"'{key}'" in msg, msg


def test_the_amplitudes_are_enumerated():
    assert set(AMPLITUDES) == {"rd_noise", "c_pink", "u_pink", "acn", "pca0", "pedestal",
                               "ktc", "bias_offset", "bias_amp"}


@pytest.mark.parametrize("key", AMPLITUDES)
@pytest.mark.parametrize("cls", list(VALUES))
def test_scene_mapping_and_file_refuse_it(key, cls, tmp_path):
    with pytest.raises(ParameterError) as info:
        parse_scene(_mapping(key, VALUES[cls]))
    _check(str(info.value), key)
    assert str(info.value).startswith("[noise] ")
    if cls == "adc":
        assert "would clip every pixel" in str(info.value)
        assert "'gain' 2 e-/DN" in str(info.value) and "'adc_bits' 12" in str(info.value)
    (tmp_path / "s.toml").write_text(_toml(key, VALUES[cls]))
    with pytest.raises(ParameterError) as info:
        load_scene(tmp_path / "s.toml")
    _check(str(info.value), key)
    assert str(tmp_path / "s.toml") in str(info.value)


@pytest.mark.parametrize("key", [k for k in AMPLITUDES if k != "bias_offset"])
def test_the_limit_itself_is_accepted(key):
    scene = parse_scene(_mapping(key, LIMIT))
    assert getattr(scene.noise, key) == LIMIT


def _nirspec_spread():
    """Rms spread (e-) of the nirspec preset's components around the bias, from the
    preset's amplitudes (root sum of squares; white noise at the larger of the
    regular and reference-pixel levels)."""
    p = noise.NIRSPEC_DEFAULTS
    amps = [max(p.rd_noise if isinstance(p.rd_noise, tuple) else (p.rd_noise,))
            * max(1.0, p.ref_ratio)]
    for name in ("c_pink", "u_pink", "acn", "pca0", "pedestal", "ktc", "bias_amp"):
        v = getattr(p, name)
        amps.append(max(v) if isinstance(v, tuple) else v)
    return sum(a * a for a in amps) ** 0.5


@pytest.mark.parametrize("side", ["top", "bottom"])
def test_a_bias_that_puts_every_pixel_outside_the_adc_is_refused(side):
    # The constant reset level clips every pixel once it lies more than 5 rms spreads
    # s of the other components beyond the ADC range [0, gain (2**bits - 1)] e-:
    # above the top code (charge only adds), or below 0 for every pixel without
    # charge.  Before, only 100 x the range was refused (`scenesim noise --unit DN
    # --gain 0.001` wrote every pixel at 65535).  Just inside is accepted, just
    # outside refused, in one line naming the key.
    s = _nirspec_spread()
    adc_range = GAIN * (2 ** BITS - 1)
    edge = adc_range + 5 * s if side == "top" else -5 * s
    step = 1e-6 * max(abs(edge), 1.0)
    inside = edge - step if side == "top" else edge + step
    outside = edge + step if side == "top" else edge - step
    assert parse_scene(_mapping("bias_offset", inside)).noise.bias_offset == inside
    with pytest.raises(ParameterError) as info:
        parse_scene(_mapping("bias_offset", outside))
    _check(str(info.value), "bias_offset")
    assert ("above the ADC's top code" if side == "top" else "below code 0") in \
        str(info.value)


@pytest.mark.parametrize("key", AMPLITUDES)
def test_library_scene_replace_refuses_it(key):
    scene = parse_scene(_mapping(key, 1.0))
    with pytest.raises(ParameterError) as info:
        scene.replace(noise=scene.noise.replace(**{key: VALUES["adc"]}))
    _check(str(info.value), key)
    # a smaller ADC range under the same amplitudes: the gain named too (the bias
    # at the top code: 8190 e- - 5 x ~500 e- of spread is above half the range)
    start = GAIN * (2 ** BITS - 1) if key == "bias_offset" else LIMIT
    scene = parse_scene(_mapping(key, start))
    with pytest.raises(ParameterError) as info:
        scene.replace(effects=dataclasses.replace(scene.effects, gain=GAIN / 2))
    _check(str(info.value), key)
    assert "'gain' 1 e-/DN" in str(info.value)


@pytest.mark.parametrize("key", AMPLITUDES)
def test_write_noise_fits_in_dn_refuses_it(key, tmp_path):
    det = noise.preset("H2RG", naxis1=16, naxis2=16)
    limit16 = 100 * GAIN * 65535                     # the file's ADC: 16 bits
    params = noise.ZERO_NOISE.replace(**{key: 1.01 * limit16})
    gen = noise.NoiseGenerator(det, params, rng=1, threads=1)
    with pytest.raises(ParameterError) as info:
        noise.write_noise_fits(tmp_path / "n.fits", gen, 2, unit="DN", gain=GAIN)
    _check(str(info.value), key)
    assert "unit='DN'" in str(info.value)
    assert os.listdir(tmp_path) == []
    # in electrons (float32) nothing clips; at the limit the DN file is written
    noise.write_noise_fits(tmp_path / "e.fits", gen, 2, unit="e")
    # (the bias alone, with nothing around it, may reach the top code itself)
    at = GAIN * 65535 if key == "bias_offset" else limit16
    at_limit = noise.NoiseGenerator(det, noise.ZERO_NOISE.replace(**{key: at}),
                                    rng=1, threads=1)
    noise.write_noise_fits(tmp_path / "dn.fits", at_limit, 2, unit="DN", gain=GAIN)
    assert sorted(os.listdir(tmp_path)) == ["dn.fits", "e.fits"]


def _snapshot(directory):
    return {n: hashlib.sha256((directory / n).read_bytes()).hexdigest()
            for n in sorted(os.listdir(directory))}


def _cli(args, cwd):
    return subprocess.run([sys.executable, "-m", "scenesim.cli", *args], cwd=cwd,
                          capture_output=True, text=True, timeout=120)


def _one_line(stderr, *words):
    lines = [ln for ln in stderr.splitlines() if ln.strip()]
    assert len(lines) == 1, stderr
    assert "Traceback" not in stderr
    for w in words:
        assert w in lines[0], (w, lines[0])


@pytest.mark.parametrize("key, cls", [("c_pink", "float32"), ("rd_noise", "float32"),
                                      ("bias_offset", "adc"), ("c_pink", "adc")])
def test_run_command_refuses_it_in_one_line(key, cls, tmp_path):
    (tmp_path / "s.toml").write_text(_toml(key, VALUES[cls]))
    before = _snapshot(tmp_path)
    res = _cli(["run", "s.toml", "-q"], tmp_path)
    assert res.returncode == 2, res.stderr
    _one_line(res.stderr, "s.toml", "[noise]", f"'{key}'")
    assert _snapshot(tmp_path) == before


def test_noise_command_refuses_a_gain_that_clips_every_pixel(tmp_path):
    # the paper's 5000 e- bias at 1e-5 e-/DN is 5e8 DN, beyond 100 x the 16-bit range
    # (65.5 e- at this gain): every pixel at 65535
    res = _cli(["noise", "--naxis", "64", "--frames", "2", "--unit", "DN", "--gain",
                "1e-5", "-q", "-o", "n.fits"], tmp_path)
    assert res.returncode == 2, res.stderr
    _one_line(res.stderr, "'bias_offset'", "'gain' 1e-05", "unit='DN'")
    assert os.listdir(tmp_path) == []
