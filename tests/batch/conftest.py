"""A small scene for the batch tests: 64x64 H2RG-like array, RAPID x 5, full noise,
three stars and cosmic rays (so jumps are graded); about 0.2 s a realisation."""

import pytest

SMALL_SCENE = """\
seed = 777
description = "batch tests: 64x64, RAPID x 5"

[detector]
preset = "H2RG"
naxis1 = 64
naxis2 = 64

[readout]
pattern = "RAPID"
ngroups = 5

[sources]
dark_current = 0.01
background = 1.0

[[sources.stars]]
x = 20.3
y = 30.6
flux = 3000.0

[[sources.stars]]
x = 45.2
y = 15.1
flux = 300.0

[effects]
cosmic_ray_rate = 500.0

[output]
path = "small.fits"
fit = "gls"
"""


@pytest.fixture
def small_scene(tmp_path):
    """Path of the small scene file (in its own directory)."""
    d = tmp_path / "scenes"
    d.mkdir()
    path = d / "small.toml"
    path.write_text(SMALL_SCENE)
    return path
