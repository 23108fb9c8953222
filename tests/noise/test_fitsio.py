"""Tests of noise.write_noise_fits: round trips with astropy, header records, atomicity.

The expected data are the generator's own frames (same seed, fresh generator), and the
DN conversion is rewritten here from its definition: rint(e / gain) clipped to
[0, 65535].  A failing write must leave neither the destination nor a temporary file.
"""

import dataclasses
import os
import stat
from importlib import metadata

import numpy as np
import pytest
from astropy.io import fits

from noise import (NIRSPEC_DEFAULTS, ZERO_NOISE, NoiseGenerator, NoiseParams, preset,
                   write_noise_fits)
from noise.errors import ParameterError, ParameterTypeError

DET = preset("H2RG", naxis1=64, naxis2=64, n_out=4)

#: Header keyword of every NoiseParams field (typed in independently of params.py).
KEYWORDS = {
    "rd_noise": "RDNOISE", "ref_ratio": "REFRATIO", "c_pink": "C_PINK",
    "u_pink": "U_PINK", "acn": "ACN", "pca0": "PCA0AMP", "pedestal": "PEDESTAL",
    "ktc": "KTCNOISE", "bias_offset": "BIASOFF", "bias_amp": "BIASAMP",
    "rtn_fraction": "RTNFRAC", "rtn_amp": "RTNAMP", "rtn_tau_low": "RTNTLOW",
    "rtn_tau_high": "RTNTHIGH", "f_min": "FMIN", "pink_spectrum": "PINKSPEC",
    "pca0_file": "PCA0FILE",
}


def _gen(params, rng=7):
    return NoiseGenerator(DET, params, rng=rng, threads=1)


def _files(directory):
    return sorted(os.listdir(directory))


def test_float32_electrons_round_trip(tmp_path):
    path = tmp_path / "ramp.fits"
    seen = []
    out = write_noise_fits(str(path), _gen(NIRSPEC_DEFAULTS), 3, progress=seen.append)
    assert out == str(path)
    assert seen == [1, 2, 3]
    with fits.open(path) as hdul:
        data = hdul[0].data
        assert data.dtype == np.dtype(">f4") and data.shape == (3, 64, 64)
        np.testing.assert_array_equal(data, _gen(NIRSPEC_DEFAULTS).cube(3)[0])
        assert hdul[0].header["BUNIT"] == "electron"
    assert _files(tmp_path) == ["ramp.fits"]               # no temporary file left


@pytest.mark.parametrize("side", ["bottom", "top"])
def test_uint16_dn_round_trip_at_the_edges_of_the_adc(tmp_path, side):
    """A bias 5 rms spreads inside either end of the 16-bit range is written exactly
    (rint(e / gain), nothing clipped); just outside it is refused before any file
    (issue 12: a bias at code 0 used to clip half of every pixel's reads without a
    word).  The ADC's clipping itself: tests/noise/test_adc.py."""
    gain, rd = 2.0, 20.0
    adc_range = gain * 65535
    inside = 5 * rd + 1 if side == "bottom" else adc_range - 5 * rd - 1
    params = ZERO_NOISE.replace(rd_noise=rd, bias_offset=inside)
    path = tmp_path / "dn.fits"
    write_noise_fits(path, _gen(params), 2, unit="DN", gain=gain)
    electrons = _gen(params).cube(2)[0].astype(np.float64)
    expected = np.clip(np.rint(electrons / gain), 0, 65535)
    with fits.open(path) as hdul:
        data = hdul[0].data
        assert data.dtype == np.uint16 and data.shape == (2, 64, 64)
        np.testing.assert_array_equal(data, expected)
        assert hdul[0].header["BUNIT"] == "DN" and hdul[0].header["GAIN"] == gain
    outside = 5 * rd - 1 if side == "bottom" else adc_range - 5 * rd + 1
    with pytest.raises(ParameterError, match="unit='DN'.*'bias_offset'"):
        write_noise_fits(tmp_path / "out.fits", _gen(params.replace(bias_offset=outside)),
                         2, unit="DN", gain=gain)
    assert _files(tmp_path) == ["dn.fits"]


def test_four_dimensional_for_several_integrations(tmp_path):
    path = tmp_path / "ints.fits"
    write_noise_fits(path, _gen(NIRSPEC_DEFAULTS), 3, nints=2)
    with fits.open(path) as hdul:
        data = hdul[0].data
        assert data.shape == (2, 3, 64, 64)
        np.testing.assert_array_equal(data, _gen(NIRSPEC_DEFAULTS).cube(3, nints=2))
        assert hdul[0].header["NINTS"] == 2 and hdul[0].header["NFRAMES"] == 3


def _parse(value):
    """Header value back to the NoiseParams form: float, tuple, or tuple of pairs."""
    if not isinstance(value, str):
        return value
    if ":" in value:
        return tuple(tuple(float(v) for v in pair.split(":")) for pair in value.split(";"))
    return tuple(float(v) for v in value.split(","))


def test_header_records_every_parameter_seed_and_version(tmp_path):
    params = NoiseParams(rd_noise=(5.0, 6.0, 7.0, 8.0), ref_ratio=0.7, c_pink=2.5,
                         u_pink=(0.0, 1.0, 0.0, 2.0), acn=0.25, pca0=0.3, pedestal=3.5,
                         ktc=25.0, bias_offset=4000.0, bias_amp=400.0,
                         rtn_fraction=0.01, rtn_amp=15.0, rtn_tau_low=0.5,
                         rtn_tau_high=0.25, f_min=2e-4,
                         pink_spectrum=((1.0, 1.0), (100.0, 0.01), (1e5, 1e-5)))
    assert set(KEYWORDS) == {f.name for f in dataclasses.fields(NoiseParams)}
    path = tmp_path / "hdr.fits"
    gen = NoiseGenerator(DET, params, rng=123456789, threads=1)
    write_noise_fits(path, gen, 1)
    hdr = fits.getheader(path)
    for field, key in KEYWORDS.items():
        value = getattr(params, field)
        if field == "pca0_file":
            assert hdr[key] == "synthetic"
        else:
            assert _parse(hdr[key]) == value, (field, hdr[key])
    assert hdr["SEEDENT"] == "123456789"
    assert hdr["SSIMVER"] == metadata.version("scenesim")
    assert hdr["TFRAME"] == pytest.approx(DET.frame_time, rel=1e-12)
    # the recorded seed reproduces the data
    again = NoiseGenerator(DET, params, rng=int(hdr["SEEDENT"]), threads=1).cube(1)[0]
    np.testing.assert_array_equal(fits.getdata(path), again)


def test_spawned_seed_recorded_and_reproducible(tmp_path):
    """A child SeedSequence is recorded as entropy plus spawn key (SEEDENT, SEEDKEY)."""
    child = np.random.SeedSequence(2024).spawn(3)[2]
    path = tmp_path / "child.fits"
    write_noise_fits(path, NoiseGenerator(DET, NIRSPEC_DEFAULTS, rng=child, threads=1), 1)
    hdr = fits.getheader(path)
    assert (hdr["SEEDENT"], hdr["SEEDKEY"]) == ("2024", "2")
    key = tuple(int(k) for k in hdr["SEEDKEY"].split(","))
    again = np.random.SeedSequence(int(hdr["SEEDENT"]), spawn_key=key)
    data = NoiseGenerator(DET, NIRSPEC_DEFAULTS, rng=again, threads=1).cube(1)[0]
    np.testing.assert_array_equal(fits.getdata(path), data)


def test_default_spectrum_recorded_as_one_over_f(tmp_path):
    path = tmp_path / "pink.fits"
    write_noise_fits(path, _gen(ZERO_NOISE), 1)
    assert fits.getheader(path)["PINKSPEC"] == "1/f"


class _FailingGenerator(NoiseGenerator):
    """Yields one frame, then fails as a crashed run would."""

    def frames(self, nreads, reads=None, *, nints=1, integrations=None, dn_gain=None,
               reuse=0):
        it = super().frames(nreads, reads, nints=nints, integrations=integrations,
                            dn_gain=dn_gain, reuse=reuse)
        yield next(it)
        raise RuntimeError("simulated failure midway")


def test_failing_write_leaves_nothing(tmp_path):
    gen = _FailingGenerator(DET, NIRSPEC_DEFAULTS, rng=1, threads=1)
    with pytest.raises(RuntimeError, match="midway"):
        write_noise_fits(tmp_path / "broken.fits", gen, 4)
    assert _files(tmp_path) == []


def test_completed_outputs_lists_only_what_was_renamed_into_place(tmp_path,
                                                                  monkeypatch):
    # what an interrupted command reports as kept (scenesim.cli._interrupted)
    import noise.fitsio as fitsio
    from scenesim import cli
    monkeypatch.setattr(fitsio, "_COMPLETED", [])
    monkeypatch.setattr(fitsio, "_REPLACING", [])
    write_noise_fits(tmp_path / "a.fits", NoiseGenerator(DET, NIRSPEC_DEFAULTS, rng=1,
                                                         threads=1), 2)
    with pytest.raises(RuntimeError):
        write_noise_fits(tmp_path / "b.fits", _FailingGenerator(
            DET, NIRSPEC_DEFAULTS, rng=1, threads=1), 4)
    assert fitsio.completed_outputs() == [str(tmp_path / "a.fits")]
    assert cli._interrupted(" noise", KeyboardInterrupt()) == 130
    monkeypatch.setattr(fitsio, "_COMPLETED", [])
    assert cli._interrupted(" noise", KeyboardInterrupt()) == 130


def test_interrupted_names_the_files_it_keeps(capsys, monkeypatch):
    import noise.fitsio as fitsio
    from scenesim import cli
    monkeypatch.setattr(fitsio, "_COMPLETED", [])
    monkeypatch.setattr(fitsio, "_REPLACING", [])      # other tests' outputs
    cli._interrupted(" run", KeyboardInterrupt())
    assert capsys.readouterr().err == ("scenesim run: interrupted (SIGINT); no partial "
                                       "output was left\n")
    for name in ("x.fits", "x_truth.fits", "x_gls.fits", "a", "b", "c"):
        fitsio.record_completed(name)
    fitsio.record_completed("x.fits")                # once, however often rewritten
    cli._interrupted(" run", KeyboardInterrupt())
    err = capsys.readouterr().err
    assert err.count("\n") == 1
    assert ("the files it had finished are complete and kept ('x.fits', 'x_truth.fits', "
            "'x_gls.fits', 'a' and 2 more); no partial output was left") in err


def test_interrupted_names_the_files_it_was_to_replace_and_did_not(
        tmp_path, capsys, monkeypatch):
    # run --overwrite stopped while fitting: the new exposure and truth beside the
    # earlier run's slope file, which the line had not named
    import noise.fitsio as fitsio
    from scenesim import cli
    from scenesim.outputs import check_outputs
    monkeypatch.setattr(fitsio, "_COMPLETED", [])
    monkeypatch.setattr(fitsio, "_REPLACING", [])
    monkeypatch.chdir(tmp_path)
    for name in ("x.fits", "x_truth.fits", "x_gls.fits"):
        (tmp_path / name).write_text("earlier")
    check_outputs({"exposure": "x.fits", "truth": "x_truth.fits", "fit": "x_gls.fits",
                   "new": "y.fits"}, overwrite=True)
    for name in ("x.fits", "x_truth.fits"):
        fitsio.record_completed(name)
    cli._interrupted(" run", KeyboardInterrupt())
    err = capsys.readouterr().err
    assert err.count("\n") == 1
    assert ("kept ('x.fits', 'x_truth.fits'); 'x_gls.fits' was not rewritten and is "
            "still an earlier run's; no partial output was left") in err
    fitsio.record_completed("x_gls.fits")
    cli._interrupted(" run", KeyboardInterrupt())
    assert "earlier run" not in capsys.readouterr().err


def test_failing_write_keeps_existing_file(tmp_path):
    path = tmp_path / "keep.fits"
    path.write_bytes(b"previous result")
    gen = _FailingGenerator(DET, NIRSPEC_DEFAULTS, rng=1, threads=1)
    with pytest.raises(RuntimeError):
        write_noise_fits(path, gen, 4, overwrite=True)
    assert path.read_bytes() == b"previous result"
    assert _files(tmp_path) == ["keep.fits"]


def test_missing_directory(tmp_path):
    target = tmp_path / "no_such_dir" / "x.fits"
    with pytest.raises(ParameterError, match=r"'path'.*does not exist"):
        write_noise_fits(target, _gen(NIRSPEC_DEFAULTS), 2)
    assert _files(tmp_path) == []


def test_no_overwrite(tmp_path):
    path = tmp_path / "x.fits"
    path.write_bytes(b"keep")
    with pytest.raises(ParameterError, match=r"'path'.*overwrite"):
        write_noise_fits(path, _gen(NIRSPEC_DEFAULTS), 1, overwrite=False)
    assert path.read_bytes() == b"keep" and _files(tmp_path) == ["x.fits"]


@pytest.mark.parametrize("kwargs, name", [
    (dict(unit="ADU"), "unit"), (dict(gain=0.0), "gain"), (dict(gain=float("nan")), "gain"),
    (dict(nints=0), "nints"),
    # old: int() truncated these (2.7 frames became 2, 1.5 integrations 1)
    (dict(nframes=2.7), "nframes"), (dict(nints=1.5), "nints"),
    (dict(nframes="3"), "nframes"), (dict(nframes=True), "nframes"),
    (dict(nframes=0), "nframes"),
])
def test_bad_arguments_write_nothing(tmp_path, kwargs, name):
    nframes = kwargs.pop("nframes", 2)
    with pytest.raises(ParameterError, match=f"'{name}'"):
        write_noise_fits(tmp_path / "x.fits", _gen(NIRSPEC_DEFAULTS), nframes, **kwargs)
    assert _files(tmp_path) == []


# ------------------------------------------------------------------ write-behind
def _record_advice(monkeypatch, fail=False):
    """Record (or refuse, with ``fail``) every posix_fadvise call."""
    calls = []

    def advise(fd, offset, length, advice):
        calls.append((offset, length, advice))
        if fail:
            raise OSError(22, "Invalid argument")

    monkeypatch.setattr(os, "posix_fadvise", advise, raising=False)
    monkeypatch.setattr(os, "POSIX_FADV_DONTNEED", 4, raising=False)
    return calls


def _expected_advice(pieces, lag):
    """Each piece (offset, length) advised when written, and again ``lag`` pieces on."""
    out = []
    for k, piece in enumerate(pieces):
        out.append(piece + (4,))
        if k >= lag:
            out.append(pieces[k - lag] + (4,))
    return out


def test_write_behind_starts_each_piece_and_drops_the_one_lag_pieces_back(
        tmp_path, monkeypatch):
    """After each piece: one call over exactly its new bytes (start its write-back),
    then one over the piece ``lag`` back (drop it); together they cover the file from
    the first piece on, each piece dropped once, the last ``lag`` pieces kept."""
    from noise.fitsio import WriteBehind
    calls = _record_advice(monkeypatch)
    sizes = [10, 4096, 3, 70000, 1, 500]
    with open(tmp_path / "x.bin", "wb", buffering=1 << 16) as f:
        f.write(b"h" * 2880)                       # a header before the first piece
        behind = WriteBehind(f, lag=2, min_bytes=0)
        assert behind.active
        for n in sizes:
            f.write(b"d" * n)
            behind.written()
        behind.written()                           # nothing new: no call
    ends = 2880 + np.cumsum(sizes)
    pieces = [(int(a), int(b - a)) for a, b in zip([2880, *ends[:-1]], ends)]
    assert calls == _expected_advice(pieces, 2)
    assert (tmp_path / "x.bin").read_bytes() == b"h" * 2880 + b"d" * sum(sizes)


def test_write_behind_is_advice_only(tmp_path, monkeypatch):
    """A refused advice turns it off without an error; a gzip stream or a missing
    posix_fadvise leaves it off; the ramp written through it is the generator's."""
    from noise.fitsio import WriteBehind
    calls = _record_advice(monkeypatch, fail=True)
    monkeypatch.setattr(WriteBehind.__init__, "__defaults__", (2, 0))   # every frame
    path = tmp_path / "ramp.fits"
    write_noise_fits(str(path), _gen(NIRSPEC_DEFAULTS), 3)
    assert len(calls) == 1                     # refused once, then off
    with fits.open(path) as hdul:
        np.testing.assert_array_equal(hdul[0].data, _gen(NIRSPEC_DEFAULTS).cube(3)[0])
    import gzip
    with gzip.open(tmp_path / "x.gz", "wb") as gz:
        assert not WriteBehind(gz).active
    monkeypatch.delattr(os, "posix_fadvise")
    with open(tmp_path / "y.bin", "wb") as f:
        assert not WriteBehind(f).active
    with pytest.raises(ParameterError, match="'lag' must be"):
        WriteBehind(None, lag=0)


def test_write_behind_groups_small_pieces(tmp_path, monkeypatch):
    """Pieces smaller than ``min_bytes`` are handed over together, once enough bytes
    have been written since the last piece."""
    from noise.fitsio import WriteBehind
    calls = _record_advice(monkeypatch)
    with open(tmp_path / "x.bin", "wb") as f:
        behind = WriteBehind(f, lag=1, min_bytes=100)
        for _ in range(7):
            f.write(b"d" * 40)
            behind.written()
    # 40, 80: too few; 120: piece [0, 120); 160, 200: too few; 240: piece [120, 240)
    assert calls == _expected_advice([(0, 120), (120, 120)], 1)


def test_noise_ramp_is_written_behind_frame_by_frame(tmp_path, monkeypatch):
    """write_noise_fits hands every frame's bytes to the kernel once, in order, and
    the file holds exactly the ramp (frames of 4 MB and more: one piece each)."""
    from noise.fitsio import WriteBehind
    calls = _record_advice(monkeypatch)
    monkeypatch.setattr(WriteBehind.__init__, "__defaults__", (2, 0))   # every frame
    path = tmp_path / "ramp.fits"
    write_noise_fits(str(path), _gen(NIRSPEC_DEFAULTS), 5)
    frame = 64 * 64 * 4
    head = calls[0][0]                         # the header's bytes are not handed over
    assert head > 0 and head % 2880 == 0
    assert calls == _expected_advice([(head + k * frame, frame) for k in range(5)], 2)
    with fits.open(path) as hdul:
        np.testing.assert_array_equal(hdul[0].data, _gen(NIRSPEC_DEFAULTS).cube(5)[0])


def test_writer_thread_keeps_order_and_raises_a_write_error_once():
    """Writes run in order, one at a time; a failed write's error comes out of the
    next submit (or wait), once; close waits and may be called again."""
    from noise.fitsio import WriterThread
    seen = []

    def write(k):
        if k == 3:
            raise OSError(28, "No space left on device")
        seen.append(k)

    w = WriterThread()
    for k in range(3):
        w.submit(write, k)
    w.submit(write, 3)
    with pytest.raises(OSError, match="No space"):
        w.submit(write, 4)
    w.wait()                                   # the error is not raised twice
    w.submit(write, 5)
    w.close()
    w.close()
    assert seen == [0, 1, 2, 5]


def test_a_target_that_is_not_a_regular_file_is_never_replaced(tmp_path):
    # with overwrite, os.replace would put a regular file where a FIFO (or, as root,
    # a device such as /dev/null) was; tested on a FIFO only
    fifo = tmp_path / "pipe.fits"
    os.mkfifo(fifo)
    gen = NoiseGenerator(DET, NIRSPEC_DEFAULTS, rng=1, threads=1)
    with pytest.raises(ParameterError, match="not a regular file"):
        write_noise_fits(fifo, gen, 2, overwrite=True)
    assert stat.S_ISFIFO(os.stat(fifo).st_mode) and _files(tmp_path) == ["pipe.fits"]


@pytest.mark.parametrize("cards, match", [
    ([("NAXIS", 7, "x")], "structure"), ([("BZERO", 1000.0)], "structure"),
    ([("NAXIS2", 1)], "structure"), ([("GAIN", 3.0)], "scenesim writes itself"),
    ([("X", float("nan"))], "not finite"), ([("X", "caf\u00e9")], "printable ASCII"),
    ([("TOOLONGKEY", 1)], "1-8 characters"), ([("X", [1])], "bool, an integer"),
    ([("X", 1, "\n")], "printable ASCII")])
def test_extra_cards_that_fits_cannot_hold_are_refused(tmp_path, cards, match):
    # before: NAXIS wrote an unreadable file, BZERO shifted the data silently, a
    # 2-tuple (the documented form) raised a bare ValueError
    gen = NoiseGenerator(DET, NIRSPEC_DEFAULTS, rng=1, threads=1)
    with pytest.raises((ParameterError, ParameterTypeError), match=match):
        write_noise_fits(tmp_path / "x.fits", gen, 2, extra_cards=cards)
    assert _files(tmp_path) == []
    write_noise_fits(tmp_path / "y.fits", gen, 2,
                     extra_cards=[("OBSERVER", "me"), ("obsid", np.int64(5), "id")])
    hdr = fits.getheader(tmp_path / "y.fits")
    assert hdr["OBSERVER"] == "me" and hdr["OBSID"] == 5


def test_the_generators_own_template_file_is_never_replaced(tmp_path, monkeypatch):
    """write_noise_fits(path=pca0_file, overwrite=True) replaced the template image the
    generator had read with a noise cube (the command refuses it; the API did not),
    under any spelling or link."""
    template = tmp_path / "tmpl.fits"
    fits.writeto(template, np.random.default_rng(1).standard_normal(DET.shape)
                 .astype(np.float32))
    before = template.read_bytes()
    os.symlink(template, tmp_path / "link.fits")
    gen = NoiseGenerator(DET, NoiseParams(pca0_file=str(template)), rng=2, threads=1)
    monkeypatch.chdir(tmp_path)
    for path in (template, "tmpl.fits", "./tmpl.fits", "link.fits"):
        with pytest.raises(ParameterError, match=r"'pca0_file' \(a file it reads\)"):
            write_noise_fits(path, gen, 1, overwrite=True)
    assert template.read_bytes() == before
    write_noise_fits("other.fits", gen, 1)
