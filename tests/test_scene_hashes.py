"""Seed-pinned hashes of the example scenes' science arrays.

Statistics cannot see everything (a sign flip of one of two independent 1/f series, a
swapped stream key); a hash of every output array can.  ``tests/data/scene_hashes.json``
holds the hashes of every HDU of the exposure, truth and fit files of each example
scene run with its own seed through the ``scenesim`` command (plus the quick scene
under every fitter and reference scheme, and four noise-only files), as written by
``python tests/tools/hash_scenes.py --out tests/data/scene_hashes.json``.

Refresh that file only with a stated reason in the commit (a deliberate change of
the physics or of a random stream, or a numpy release that changes a bit
generator's output), never to make a refactor pass: a refactor must leave every
hash unchanged.  The small scenes run here; the full-frame ones (2048^2 and
4096^2) are marked slow.
"""

import json
import os
import sys

import pytest

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, os.path.join(HERE, "tools"))
import hash_scenes  # noqa: E402

with open(os.path.join(HERE, "data", "scene_hashes.json")) as _f:
    PINNED = json.load(_f)

LARGE = sorted(set(PINNED["scenes"]) - set(hash_scenes.SMALL))


def _diff(want, got, path=()):
    if isinstance(want, dict) and isinstance(got, dict):
        out = []
        for k in sorted(set(want) | set(got)):
            out += _diff(want.get(k), got.get(k), path + (k,))
        return out
    return [] if want == got else [f"{'/'.join(path)}: {want} -> {got}"]


def test_small_scenes_fitters_and_noise_files_are_unchanged(tmp_path):
    # two commands at a time (each is its own process: the hashes cannot depend on it)
    got = {"scenes": hash_scenes.scene_hashes(hash_scenes.SMALL, str(tmp_path), jobs=2),
           "fitters": hash_scenes.fitter_hashes(str(tmp_path), jobs=2),
           "noise": hash_scenes.noise_hashes(str(tmp_path), jobs=2)}
    want = {"scenes": {k: PINNED["scenes"][k] for k in hash_scenes.SMALL},
            "fitters": PINNED["fitters"], "noise": PINNED["noise"]}
    assert _diff(want, got) == []


@pytest.mark.slow
@pytest.mark.parametrize("name", LARGE)
def test_full_frame_scene_is_unchanged(tmp_path, name):
    got = hash_scenes.scene_hashes([name], str(tmp_path))[name]
    assert _diff(PINNED["scenes"][name], got) == []
