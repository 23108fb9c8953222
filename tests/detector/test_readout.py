"""Tests of scenesim.detector.readout: read patterns, read times, tau, slots and file round trips.

Expected values are written independently of the module: closed forms for MULTIACCUM
mean times and for tau, brute-force double sums for tau, literal slot tables, and a
seeded Poisson simulation for the meaning of t_bar and tau.
"""

import dataclasses
import io
import math
import pickle

import numpy as np
import pytest
from astropy.io import fits
from astropy.table import Table

from noise.errors import FileFormatError, ParameterError
from scenesim.detector.readout import (
    NAMED_PATTERNS,
    ROMAN_LIKE_SKIP_TABLE,
    ROMAN_LIKE_TABLE,
    Readout,
)

T_FRAME = 10.73676  # s, full-frame H2RG frame time (DESIGN.md section 2)

# The documented JDox values, typed in again here so a typo in the module is caught.
JDOX = {
    "RAPID": (1, 0), "BRIGHT1": (1, 1), "BRIGHT2": (2, 0), "SHALLOW2": (2, 3),
    "SHALLOW4": (4, 1), "MEDIUM2": (2, 8), "MEDIUM8": (8, 2), "DEEP2": (2, 18),
    "DEEP8": (8, 12), "NRSRAPID": (1, 0), "NRS": (4, 0),
    # NIRSpec's traditional patterns with dropped frames (JDox "NIRSpec Detector
    # Readout Modes and Patterns"), and NIRISS's (a probe found them missing)
    "NRSRAPIDD1": (1, 1), "NRSRAPIDD2": (1, 2), "NRSRAPIDD6": (1, 6),
    "NISRAPID": (1, 0), "NIS": (4, 0),
    # IRS2: group times 14.589 s and 72.944 s in JWST planning tools (1 and 5 frames
    # of 14.5889 s)
    "NRSIRS2RAPID": (1, 0), "NRSIRS2": (5, 0),
}


def _tau_brute(times):
    """Poisson variance per unit rate of the mean of reads at ``times``.

    A Poisson process N(t) of unit rate has Cov(N(s), N(t)) = min(s, t), so
    Var(mean_k N(t_k)) = (1/N^2) sum_j sum_k min(t_j, t_k).
    """
    t = np.asarray(times, dtype=float)
    return np.minimum(t[:, None], t[None, :]).sum() / t.size ** 2


# ------------------------------------------------------------------ named patterns
def test_named_patterns_table_matches_jdox():
    assert NAMED_PATTERNS == JDOX


@pytest.mark.parametrize("pattern", sorted(JDOX))
def test_named_pattern_reads_times_and_tgroup(pattern):
    nf, gg = JDOX[pattern]
    ngroups = 4
    ro = Readout.named(pattern.lower(), ngroups)  # case-insensitive
    assert ro.name == pattern
    assert (ro.nframes, ro.groupgap, ro.nskip, ro.ngroups) == (nf, gg, 0, ngroups)
    expected = tuple(tuple(g * (nf + gg) + j for j in range(nf)) for g in range(ngroups))
    assert ro.resultants == expected
    assert ro.nreads == (ngroups - 1) * (nf + gg) + nf
    assert ro.is_uniform
    assert ro.tgroup(T_FRAME) == pytest.approx((nf + gg) * T_FRAME, rel=1e-14)
    # Rolling reset: read k at (k+1) t_frame, so the mean of reads s..s+nf-1 is
    # t_frame * (s + (nf + 1)/2).
    g = np.arange(ngroups)
    tbar = T_FRAME * (g * (nf + gg) + (nf + 1) / 2)
    np.testing.assert_allclose(ro.mean_times(T_FRAME), tbar, rtol=1e-14)


def test_multiaccum_with_nskip_closed_form():
    nf, ng, gg, nskip = 3, 5, 2, 4
    ro = Readout.multiaccum(nf, ng, groupgap=gg, nskip=nskip, nints=2)
    assert ro.resultants[0] == (4, 5, 6)
    assert ro.resultants[-1] == (24, 25, 26)
    assert ro.nreads == nskip + (ng - 1) * (nf + gg) + nf
    g = np.arange(ng)
    tbar = T_FRAME * (nskip + g * (nf + gg) + (nf + 1) / 2)
    np.testing.assert_allclose(ro.mean_times(T_FRAME), tbar, rtol=1e-14)
    assert ro.tgroup(T_FRAME) == pytest.approx((nf + gg) * T_FRAME, rel=1e-14)


# ------------------------------------------------------------------ tau
@pytest.mark.parametrize("nreads", [1, 2, 3, 5, 8, 17])
@pytest.mark.parametrize("first", [0, 6])
def test_tau_consecutive_reads_closed_form(nreads, first):
    # N reads at t_k = t0 + (k-1) d: tau = t0 + d (N-1)(2N-1)/(6N), from
    # sum_{j=0}^{N-1} (2N-2j-1) j = N(N-1)(2N-1)/6.
    ro = Readout.from_reads([range(first, first + nreads)])
    t0, d = (first + 1) * T_FRAME, T_FRAME
    closed = t0 + d * (nreads - 1) * (2 * nreads - 1) / (6 * nreads)
    times = t0 + d * np.arange(nreads)
    assert ro.tau(T_FRAME)[0] == pytest.approx(closed, rel=1e-13)
    assert ro.tau(T_FRAME)[0] == pytest.approx(_tau_brute(times), rel=1e-13)
    if nreads == 1:
        assert ro.tau(T_FRAME)[0] == pytest.approx(t0, rel=1e-15)


def test_tau_uneven_reads_brute_force():
    reads = [[0], [2, 3], [7, 9, 10, 15], [16, 30]]
    ro = Readout.from_reads(reads)
    expected = [_tau_brute((np.asarray(r) + 1) * T_FRAME) for r in reads]
    np.testing.assert_allclose(ro.tau(T_FRAME), expected, rtol=1e-13)


def test_tbar_and_tau_are_poisson_mean_and_variance():
    # A constant rate f over a seeded Poisson ramp: E[R] = f t_bar and Var[R] = f tau.
    ro = Readout.from_ma_table(ROMAN_LIKE_SKIP_TABLE)
    t_frame, flux, npix = 3.0, 50.0, 20000
    rng = np.random.default_rng(20240531)
    t = np.concatenate(ro.read_times(t_frame))
    increments = rng.poisson(flux * np.diff(t, prepend=0.0)[:, None], size=(t.size, npix))
    resultants = ro.resultant_matrix() @ np.cumsum(increments, axis=0)
    tbar, tau = ro.mean_times(t_frame), ro.tau(t_frame)
    var_true = flux * tau
    # Mean of n samples: sigma = sqrt(Var/n); 5 sigma.
    np.testing.assert_array_less(np.abs(resultants.mean(axis=1) - flux * tbar),
                                 5 * np.sqrt(var_true / npix))
    # Sample variance: Var(s^2)/sigma^4 = 2/(n-1) + kappa/n, with the excess kurtosis
    # of a weighted sum of Poisson increments (weights <= 1) kappa <= 1/Var; 5 sigma.
    rel_sigma = np.sqrt(2 / (npix - 1) + 1 / (var_true * npix))
    ratio = resultants.var(axis=1, ddof=1) / var_true
    np.testing.assert_array_less(np.abs(ratio - 1), 5 * rel_sigma)


# ------------------------------------------------------------------ reset modes
def test_global_reset_shifts_times_by_pixel_time_minus_t_frame():
    rolling = Readout.from_ma_table(ROMAN_LIKE_SKIP_TABLE)
    glob = dataclasses.replace(rolling, reset_mode="global")
    pix = np.array([[0.0, 1e-3, 2.5], [0.7, 5.0, 10.0]])  # s, shape (2, 3)
    shift = pix - T_FRAME
    for r_roll, r_glob, reads in zip(rolling.read_times(T_FRAME, pix),
                                     glob.read_times(T_FRAME, pix), rolling.resultants):
        k = np.asarray(reads, dtype=float)[:, None, None]
        assert r_glob.shape == (len(reads), 2, 3)
        np.testing.assert_allclose(r_roll, np.broadcast_to((k + 1) * T_FRAME, r_roll.shape),
                                   rtol=1e-14)
        np.testing.assert_allclose(r_glob, k * T_FRAME + pix, rtol=1e-14, atol=1e-12)
        np.testing.assert_allclose(r_glob - r_roll, np.broadcast_to(shift, r_glob.shape),
                                   atol=1e-12)
    for method in ("mean_times", "tau"):
        roll_t = getattr(rolling, method)(T_FRAME, pix)
        glob_t = getattr(glob, method)(T_FRAME, pix)
        assert glob_t.shape == (rolling.ngroups, 2, 3)
        np.testing.assert_allclose(glob_t - roll_t, np.broadcast_to(shift, glob_t.shape),
                                   atol=1e-12)
    # Rolling reset: every pixel has the same times; tgroup does not depend on mode.
    np.testing.assert_array_equal(rolling.mean_times(T_FRAME, pix)[:, 1, 2],
                                  rolling.mean_times(T_FRAME))
    assert glob.tgroup(T_FRAME) == pytest.approx(rolling.tgroup(T_FRAME), rel=1e-14)


# ------------------------------------------------------------------ slots and matrix
def test_frame_slots_three_integrations():
    ro = Readout.multiaccum(2, 3, groupgap=1, nints=3)  # reads 0,1 3,4 6,7; nreads 8
    assert ro.needed_reads == (0, 1, 3, 4, 6, 7)
    assert ro.nreads == 8
    expected = np.array([[1, 2, 4, 5, 7, 8],
                         [10, 11, 13, 14, 16, 17],
                         [19, 20, 22, 23, 25, 26]])
    slots = ro.frame_slots()
    assert slots.shape == (3, 6)
    np.testing.assert_array_equal(slots, expected)


@pytest.mark.parametrize("readout", [
    Readout.named("MEDIUM8", 5),
    Readout.from_ma_table(ROMAN_LIKE_TABLE),
    Readout.from_ma_table(ROMAN_LIKE_SKIP_TABLE, reset_mode="global"),
])
def test_resultant_matrix_averages_reads(readout):
    mat = readout.resultant_matrix()
    assert mat.shape == (readout.ngroups, len(readout.needed_reads))
    np.testing.assert_allclose(mat.sum(axis=1), 1.0, rtol=1e-15)
    np.testing.assert_array_equal((mat > 0).sum(axis=1), readout.n_per_resultant)
    pix = np.array([0.3, 4.0])
    times = np.concatenate(readout.read_times(T_FRAME, pix), axis=0)  # (nneeded, 2)
    np.testing.assert_allclose(mat @ times, readout.mean_times(T_FRAME, pix), rtol=1e-14)


# ------------------------------------------------------------------ MA tables
def test_roman_like_table_contiguous():
    ro = Readout.from_ma_table(ROMAN_LIKE_TABLE)
    assert ro.name == "MA_TABLE"
    assert ro.ngroups == 9
    np.testing.assert_array_equal(ro.n_per_resultant, [1, 2, 3, 4, 6, 6, 8, 8, 6])
    assert ro.nreads == 44
    assert ro.needed_reads == tuple(range(44))
    assert not ro.is_uniform
    # tgroup of a non-MULTIACCUM readout: mean t_bar spacing.  First resultant is read
    # 0 at t_frame; last is reads 38..43, mean (38+43)/2 + 1 = 41.5 frames.
    assert ro.tgroup(T_FRAME) == pytest.approx((41.5 - 1.0) / 8 * T_FRAME, rel=1e-14)


def test_ma_table_skipping_reads():
    ro = Readout.from_ma_table(ROMAN_LIKE_SKIP_TABLE)
    skipped = {2, 5, 6, 7, 12, 13, 14, 15, 20, 21, 22, 23, 24, 25, 26, 27}
    assert ro.ngroups == 6
    assert ro.nreads == 36  # last read used is 35; skipped reads still count
    assert ro.needed_reads == tuple(k for k in range(36) if k not in skipped)
    assert len(ro.needed_reads) == 20
    assert ro.frame_slots().shape == (1, 20)
    assert ro.resultants[3] == (8, 9, 10, 11)


def test_is_uniform_cases():
    assert Readout.from_reads([[0, 2], [4, 6], [8, 10]]).is_uniform
    assert Readout.from_reads([[3, 4, 5]]).is_uniform
    assert not Readout.from_reads([[0, 1], [3, 4], [5, 6]]).is_uniform  # uneven starts
    assert not Readout.from_reads([[0, 1], [4, 6]]).is_uniform  # different layout
    assert not Readout.from_reads([[0], [1, 2]]).is_uniform  # different sizes


def test_tgroup_single_custom_resultant():
    assert Readout.from_reads([[2, 3, 4]]).tgroup(T_FRAME) == pytest.approx(3 * T_FRAME)


# ------------------------------------------------------------------ headers and tables
@pytest.mark.parametrize("reads", [[[5], [7, 8]], [[3, 4, 5], [9]], [[1], [2], [4]]])
def test_dropped_frames_of_read_lists_are_the_first_read(reads):
    # DROPFRM1 counts the frames after the reset that no resultant reads: for read
    # lists that are not a MULTIACCUM pattern it had been written 0 (a probe:
    # [[5], [7, 8]] drops 5 frames), and a truth without its READS table rebuilt
    # from it would have read from the reset
    ro = Readout.from_reads(reads)
    assert not ro.is_multiaccum
    assert dict((k, v) for k, v, _ in ro.to_header_cards(T_FRAME))["DROPFRM1"] == \
        reads[0][0]
    assert ro.read_table(T_FRAME).meta["DROPFRM1"] == reads[0][0]
    assert Readout(tuple(map(tuple, reads)), nskip=0).nskip == reads[0][0]


def test_header_cards_multiaccum():
    ro = Readout.named("SHALLOW4", 6, nints=3)
    cards = ro.to_header_cards(T_FRAME)
    keys = [c[0] for c in cards]
    assert keys == ["NINTS", "NGROUPS", "NFRAMES", "GROUPGAP", "DROPFRM1", "READPATT",
                    "TFRAME", "TGROUP", "RESETMD", "NREADS", "EFFINTTM"]
    assert all(len(k) <= 8 for k in keys)
    values = {k: v for k, v, _ in cards}
    assert values["NINTS"] == 3 and values["NGROUPS"] == 6
    assert values["NFRAMES"] == 4 and values["GROUPGAP"] == 1
    assert values["READPATT"] == "SHALLOW4" and values["RESETMD"] == "rolling"
    assert values["NREADS"] == 5 * 5 + 4
    assert values["TGROUP"] == pytest.approx(5 * T_FRAME, rel=1e-14)
    # Evenly spaced groups: t_bar_last - t_bar_first = (ngroups - 1) tgroup.
    assert values["EFFINTTM"] == pytest.approx(5 * 5 * T_FRAME, rel=1e-14)
    hdr = fits.Header(cards)  # every card is a valid FITS card
    assert hdr["TFRAME"] == pytest.approx(T_FRAME)


def test_header_cards_custom_readout():
    ro = Readout.from_ma_table(ROMAN_LIKE_SKIP_TABLE)
    values = {k: v for k, v, _ in ro.to_header_cards(3.0)}
    assert values["NFRAMES"] == 1  # size of the first resultant
    assert values["GROUPGAP"] == 0  # read 1 follows read 0 directly
    assert values["NREADS"] == 36
    # Rolling read k at (k+1) t_frame: t_bar of reads 28..35 is (31.5 + 1) frames, of
    # read 0 one frame, so EFFINTTM = 31.5 frames of 3 s.
    assert values["EFFINTTM"] == pytest.approx(31.5 * 3.0, rel=1e-14)


ROUND_TRIP = [
    Readout.named("DEEP8", 4, nints=2),
    Readout.multiaccum(3, 5, groupgap=2, nskip=4, reset_mode="global", name="X"),
    Readout.from_ma_table(ROMAN_LIKE_TABLE),
    Readout.from_ma_table(ROMAN_LIKE_SKIP_TABLE, nints=3, reset_mode="global"),
    Readout.from_reads([[0], [1], [5]]),
]


@pytest.mark.parametrize("readout", ROUND_TRIP)
def test_read_table_round_trip(readout):
    table = readout.read_table(T_FRAME)
    assert len(table) == readout.ngroups
    width = int(readout.n_per_resultant.max())
    assert table["READS"].shape == (readout.ngroups, width)
    for row, reads in zip(table, readout.resultants):
        n = len(reads)
        assert row["NREADS"] == n and row["FIRST_READ"] == reads[0]
        assert tuple(row["READS"][:n]) == reads
        assert np.all(row["READS"][n:] == -1)
        assert np.all(np.isnan(row["READ_TIMES"][n:]))
    np.testing.assert_allclose(table["TMEAN"], readout.mean_times(T_FRAME), rtol=1e-15)
    np.testing.assert_allclose(table["TAU"], readout.tau(T_FRAME), rtol=1e-15)
    kwargs = dict(nints=readout.nints, reset_mode=readout.reset_mode, name=readout.name)
    assert Readout.from_read_table(table, **kwargs) == readout
    # Through a FITS binary table in memory.
    buf = io.BytesIO()
    fits.HDUList([fits.PrimaryHDU(), fits.table_to_hdu(table)]).writeto(buf)
    buf.seek(0)
    back = Table.read(buf, hdu=1)
    assert Readout.from_read_table(back, **kwargs) == readout


def test_from_read_table_ignores_custom_header_nframes():
    # Cards of a custom readout copied beside the table must not make it MULTIACCUM.
    ro = Readout.from_ma_table(ROMAN_LIKE_TABLE)
    table = ro.read_table(T_FRAME)
    table.meta.update({k: v for k, v, _ in ro.to_header_cards(T_FRAME)})
    assert Readout.from_read_table(table, nints=1, reset_mode="rolling",
                                   name="MA_TABLE") == ro


def test_from_read_table_bad_tables():
    table = Readout.named("RAPID", 3).read_table(T_FRAME)
    kwargs = dict(nints=1, reset_mode="rolling", name="RAPID")
    with pytest.raises(FileFormatError, match="READS"):
        Readout.from_read_table(table[["RESULTANT", "NREADS"]], **kwargs)
    bad = table.copy()
    bad["NREADS"][1] = 2
    with pytest.raises(FileFormatError, match="NREADS"):
        Readout.from_read_table(bad, **kwargs)
    bad = table.copy()
    bad["READS"][2] = [0]
    bad["FIRST_READ"][2] = 0
    with pytest.raises(FileFormatError, match="increasing"):
        Readout.from_read_table(bad, **kwargs)
    with pytest.raises(ParameterError, match="'nints'"):
        Readout.from_read_table(table, nints=0, reset_mode="rolling", name="RAPID")


# ------------------------------------------------------------------ value semantics
def test_frozen_hashable_picklable_and_normalised():
    a = Readout([[0, 1], [np.int64(2)]])
    b = Readout(((0, 1), (2,)))
    assert a == b and hash(a) == hash(b) and len({a, b}) == 1
    assert a.resultants == ((0, 1), (2,))
    assert pickle.loads(pickle.dumps(a)) == a
    with pytest.raises(dataclasses.FrozenInstanceError):
        a.nints = 2
    assert Readout.named("nrs", 2) == Readout.multiaccum(4, 2, name="NRS")


# ------------------------------------------------------------------ validation
BAD_INPUTS = [
    ("pattern", "DEEEP8", lambda: Readout.named("DEEEP8", 2)),
    ("pattern", "None", lambda: Readout.named(None, 2)),
    ("ngroups", "0", lambda: Readout.named("RAPID", 0)),
    ("ngroups", "0", lambda: Readout.multiaccum(1, 0)),
    ("nframes", "0", lambda: Readout.multiaccum(0, 3)),
    ("nframes", "1.5", lambda: Readout.multiaccum(1.5, 3)),
    ("nints", "0", lambda: Readout.multiaccum(1, 3, nints=0)),
    ("nints", "True", lambda: Readout(((0,),), nints=True)),
    ("groupgap", "-1", lambda: Readout.multiaccum(1, 3, groupgap=-1)),
    ("nskip", "-2", lambda: Readout.multiaccum(1, 3, nskip=-2)),
    ("reset_mode", "'Rolling'", lambda: Readout.multiaccum(1, 3, reset_mode="Rolling")),
    ("reset_mode", "'both'", lambda: Readout.from_reads([[0]], reset_mode="both")),
    ("read_lists", "empty", lambda: Readout.from_reads([[0], []])),
    ("read_lists", "[]", lambda: Readout.from_reads([])),
    ("read_lists", "-1", lambda: Readout.from_reads([[-1, 0]])),
    ("read_lists", "read 0 after read 1", lambda: Readout.from_reads([[1, 0]])),
    ("read_lists", "read 1 after read 1", lambda: Readout.from_reads([[0, 1], [1, 2]])),
    ("read_lists", "0.5", lambda: Readout.from_reads([[0.5]])),
    ("table", "non-increasing", lambda: Readout.from_ma_table([(0, 2), (1, 2)])),
    ("table", "non-increasing", lambda: Readout.from_ma_table([(5, 1), (2, 1)])),
    ("table[1] nreads", "0", lambda: Readout.from_ma_table([(0, 1), (1, 0)])),
    ("table[0] first_read", "-1", lambda: Readout.from_ma_table([(-1, 2)])),
    ("table", "pair", lambda: Readout.from_ma_table([(0, 1, 2)])),
    ("table", "[]", lambda: Readout.from_ma_table([])),
    ("resultants", "empty", lambda: Readout(((0,), ()))),
    ("resultants", "read 3 after read 4", lambda: Readout(((2, 4), (3,)))),
    ("resultants", "-3", lambda: Readout(((-3,),))),
    ("resultants", "MULTIACCUM", lambda: Readout(((0, 1), (3, 4)), nframes=2,
                                                 groupgap=0)),
    ("groupgap", "None", lambda: Readout(((0, 1),), nframes=2)),
    ("nskip", "3", lambda: Readout(((1, 2),), nskip=3)),
    ("name", "''", lambda: Readout(((0,),), name="")),
    ("t_frame", "0", lambda: Readout.named("RAPID", 2).mean_times(0)),
    ("t_frame", "nan", lambda: Readout.named("RAPID", 2).tgroup(math.nan)),
    ("pixel_time", "-1.0", lambda: Readout.named("RAPID", 2).read_times(1.0, [0.0, -1.0])),
]


@pytest.mark.parametrize("param, bad, call", BAD_INPUTS,
                         ids=[f"{p}-{b}" for p, b, _ in BAD_INPUTS])
def test_bad_input_raises_parameter_error(param, bad, call):
    with pytest.raises(ParameterError) as info:
        call()
    message = str(info.value)
    assert f"'{param}" in message
    assert bad in message


def test_unknown_pattern_suggests_nearest():
    with pytest.raises(ParameterError, match="did you mean 'DEEP8'"):
        Readout.named("deep9", 3)


@pytest.mark.parametrize("det_name, pattern, match", [
    ("NIRSPEC-IRS2", "NRSRAPID", r"'NRSRAPID' is not an IRS2 pattern, but detector "
                                 r"'NIRSPEC-IRS2' interleaves"),
    ("NIRSPEC-IRS2", "NRS", r"'NRS' is not an IRS2 pattern"),
    ("NIRSPEC-IRS2", "NRSRAPIDD6", r"'NRSRAPIDD6' is not an IRS2 pattern"),
    ("NIRSPEC", "NRSIRS2RAPID", r"'NRSIRS2RAPID' is an IRS2 pattern, but detector "
                                r"'NIRSPEC' has no interleaved"),
    ("H2RG", "NRSIRS2", r"'NRSIRS2' is an IRS2 pattern"),
])
def test_a_named_pattern_that_contradicts_the_detector_is_refused(det_name, pattern,
                                                                   match):
    """Before, an IRS2 detector read with NRSRAPID wrote an uncal of the IRS2 layout
    (3200 columns, 14.589 s frames) that said READPATT 'NRSRAPID', and the reverse an
    ordinary frame that said 'NRSIRS2RAPID': jwst tells IRS2 data by its shape and
    picks reference files by READPATT.  Refused by the engine and the scene alike."""
    from noise.clock import preset

    from scenesim.engine import ChargeEngine
    from scenesim.scene import parse_scene

    det = preset(det_name, naxis1=64, naxis2=64)
    with pytest.raises(ParameterError, match=match):
        ChargeEngine(det, Readout.named(pattern, ngroups=2), rng=1)
    with pytest.raises(ParameterError, match=r"^\[readout\] 'pattern' = " + match):
        parse_scene({"detector": {"preset": det_name, "naxis1": 64, "naxis2": 64},
                     "readout": {"pattern": pattern, "ngroups": 2}})
    # the unnamed forms and NIRCam's names (generic MULTIACCUM labels) fit any
    # detector; a matching name is accepted
    ChargeEngine(det, Readout.multiaccum(1, 2), rng=1)
    ChargeEngine(det, Readout.named("RAPID", ngroups=2), rng=1)
    good = "NRSIRS2RAPID" if det.interleave is not None else "NRSRAPID"
    ChargeEngine(det, Readout.named(good, ngroups=2), rng=1)


def test_a_custom_readout_may_not_take_a_jwst_patterns_name_it_is_not():
    # Files carry the name as READPATT, which JWST software selects by, beside
    # NFRAMES / GROUPGAP cards: a probe's nframes = 4 named 'RAPID' (NFRAMES 1) and an
    # MA table named 'DEEP8' were written as such.  Any case; a matching MULTIACCUM,
    # and any other label, are accepted.
    import pytest
    from noise.errors import ParameterError
    with pytest.raises(ParameterError, match=r"'name' = 'RAPID' is the JWST pattern of "
                                             r"NFRAMES 1, GROUPGAP 0.*'nframes' = 4"):
        Readout.multiaccum(4, 3, name="RAPID")
    with pytest.raises(ParameterError, match=r"'name' = 'deep8' .* an MA table"):
        Readout.from_ma_table([[0, 1], [1, 2]], name="deep8")
    with pytest.raises(ParameterError, match=r"'name' = 'MEDIUM8' .* read lists"):
        Readout.from_reads([[0], [2], [3]], name="MEDIUM8")
    assert Readout.multiaccum(8, 3, groupgap=2, name="MEDIUM8").name == "MEDIUM8"
    assert Readout.from_ma_table([[0, 1], [1, 2]], name="MY_TABLE").name == "MY_TABLE"
    # read lists that are exactly a MULTIACCUM pattern are recognised as one: they
    # may carry its name, and have its numbers (an uncal), as by the 'nframes' form
    ro = Readout.from_ma_table([[0, 1], [1, 1], [2, 1]], name="RAPID")
    assert (ro.is_multiaccum, ro.nframes, ro.groupgap, ro.nskip) == (True, 1, 0, 0)
    ro = Readout.from_reads([[2, 3, 4, 5], [10, 11, 12, 13]])
    assert (ro.nframes, ro.groupgap, ro.nskip) == (4, 4, 2)
    assert ro.resultants == Readout.multiaccum(4, 2, groupgap=4, nskip=2).resultants
    assert not Readout.from_reads([[0], [2], [3], [9]]).is_multiaccum


def test_a_custom_readouts_name_is_checked_against_the_detector_by_its_key():
    # an IRS2 name on a custom readout of the right numbers, on an H2RG: refused,
    # and the message names the key the user gave ('name', not 'pattern')
    import pytest
    from noise.errors import ParameterError
    from scenesim.detector.readout import NAMED_PATTERNS
    from scenesim.scene import parse_scene
    nf, gg = NAMED_PATTERNS["NRSIRS2"]
    with pytest.raises(ParameterError, match=r"\[readout\] 'name' = 'NRSIRS2' is an IRS2"):
        parse_scene({"seed": 1, "detector": {"naxis1": 16, "naxis2": 16},
                     "noise": {"preset": "none"},
                     "readout": {"nframes": nf, "groupgap": gg, "ngroups": 2,
                                 "name": "NRSIRS2"}})


def test_one_group_effinttm_is_the_groups_mean_time_in_every_file():
    # MEDIUM8 x 1 group: the exposure said EFFINTTM = 0 (tbar_last - tbar_first)
    # while its JWST uncal said tbar_0 = 4.5 frames (frames 1..8 averaged, read k at
    # (k + 1) t_frame: mean 4.5 t_frame).  Both now give the mean time.
    ro = Readout.named("MEDIUM8", 1)
    cards = {k: v for k, v, _ in ro.to_header_cards(2.0)}
    assert cards["EFFINTTM"] == ro.effective_integration_time(2.0) == 9.0
    ro2 = Readout.named("MEDIUM8", 3)        # group means at 4.5, 14.5, 24.5 frames
    assert ro2.effective_integration_time(2.0) == 40.0
