"""The IRS2 clock (noise.clock.Interleave, Detector.ref_output): frame time, slots of
the normal and interleaved samples, the raw layout, headers and bad input.

Expected values: the layout of the jwst 3.0 pipeline's IRS2 code
(jwst/refpix/irs2_subtract_reference.py): per output 512 normal pixels and 32
excursions of 4 reference samples (640 samples), a reference output first, 3200 x
2048 raw samples; in time order ``(scipix_n + refpix_r + 2) * 512 / scipix_n + pad =
712`` pixel times per row, normal sample ``n`` at ``n + (refpix_r + 2) * ((n +
scipix_n/2) // scipix_n)`` and reference sample ``m`` at ``m + (scipix_n + 2) * (m //
refpix_r) + scipix_n/2 + 1`` (jwst's ``hnorm1`` and ``href1``, typed in here as the
specification), tframe 14.5889 s.
"""

import dataclasses

import numpy as np
import pytest

from noise.clock import Detector, Interleave, detector_from_header, preset
from noise.errors import ParameterError, ParameterTypeError
from astropy.io import fits

IRS2 = preset("NIRSPEC-IRS2")


def test_nirspec_irs2_numbers():
    assert IRS2.interleave == Interleave(16, 4, 1) and IRS2.ref_output
    assert IRS2.row_samples == 712                       # (16 + 4 + 2) * 32 + 8
    assert IRS2.raw_ncols_out == 640 and IRS2.raw_shape == (2048, 3200)
    # 712 * (2048 + 1) pixel times of 10 us; jwst's comment: 14.5889 s
    assert IRS2.frame_time == pytest.approx(712 * 2049 * 1e-5, rel=1e-12)
    assert round(IRS2.frame_time, 4) == 14.5889
    assert IRS2.shape == (2048, 2048)                    # the image stays 2048^2


def _jwst_slots(scipix_n=16, refpix_r=4, n=512):
    """jwst's hnorm/href (raw positions) and hnorm1/href1 (time slots), one output."""
    ind_n = np.arange(n)
    ind_ref = np.arange(n // scipix_n * refpix_r)
    hnorm = ind_n + refpix_r * ((ind_n + scipix_n // 2) // scipix_n)
    href = ind_ref + scipix_n * (ind_ref // refpix_r) + scipix_n // 2
    hnorm1 = ind_n + (refpix_r + 2) * ((ind_n + scipix_n // 2) // scipix_n)
    href1 = ind_ref + (scipix_n + 2) * (ind_ref // refpix_r) + scipix_n // 2 + 1
    slot = np.empty(n + ind_ref.size, dtype=int)
    slot[hnorm] = hnorm1
    slot[href] = href1
    return slot, hnorm


def test_slots_match_jwst_formulas():
    output, slot, image_x = IRS2.raw_columns()
    jslot, hnorm = _jwst_slots()
    sec = [slice(640 * k, 640 * (k + 1)) for k in range(5)]
    # jwst flips sections 0, 2, 4 (the reference output, outputs 2 and 4) into time order
    for k in range(5):
        s = slot[sec[k]][::-1] if k in (0, 2, 4) else slot[sec[k]]
        assert np.array_equal(s, jslot), k
        assert np.all(output[sec[k]] == k - 1)
    # output 0 (section 1): the normal samples are image columns 0..511 in order
    x1 = image_x[sec[1]]
    assert np.array_equal(np.flatnonzero(x1 >= 0), hnorm)
    assert np.array_equal(x1[hnorm], np.arange(512))
    # every raw sample of an output has its own slot, inside the row, before the nroh
    assert np.unique(jslot).size == 640 and jslot.max() == 703 == 712 - 8 - 1


def test_mask_matches_jwst():
    irs2 = pytest.importorskip("jwst.refpix.irs2_subtract_reference")
    mask = irs2.make_irs2_mask(3200, 2048, 16, 4)        # True: a normal pixel
    _, _, image_x = IRS2.raw_columns()
    assert np.array_equal(mask, image_x >= 0)


def test_image_pixel_times_skip_interleaved_slots():
    t = IRS2.pixel_sample_index()
    # output 0 of row 0: 8 normal, then the jump, 4 reference samples, the jump
    assert t[0, :10].tolist() == [0, 1, 2, 3, 4, 5, 6, 7, 14, 15]
    # output 1 runs right to left: column 1023 is read first
    assert t[0, 1023] == 0 and t[0, 1015] == 14
    assert t[1, 0] == 712
    assert np.array_equal(IRS2.pixel_time(), t * 1e-5)
    # the raw sample index holds the image's for the normal samples
    _, _, image_x = IRS2.raw_columns()
    raw = IRS2.raw_sample_index()
    normal = image_x >= 0
    assert np.array_equal(raw[:, normal], t[:, image_x[normal]])


def test_tiny_literal_row():
    # 2 outputs of 8 columns, 4 normal between excursions of 2 samples, jump 1, nroh 2
    det = Detector(name="tiny", naxis1=16, naxis2=3, n_out=2, nroh=2, nfoh=1, dt=1.0,
                   ref_border=1, interleave=Interleave(4, 2, 1), ref_output=True)
    # row: N N j R R j N N N N j R R j N N + 2 overhead = 18
    assert det.row_samples == 18 and det.frame_time == 18 * 4
    assert det.normal_slots().tolist() == [0, 1, 6, 7, 8, 9, 14, 15]
    assert det.reference_slots().tolist() == [3, 4, 11, 12]
    output, slot, image_x = det.raw_columns()
    assert output.tolist() == [-1] * 12 + [0] * 12 + [1] * 12
    assert slot[:12].tolist() == [15, 14, 12, 11, 9, 8, 7, 6, 4, 3, 1, 0]   # mirrored
    assert slot[12:24].tolist() == [0, 1, 3, 4, 6, 7, 8, 9, 11, 12, 14, 15]
    assert image_x[12:24].tolist() == [0, 1, -1, -1, 2, 3, 4, 5, -1, -1, 6, 7]
    # output 1 reads right to left: its block is in column order, its slots mirrored
    assert image_x[24:].tolist() == [8, 9, -1, -1, 10, 11, 12, 13, -1, -1, 14, 15]
    assert slot[24:].tolist() == slot[:12].tolist()
    assert det.pixel_sample_index()[1, 8:].tolist() == [18 + t for t in
                                                        (15, 14, 9, 8, 7, 6, 1, 0)]


def test_stripe_and_plain_reference_output():
    st = IRS2.stripe(1000, 32)
    assert st.raw_shape == (32, 3200) and st.frame_time == pytest.approx(712 * 33e-5)
    h2 = preset("H2RG", ref_output=True)           # Roman's amp33 style: no interleave
    assert h2.row_samples == 524 and h2.raw_shape == (2048, 2560)
    assert h2.frame_time == preset("H2RG").frame_time


def test_header_round_trip_and_plain_cards_unchanged():
    for det in (IRS2, IRS2.stripe(8, 16, "S16"), preset("H2RG", ref_output=True)):
        hdr = fits.Header([fits.Card(*c) for c in det.to_header_cards()])
        assert detector_from_header(hdr) == det
    keys = [c[0] for c in preset("H2RG").to_header_cards()]
    assert not {"NRS_NORM", "NRS_REF", "NRS_JUMP", "REFOUT"} & set(keys)


def test_interleave_from_table_or_list():
    a = dataclasses.replace(preset("NIRSPEC"), interleave={"normal": 16, "reference": 4})
    b = dataclasses.replace(preset("NIRSPEC"), interleave=[16, 4, 1])
    assert a.interleave == b.interleave == Interleave(16, 4, 1)


@pytest.mark.parametrize("change, words", [
    (dict(interleave=Interleave(16, 4, 1), subarray=None), None),
    (dict(interleave=Interleave(24, 4, 1)), ["'interleave.normal'=24", "512"]),
    (dict(interleave={"normal": 16, "refs": 4}), ["'interleave'", "'refs'"]),
    (dict(ref_output="yes"), ["'ref_output'"]),
])
def test_bad_detector_changes(change, words):
    if words is None:
        Detector(**change)
        return
    with pytest.raises((ParameterError, ParameterTypeError)) as err:
        Detector(**change)
    for w in words:
        assert w in str(err.value)


@pytest.mark.parametrize("args, words", [
    ((15, 4, 1), ["'interleave.normal'", "even", "15"]),
    ((16, 3, 1), ["'interleave.reference'", "even", "3"]),
    ((16, 4, -1), ["'interleave.jump'", "-1"]),
])
def test_bad_interleave(args, words):
    with pytest.raises(ParameterError) as err:
        Interleave(*args)
    for w in words:
        assert w in str(err.value)


def test_window_refused():
    with pytest.raises(ParameterError, match="'interleave' needs every output"):
        IRS2.window(0, 0, 64, 64)
    with pytest.raises(ParameterError, match="'ref_output' needs every output"):
        preset("H2RG", ref_output=True).window(0, 0, 64, 64)
