"""Without the pipeline extras: ``scenesim run`` imports no pipeline package, and a
product or command that needs a missing extra is refused in one line naming it,
before any work.  The missing extra is simulated by a failing import (the module set
to None in ``sys.modules``), so these tests run whether the extras are installed or
not."""

import os
import subprocess
import sys

import pytest

from noise.errors import ParameterError
from scenesim.pipelines.command import EXTRAS, require_extra

HERE = os.path.dirname(os.path.abspath(__file__))
SCENE = os.path.join(HERE, "..", "data", "pipelines", "jwst_loop.toml")
ROMAN_SCENE = os.path.join(HERE, "..", "data", "pipelines", "roman_loop.toml")
PIPELINE_MODULES = sorted({m for mods in EXTRAS.values() for m in mods} | {"crds"})

#: Runs ``scenesim.cli.main(argv)`` with the given modules unimportable, then prints
#: the pipeline modules that were imported.
_DRIVER = """
import json, sys
argv, blocked, watched = json.loads(sys.argv[1])
for name in blocked:
    sys.modules[name] = None              # 'import name' now raises ImportError
from scenesim.cli import main
rc = main(argv)
print(json.dumps([m for m in watched if sys.modules.get(m) is not None]))
sys.exit(rc)
"""


def _cli(argv, blocked, cwd):
    import json
    res = subprocess.run([sys.executable, "-c", _DRIVER,
                          json.dumps([argv, blocked, PIPELINE_MODULES])],
                         cwd=cwd, capture_output=True, text=True)
    imported = json.loads(res.stdout.splitlines()[-1]) if res.stdout.strip() else None
    return res.returncode, res.stderr, imported


def test_require_extra_names_the_extra(monkeypatch):
    monkeypatch.setitem(sys.modules, "stdatamodels", None)
    with pytest.raises(ParameterError, match=r"^--uncal needs the optional 'jwst' "
                                             r"extra \(stdatamodels is not installed\): "
                                             r"pip install -e '\.\[jwst\]'$"):
        require_extra("jwst", "--uncal")
    monkeypatch.setitem(sys.modules, "roman_datamodels", None)
    with pytest.raises(ParameterError, match=r"'roman' extra \(roman_datamodels"):
        require_extra("roman", "--l1")


def test_plain_run_imports_no_pipeline_package(tmp_path):
    rc, err, imported = _cli(["run", SCENE, "-q", "-o", "x.fits"], [], tmp_path)
    assert rc == 0, err
    assert imported == []
    assert (tmp_path / "x.fits").exists()


def test_run_without_the_extras_still_works(tmp_path):
    rc, err, imported = _cli(["run", SCENE, "-q", "-o", "x.fits"], PIPELINE_MODULES,
                             tmp_path)
    assert rc == 0, err
    assert (tmp_path / "x.fits").exists()


@pytest.mark.parametrize("flags, scene, extra", [
    (["--uncal"], SCENE, "jwst"),
    (["--reffiles"], SCENE, "jwst"),             # a JWST-sized MULTIACCUM detector
    (["--l1"], ROMAN_SCENE, "roman"),
    (["--reffiles"], ROMAN_SCENE, "roman"),      # an H4RG: Roman references
])
def test_product_without_its_extra_is_one_line_before_work(tmp_path, flags, scene,
                                                           extra):
    rc, err, _ = _cli(["run", scene, "-q", "-o", "x.fits", *flags],
                      EXTRAS[extra][:1], tmp_path)
    assert rc == 2
    lines = err.strip().splitlines()
    assert len(lines) == 1, err
    assert f"optional '{extra}' extra" in lines[0]
    assert f"pip install -e '.[{extra}]'" in lines[0]
    assert os.listdir(tmp_path) == []             # refused before any work


@pytest.mark.parametrize("extra", ["jwst", "roman"])
def test_pipeline_command_without_its_extra(tmp_path, extra):
    rc, err, _ = _cli(["pipeline", extra, "in.fits", "--refs", "refs"],
                      EXTRAS[extra][1:2], tmp_path)
    assert rc == 2
    lines = err.strip().splitlines()
    assert len(lines) == 1 and f"optional '{extra}' extra" in lines[0], err
