"""Derived output names keep the whole extension, in the scene and the command.

Before issue 12 the scene's ``[output] path = "out.fits.gz"`` gave the truth file
``out_truth.fits`` (``OutputConfig.truth_path`` cut the extension by hand, and dropped
the compression), while the fit file came out as ``out.fits_ols.gz``.  Now every
derived name goes through :func:`scenesim.outputs.derived_path`: ``out.fits.gz`` ->
``out_truth.fits.gz`` and ``out_ols.fits.gz``, written gzip-compressed.
"""

import gzip
import os
import subprocess
import sys

import pytest
from astropy.io import fits

from scenesim.outputs import derived_path
from scenesim.run import run_scene
from scenesim.scene import parse_scene
from scenesim.validate.compare import compare_files

NAMES = [
    ("out.fits", "out_truth.fits"),
    ("out.fits.gz", "out_truth.fits.gz"),
    ("out.FITS.GZ", "out_truth.FITS.GZ"),
    (os.path.join("run.v2", "out.fits.gz"), os.path.join("run.v2", "out_truth.fits.gz")),
    (os.path.join("run.v2", "out.fits"), os.path.join("run.v2", "out_truth.fits")),
]


def _scene(path, **output):
    return parse_scene({"seed": 4, "detector": {"naxis1": 16, "naxis2": 16,
                                                "ref_border": 2},
                        "readout": {"pattern": "RAPID", "ngroups": 3},
                        "sources": {"background": 1.0},
                        "output": {"path": path, **output}})


@pytest.mark.parametrize("path, truth", NAMES)
def test_scene_truth_path_keeps_the_extension(path, truth):
    cfg = _scene(path).output
    assert cfg.truth_path == truth == derived_path(path, "_truth")


def _is_gzip(path):
    with open(path, "rb") as f:
        return f.read(2) == b"\x1f\x8b"


@pytest.mark.parametrize("ending", [".fits.gz", ".FITS.GZ", ".Fits.Gz"])
def test_run_scene_writes_gz_names_and_gzip(tmp_path, ending):
    # an upper-case ending was written compressed, then read back as an uncompressed
    # file by the fit ("truncated"): compression is told by content now
    res = run_scene(_scene(str(tmp_path / f"out{ending}"), fit="ols", compare=True),
                    progress=False)
    assert sorted(os.listdir(tmp_path)) == sorted([f"out{ending}", f"out_ols{ending}",
                                                   f"out_truth{ending}"])
    assert res.truth == str(tmp_path / f"out_truth{ending}")
    for name in os.listdir(tmp_path):
        assert _is_gzip(tmp_path / name), name
        with fits.open(tmp_path / name) as hdul:
            hdul.verify("exception")
    with gzip.open(tmp_path / f"out_truth{ending}") as f:
        assert f.read(6) == b"SIMPLE"
    assert res.report is not None and res.report.rows
    assert compare_files(res.fit, res.truth).rows


def test_command_run_with_a_gz_scene_path(tmp_path):
    (tmp_path / "s.toml").write_text(
        'seed = 4\n[detector]\nnaxis1 = 16\nnaxis2 = 16\nref_border = 2\n'
        '[readout]\npattern = "RAPID"\nngroups = 3\n[sources]\nbackground = 1.0\n'
        '[output]\npath = "x.fits.gz"\nfit = "gls"\n')
    res = subprocess.run([sys.executable, "-m", "scenesim.cli", "run", "s.toml", "-q"],
                         cwd=tmp_path, capture_output=True, text=True, timeout=300)
    assert res.returncode == 0, res.stderr
    assert res.stderr == ""
    assert sorted(os.listdir(tmp_path)) == ["s.toml", "x.fits.gz", "x_gls.fits.gz",
                                            "x_truth.fits.gz"]
    assert all(_is_gzip(tmp_path / n) for n in os.listdir(tmp_path) if n != "s.toml")
    # the truth is refused as an output of the next run (it exists), named in full
    again = subprocess.run([sys.executable, "-m", "scenesim.cli", "run", "s.toml", "-q"],
                           cwd=tmp_path, capture_output=True, text=True, timeout=300)
    assert again.returncode == 2
    assert "x.fits.gz" in again.stderr and len(again.stderr.strip().splitlines()) == 1


@pytest.mark.parametrize("command, ending", [
    (["noise", "--preset", "H2RG", "--naxis", "16", "--frames", "2", "-o", "n.txt"],
     ".fits or .fits.gz"),
    (["noise", "--preset", "H2RG", "--naxis", "16", "--frames", "2", "-o", "n.fit"],
     ".fits or .fits.gz"),
    (["fit", "x.fits", "-o", "f.txt"], ".fits or .fits.gz"),
    (["calibrate", "x.fits", "-o", "cal.txt"], ".toml"),
    (["psd", "x.fits", "--plot", "p.txt"], ".png"),
])
def test_every_command_output_ends_in_its_format(tmp_path, command, ending):
    """Before, only `run -o` was held to its format's ending: `noise -o n.txt` wrote
    FITS under a .txt name and `psd --plot p.txt` a PNG.  Each is refused in one
    line naming the option's file and the endings allowed, before reading anything
    (x.fits does not even exist)."""
    res = subprocess.run([sys.executable, "-m", "scenesim.cli", *command], cwd=tmp_path,
                         capture_output=True, text=True, timeout=300)
    assert res.returncode == 2, res.stderr
    lines = res.stderr.strip().splitlines()
    assert len(lines) == 1 and f"must end in {ending}" in lines[0], res.stderr
    assert os.listdir(tmp_path) == []


@pytest.mark.parametrize("exposure, slopes", [
    ("x.fits", "x_gls.fits"), ("x.fits.gz", "x_gls.fits.gz"), ("x.dat", "x_gls.fits"),
    ("x", "x_gls.fits"), (os.path.join("a.b", "x"), os.path.join("a.b", "x_gls.fits"))])
def test_the_default_slope_file_is_a_fits_name(exposure, slopes):
    from scenesim.outputs import fit_path_for
    assert fit_path_for(exposure, "gls") == slopes


def test_an_output_directory_that_is_a_dangling_link_is_refused_first(tmp_path):
    """--plots, bench --out, batch --out, pipeline -o and --reffiles on a symbolic link
    to nothing: os.makedirs raised FileExistsError (a traceback, for `run` after its
    files were written)."""
    from noise.errors import ParameterError
    from scenesim.batch.runner import _check_out_writable
    from scenesim.bench import _check_out_dir
    from scenesim.outputs import check_plot_dir
    link = tmp_path / "figs"
    os.symlink(tmp_path / "nothere", link)
    for check in (lambda: check_plot_dir(link), lambda: _check_out_dir(link, (), False),
                  lambda: _check_out_writable(str(link))):
        with pytest.raises(ParameterError, match=r"is a symbolic link to .*nothere.*"
                                                 r"does not exist"):
            check()
    (tmp_path / "s.toml").write_text(
        'seed = 1\n[detector]\nnaxis1 = 16\nnaxis2 = 16\nref_border = 2\n[readout]\n'
        'pattern = "RAPID"\nngroups = 3\n[output]\npath = "x.fits"\nfit = "ols"\n'
        'compare = true\n')
    res = subprocess.run([sys.executable, "-m", "scenesim.cli", "run", "s.toml", "-o",
                          "x.fits", "--plots", "figs", "-q"], cwd=tmp_path,
                         capture_output=True, text=True)
    assert res.returncode == 2 and "symbolic link" in res.stderr, res.stderr
    assert sorted(os.listdir(tmp_path)) == ["figs", "s.toml"]


def test_an_output_that_is_a_link_to_nothing_needs_overwrite(tmp_path):
    """A dangling symbolic link at an output path is something there: it had been
    replaced by the new file without --overwrite."""
    (tmp_path / "s.toml").write_text(
        'seed = 1\n[detector]\nnaxis1 = 16\nnaxis2 = 16\nref_border = 2\n[readout]\n'
        'pattern = "RAPID"\nngroups = 3\n[output]\npath = "x.fits"\n')
    os.symlink("nowhere.fits", tmp_path / "dl.fits")
    res = subprocess.run([sys.executable, "-m", "scenesim.cli", "run", "s.toml", "-o",
                          "dl.fits", "-q"], cwd=tmp_path, capture_output=True, text=True)
    assert res.returncode == 2 and "is a symbolic link (to 'nowhere.fits'" in \
        res.stderr, res.stderr
    assert os.path.islink(tmp_path / "dl.fits")
    res = subprocess.run([sys.executable, "-m", "scenesim.cli", "run", "s.toml", "-o",
                          "dl.fits", "-q", "--overwrite"], cwd=tmp_path,
                         capture_output=True, text=True)
    assert res.returncode == 0, res.stderr
    assert not os.path.islink(tmp_path / "dl.fits") and \
        not (tmp_path / "nowhere.fits").exists()
