"""``compare`` against corrupt header values, card by card.

The files of one small run (exposure, truth, OLS slopes; a 32 x 32 array with cosmic
rays and a fit) are copied with one header card changed to a value of each class of
:data:`VALUES` (a string, negative, zero, huge, an integer beyond int64's half, a
boolean, a fraction, or the card deleted), and given to
:func:`scenesim.validate.compare.compare_files` in the place of the good file (a
changed exposure as ``exposure=``; the others without an exposure, so the read times
come from the truth's readout cards).  Every card of every HDU is tried, less the structural
ones astropy writes itself (``SIMPLE``, ``BITPIX``, ``NAXISn``, ``TFORMn``, ...).

Each case must either compare (the card is not read, or the value is allowed) or raise
:class:`noise.errors.FileFormatError` in one line naming the changed file -- never
another exception, a numpy error, an overflow or a warning (warnings are errors in this
suite), and nothing is written.  The cards the comparison reads must be refused where
the value is wrong (:data:`MUST_REFUSE`): before issue 12 ``TFRAME = 1e300`` overflowed
("overflow encountered in square"), ``NINTS = 1e300`` failed with numpy's "Maximum
allowed size exceeded", ``NGROUPS = 'abc'`` raised a bare ValueError, a negative
``RDNOISE`` or a readout with one group raised errors that named no file, and
``NINTS = 2.5`` was truncated to 2 without a word.

The cards the comparison reads (:data:`FAST_CARDS`) run in the fast suite; every other
card is ``slow``.
"""

import hashlib
import os
import shutil

import pytest
from astropy.io import fits

from noise.errors import FileFormatError
from scenesim.engine import EngineOptions
from scenesim.run import run_scene
from scenesim.scene import parse_scene
from scenesim.validate.compare import Report, compare_files

#: One value of each class (``None``: the card deleted).
VALUES = {"string": "abc", "negative": -1, "zero": 0, "huge": 1e300, "bigint": 2 ** 62,
          "bool": True, "fraction": 2.5, "deleted": None}
#: Cards astropy manages (changing them makes another file, not a corrupt value).
STRUCTURAL = {"SIMPLE", "BITPIX", "NAXIS", "EXTEND", "XTENSION", "PCOUNT", "GCOUNT",
              "TFIELDS"}
#: Cards the comparison reads: the fast suite.
FAST_CARDS = {"GAIN", "TFRAME", "NINTS", "NGROUPS", "NFRAMES", "GROUPGAP", "DROPFRM1",
              "RESETMD", "READPATT", "ADCBITS", "FULLWELL", "RDNOISE", "RNOISE", "IPC",
              "IPCDECON", "DETNAX1", "NOUTFULL", "NROH", "PIXDWELL", "SUBKIND",
              "PSFFWHM", "FILETYPE"}
#: ``{(file, card): classes}`` the comparison must refuse.
MUST_REFUSE = {
    ("truth", "TFRAME"): {"string", "negative", "zero", "huge", "bigint", "bool"},
    ("truth", "NINTS"): {"string", "negative", "zero", "huge", "bigint", "bool",
                         "fraction"},
    ("truth", "NGROUPS"): {"string", "negative", "zero", "huge", "bigint", "bool",
                           "fraction"},
    ("truth", "RDNOISE"): {"string", "negative", "huge"},
    ("truth", "GAIN"): {"string", "negative", "zero", "huge", "bool"},
    ("exposure", "TFRAME"): {"string", "negative", "zero", "huge", "bigint", "bool",
                             "deleted"},
    ("exposure", "NINTS"): {"string", "negative", "zero", "huge", "bigint", "bool",
                            "fraction"},
    ("fit", "RNOISE"): {"negative", "huge"},
}
FILES = ("truth", "fit", "exposure")
#: Cases of an open defect outside compare, left out of the loops until it is fixed
#: (none now: a READS table's NFRAMES = 2**62 is refused by Readout's bound,
#: :func:`test_huge_nframes_in_the_reads_table`).
KNOWN = set()


@pytest.fixture(scope="module")
def good(tmp_path_factory):
    d = tmp_path_factory.mktemp("header_values")
    scene = parse_scene({"seed": 3, "detector": {"naxis1": 32, "naxis2": 32,
                                                 "ref_border": 4},
                         "readout": {"pattern": "RAPID", "ngroups": 4},
                         "sources": {"background": 2.0},
                         "effects": {"cosmic_ray_rate": 50.0},
                         "output": {"path": str(d / "x.fits"), "fit": "ols"}})
    res = run_scene(scene, progress=False, options=EngineOptions(threads=1))
    return {"exposure": res.exposure, "truth": res.truth, "fit": res.fit}


def _cards(path):
    """``(hdu index, card)`` of every non-structural card of ``path``."""
    with fits.open(path) as hdul:
        return [(i, k) for i, hdu in enumerate(hdul) for k in hdu.header.keys()
                if k not in STRUCTURAL and not k.startswith(("NAXIS", "TFORM"))]


def _snapshot(directory):
    return {n: hashlib.sha256((directory / n).read_bytes()).hexdigest()
            for n in sorted(os.listdir(directory))}


def _cases(good, which, cls, fast):
    """Run every card of file ``which`` set to class ``cls``; return the failures."""
    failures = []
    src = good[which]
    work = os.path.dirname(src)
    for i, key in _cards(src):
        if (i == 0 and key in FAST_CARDS) != fast or (which, i, key, cls) in KNOWN:
            continue
        bad = os.path.join(work, f"bad_{which}_{i}_{key}_{cls}.fits")
        with fits.open(src) as hdul:
            if VALUES[cls] is None:
                del hdul[i].header[key]
            else:
                hdul[i].header[key] = VALUES[cls]
            hdul.writeto(bad, output_verify="silentfix")
        paths = dict(good, **{which: bad})
        label = f"{which} HDU {i} {key} = {VALUES[cls]!r}"
        try:
            # the truth's readout cards are read only without an exposure
            out = compare_files(paths["fit"], paths["truth"],
                                exposure=paths["exposure"] if which == "exposure" else None)
        except FileFormatError as exc:
            msg = str(exc)
            if "\n" in msg or bad not in msg:
                failures.append(f"{label}: message without the file: {msg}")
        except Exception as exc:                # noqa: BLE001 -- the point of the test
            failures.append(f"{label}: {type(exc).__name__}: {exc}")
        else:
            assert isinstance(out, Report)
            if i == 0 and cls in MUST_REFUSE.get((which, key), ()):
                failures.append(f"{label}: accepted")
        finally:
            os.remove(bad)
    return failures


@pytest.mark.parametrize("which", FILES)
@pytest.mark.parametrize("cls", list(VALUES))
def test_cards_compare_reads(good, which, cls):
    before = _snapshot(_dir(good))
    assert _cases(good, which, cls, fast=True) == []
    assert _snapshot(_dir(good)) == before


@pytest.mark.slow
@pytest.mark.parametrize("which", FILES)
@pytest.mark.parametrize("cls", list(VALUES))
def test_every_other_card(good, which, cls):
    before = _snapshot(_dir(good))
    assert _cases(good, which, cls, fast=False) == []
    assert _snapshot(_dir(good)) == before


def _dir(good):
    from pathlib import Path
    return Path(os.path.dirname(good["truth"]))


def test_the_enumeration_reaches_the_cards_compare_reads(good):
    for which in FILES:
        read = {k for i, k in _cards(good[which]) if i == 0 and k in FAST_CARDS}
        assert {"TFRAME", "NINTS"} <= read, (which, read)
    assert {"GAIN", "RDNOISE", "NGROUPS", "DETNAX1"} <= {
        k for _, k in _cards(good["truth"])}
    assert len(_cards(good["truth"])) >= 70


def test_messages_name_the_file_and_the_card(good, tmp_path):
    truth = str(tmp_path / "t.fits")
    shutil.copyfile(good["truth"], truth)
    with fits.open(truth, mode="update") as hdul:
        hdul[0].header["TFRAME"] = 1e300
    with pytest.raises(FileFormatError) as info:
        compare_files(good["fit"], truth)
    assert str(info.value).startswith(f"truth file {truth!r}: 'TFRAME' = 1e+300 s is not "
                                      f"the frame time of the detector cards")


def test_huge_nframes_in_the_reads_table(good, tmp_path):
    exposure = str(tmp_path / "e.fits")
    shutil.copyfile(good["exposure"], exposure)
    with fits.open(exposure, mode="update") as hdul:
        hdul["READS"].header["NFRAMES"] = 2 ** 62
    with pytest.raises(FileFormatError, match="e.fits"):
        compare_files(good["fit"], good["truth"], exposure=exposure)
