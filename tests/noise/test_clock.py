"""Tests of noise.clock: the one clock, scan directions, subarrays, reference pixels.

Expected values are typed in from the design brief and the paper (Rauscher 2015,
Table 1 and Fig. 5): frame time (ncols_out + nroh) * (nrows + nfoh) * dt, pixel times
as literal tables for a tiny detector, preset values as documented.
"""

import dataclasses
import pickle

import numpy as np
import pytest

from noise.clock import PRESETS, Detector, Subarray, preset
from noise.errors import ParameterError

T_FRAME_H2RG = (512 + 12) * (2048 + 1) * 1e-5     # 10.73676 s (DESIGN.md section 2)


# ------------------------------------------------------------------ frame time
def test_full_h2rg_frame_time():
    det = preset("H2RG")
    assert det.frame_time == pytest.approx(10.73676, rel=1e-12, abs=0)
    assert det.frame_time == pytest.approx(T_FRAME_H2RG, rel=1e-12, abs=0)
    assert det.row_time == pytest.approx(524e-5, rel=1e-12, abs=0)
    assert (det.ncols_out, det.row_samples, det.frame_samples) == (512, 524, 524 * 2049)
    assert det.shape == (2048, 2048) and det.n_out_active == 4


@pytest.mark.slow
def test_full_h2rg_pixel_times():
    det = preset("H2RG")
    t = det.pixel_time()
    assert t.shape == (2048, 2048) and t.dtype == np.float64
    # first pixel read by each output: x = 0, 1023, 1024, 2047 (-> <- -> <-)
    assert t[0, [0, 1023, 1024, 2047]].tolist() == [0.0] * 4
    # last pixel read in a frame: row 2047, x_fast 511
    last = (2047 * 524 + 511) * 1e-5
    for x in (511, 512, 1535, 1536):
        assert t[2047, x] == pytest.approx(last, rel=1e-12)
    assert t.max() == pytest.approx(last, rel=1e-12)
    assert t.max() < det.frame_time
    # every output sees each pixel time once per frame
    for o in range(4):
        assert np.unique(t[:, 512 * o:512 * (o + 1)]).size == 2048 * 512
    # reference border: 2048^2 - 2040^2 pixels
    assert det.reference_mask().sum() == 2048 ** 2 - 2040 ** 2


# ------------------------------------------------------------------ scan order
TINY = Detector(name="tiny", naxis1=16, naxis2=3, n_out=4, nroh=2, nfoh=1, dt=1.0,
                ref_border=1)
# row 0 of TINY, pixel times in units of dt: outputs of 4 columns, -> <- -> <-
TINY_ROW0 = [0, 1, 2, 3, 3, 2, 1, 0, 0, 1, 2, 3, 3, 2, 1, 0]


def test_pixel_time_tiny_literal():
    t = TINY.pixel_time()
    assert t.shape == (3, 16)
    # each row adds (ncols_out + nroh) = 6 pixel times
    expected = np.array([TINY_ROW0, np.add(TINY_ROW0, 6), np.add(TINY_ROW0, 12)])
    np.testing.assert_array_equal(t, expected)
    assert TINY.frame_time == (3 + 1) * (4 + 2) * 1.0
    np.testing.assert_array_equal(TINY.pixel_sample_index(), expected.astype(int))


def test_pixel_time_scales_with_dt():
    det = dataclasses.replace(TINY, dt=1e-5)
    np.testing.assert_allclose(det.pixel_time(), TINY.pixel_time() * 1e-5, rtol=1e-15)


def test_reverse_scan_flips_every_output():
    det = dataclasses.replace(TINY, reverse_scan=True)
    row0 = [3, 2, 1, 0, 0, 1, 2, 3, 3, 2, 1, 0, 0, 1, 2, 3]
    np.testing.assert_array_equal(det.pixel_time()[0], row0)
    assert [det.output_reversed(o) for o in range(4)] == [True, False, True, False]
    assert [TINY.output_reversed(o) for o in range(4)] == [False, True, False, True]


def test_output_of_column():
    np.testing.assert_array_equal(TINY.output_of_column(), np.repeat(np.arange(4), 4))


def test_pixel_times_distinct_within_output():
    det = Detector(naxis1=64, naxis2=32, n_out=4)
    t = det.pixel_time()
    for o in range(4):
        sec = t[:, 16 * o:16 * (o + 1)]
        assert np.unique(sec).size == sec.size
        # read in time order along each output's own fast direction
        if det.output_reversed(o):
            sec = sec[:, ::-1]
        assert np.all(np.diff(sec.ravel()) > 0)


# ------------------------------------------------------------------ subarrays
def test_window_timing():
    det = preset("H2RG").window(100, 200, 64, 32, name="SUB64x32")
    assert det.shape == (32, 64) and (det.x0, det.y0) == (100, 200)
    assert det.n_out_active == 1 and det.ncols_out == 64
    assert det.frame_time == pytest.approx((32 + 1) * (64 + 12) * 1e-5, rel=1e-12)
    y, x = np.mgrid[0:32, 0:64]
    np.testing.assert_allclose(det.pixel_time(), (y * 76 + x) * 1e-5, rtol=1e-15)
    assert det.subarray_name == "SUB64x32"
    # reverse_scan flips the single output
    rev = dataclasses.replace(det, reverse_scan=True)
    np.testing.assert_allclose(rev.pixel_time(), (y * 76 + 63 - x) * 1e-5, rtol=1e-15)


def test_stripe_timing():
    det = preset("H2RG").stripe(1000, 64)
    assert det.shape == (64, 2048) and det.n_out_active == 4 and det.ncols_out == 512
    assert det.frame_time == pytest.approx((64 + 1) * (512 + 12) * 1e-5, rel=1e-12)
    # same clock as the full frame, rows counted from the stripe's first row
    small = Detector(naxis1=128, naxis2=128, n_out=4)
    stripe = small.stripe(40, 16)
    np.testing.assert_array_equal(stripe.pixel_time(), small.pixel_time()[:16])
    assert stripe.frame_time == pytest.approx(17 * 44 * 1e-5, rel=1e-12)


def test_reference_mask_full():
    det = Detector(naxis1=32, naxis2=24, n_out=2, ref_border=4)
    m = det.reference_mask()
    assert m.shape == (24, 32) and m.dtype == bool
    expected = np.ones((24, 32), bool)
    expected[4:20, 4:28] = False
    np.testing.assert_array_equal(m, expected)
    assert not Detector(naxis1=32, naxis2=24, n_out=2, ref_border=0).reference_mask().any()


def test_reference_mask_subarrays():
    full = Detector(naxis1=128, naxis2=128, n_out=4, ref_border=4)
    corner = full.window(0, 0, 16, 16).reference_mask()
    expected = np.zeros((16, 16), bool)
    expected[:4, :] = True
    expected[:, :4] = True
    np.testing.assert_array_equal(corner, expected)
    assert not full.window(40, 40, 16, 16).reference_mask().any()
    top = full.window(120, 120, 8, 8).reference_mask()
    expected = np.zeros((8, 8), bool)
    expected[4:, :] = True
    expected[:, 4:] = True
    np.testing.assert_array_equal(top, expected)
    stripe = full.stripe(122, 6).reference_mask()      # rows 122..127: 124..127 are ref
    np.testing.assert_array_equal(stripe, full.reference_mask()[122:128])
    assert stripe[2:].all() and stripe[:2, :4].all() and not stripe[:2, 4:124].any()


# ------------------------------------------------------------------ presets
#: Documented preset values (detector.py PRESETS comment and Rauscher 2015 Table 1).
DOCUMENTED = {
    "H1RG": dict(naxis1=1024, naxis2=1024, n_out=16, nroh=12, nfoh=1, dt=1e-5,
                 ref_border=4, pixel_pitch=18.0, frame_time=(64 + 12) * 1025 * 1e-5),
    "H2RG": dict(naxis1=2048, naxis2=2048, n_out=4, nroh=12, nfoh=1, dt=1e-5,
                 ref_border=4, pixel_pitch=18.0, frame_time=10.73676),
    "H4RG-10": dict(naxis1=4096, naxis2=4096, n_out=32, nroh=20, nfoh=1, dt=5e-6,
                    ref_border=4, pixel_pitch=10.0, frame_time=3.03178),
    "H4RG-15": dict(naxis1=4096, naxis2=4096, n_out=64, nroh=12, nfoh=1, dt=1e-5,
                    ref_border=4, pixel_pitch=15.0, frame_time=3.11372),
    # JWST (JDox "NIRCam Detector Subarrays"): ((2048/4 + 12)(2048 + 1) + 1) x 10 us
    # = 10.73677 s; a clock of whole rows is one pixel time (1e-5 s) short of it.
    "NIRCAM": dict(naxis1=2048, naxis2=2048, n_out=4, nroh=12, nfoh=1, dt=1e-5,
                   ref_border=4, pixel_pitch=18.0, frame_time=10.73677 - 1e-5),
    "NIRSPEC": dict(naxis1=2048, naxis2=2048, n_out=4, nroh=12, nfoh=1, dt=1e-5,
                    ref_border=4, pixel_pitch=18.0, frame_time=10.73677 - 1e-5),
    # jwst 3.0 irs2_subtract_reference: 712 pixel times per row, tframe 14.5889 s
    "NIRSPEC-IRS2": dict(naxis1=2048, naxis2=2048, n_out=4, nroh=8, nfoh=1, dt=1e-5,
                         ref_border=4, pixel_pitch=18.0, frame_time=14.58888,
                         raw_shape=(2048, 3200), ref_output=True),
    # Roman WFI: romancal's ROMAN_READ_TIME, 3.04 s; 32 outputs, 10 um pixels.
    "WFI": dict(naxis1=4096, naxis2=4096, n_out=32, ref_border=4, pixel_pitch=10.0,
                frame_time=3.04),
}


@pytest.mark.parametrize("name", sorted(DOCUMENTED))
def test_presets_documented_values(name):
    det = preset(name)
    values = dict(DOCUMENTED[name])
    assert det.frame_time == pytest.approx(values.pop("frame_time"), rel=1e-9)
    for field, value in values.items():
        assert getattr(det, field) == value, field
    assert det.name == name and det.subarray is None and not det.reverse_scan


def test_presets_table_complete():
    assert sorted(PRESETS) == sorted(DOCUMENTED)


def test_preset_case_and_changes():
    assert preset("h2rg") == PRESETS["H2RG"]
    det = preset("H2RG", naxis1=128, naxis2=128)
    assert det.shape == (128, 128) and det.n_out == 4 and det.nroh == 12
    assert PRESETS["H2RG"].naxis1 == 2048            # the preset itself is untouched


def test_preset_unknown_name_suggests():
    with pytest.raises(ParameterError, match=r"'preset'.*'H2RGX'.*did you mean 'H2RG'"):
        preset("H2RGX")


def test_preset_takes_every_detector_field_and_names_an_unknown_one():
    # 'name' is a Detector field like the others (it collided with the preset's own
    # argument: TypeError)
    assert preset("H2RG", name="SCA01").name == "SCA01"
    with pytest.raises(ParameterError, match=r"unknown detector field 'naxis'.*naxis1"):
        preset("H2RG", naxis=64)
    with pytest.raises(ParameterError, match=r"'name' must be printable ASCII.*'é'"):
        preset("H2RG", name="é")


# ------------------------------------------------------------------ value object
def test_detector_is_frozen_hashable_picklable():
    det = preset("H2RG").window(8, 8, 32, 32, name="W")
    with pytest.raises(dataclasses.FrozenInstanceError):
        det.naxis1 = 4
    assert hash(det) == hash(pickle.loads(pickle.dumps(det)))
    assert pickle.loads(pickle.dumps(det)) == det
    assert det.full_frame() == preset("H2RG")


def test_header_cards_record_clock():
    det = preset("H2RG").window(100, 200, 64, 32, name="W")
    cards = {k: v for k, v, _ in det.to_header_cards()}
    assert cards["TFRAME"] == pytest.approx((33 * 76) * 1e-5, rel=1e-12)
    assert cards["PIXDWELL"] == 1e-5 and cards["NROH"] == 12 and cards["NFOH"] == 1
    assert (cards["SUBSTRT1"], cards["SUBSTRT2"]) == (101, 201)
    assert (cards["SUBSIZE1"], cards["SUBSIZE2"]) == (64, 32)
    assert cards["NOUTPUTS"] == 1 and cards["NOUTFULL"] == 4
    assert all(len(k) <= 8 for k in cards)


# ------------------------------------------------------------------ bad input
def test_n_out_must_divide_columns():
    with pytest.raises(ParameterError, match=r"'n_out'=3.*'naxis1'=100"):
        Detector(naxis1=100, naxis2=100, n_out=3)


@pytest.mark.parametrize("sub", [
    Subarray("window", 100, 0, 64, 16),       # x0 + nx > 128
    Subarray("window", 0, 120, 16, 16),       # y0 + ny > 128
    Subarray("stripe", 0, 120, 128, 16),      # stripe past the top
])
def test_subarray_outside_detector(sub):
    with pytest.raises(ParameterError, match=r"'subarray'.*outside"):
        Detector(naxis1=128, naxis2=128, n_out=4, subarray=sub)


def test_stripe_must_span_full_width():
    with pytest.raises(ParameterError, match=r"'stripe'.*x0=0 and nx=128"):
        Detector(naxis1=128, naxis2=128, n_out=4,
                 subarray=Subarray("stripe", 0, 0, 64, 16))


@pytest.mark.parametrize("kwargs, name", [
    (dict(dt=0.0), "dt"), (dict(dt=float("nan")), "dt"), (dict(nroh=-1), "nroh"),
    (dict(naxis1=0), "naxis1"), (dict(n_out=2.5), "n_out"),
    (dict(ref_border=64), "ref_border"), (dict(pixel_pitch=-1.0), "pixel_pitch"),
])
def test_bad_detector_fields(kwargs, name):
    with pytest.raises(ParameterError, match=f"'{name}'"):
        Detector(**{"naxis1": 128, "naxis2": 128, "n_out": 4, **kwargs})


@pytest.mark.parametrize("kwargs, name", [
    (dict(kind="box"), "subarray.kind"), (dict(x0=-1), "subarray.x0"),
    (dict(ny=0), "subarray.ny"),
])
def test_bad_subarray_fields(kwargs, name):
    args = {"kind": "window", "x0": 0, "y0": 0, "nx": 8, "ny": 8, **kwargs}
    with pytest.raises(ParameterError, match=f"'{name}'"):
        Subarray(**args)


def test_frame_slot_is_the_documented_time_line():
    # each integration is one reset slot followed by its nreads read slots
    from noise.clock import exposure_slots, frame_slot
    nreads = 4
    layout = []
    for i in range(3):
        layout += [("reset", i, None)] + [("read", i, k) for k in range(nreads)]
    for s, (kind, i, k) in enumerate(layout):
        if kind == "read":
            assert frame_slot(i, k, nreads) == s
    assert exposure_slots(3, nreads) == len(layout)
    i = np.arange(3)[:, None]
    k = np.arange(nreads)[None, :]
    assert frame_slot(i, k, nreads).shape == (3, nreads)
