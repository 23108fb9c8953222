"""Scene files: TOML in, validated frozen dataclasses out."""

from scenesim.scene.config import *  # noqa: F401,F403
from scenesim.scene.config import __all__  # noqa: F401
