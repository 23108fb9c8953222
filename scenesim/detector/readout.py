"""Readout patterns: which frames are read, and how they are averaged into resultants.

One object covers both conventions in use for HxRG ramps:

* **JWST MULTIACCUM** (NFRAMES, NGROUPS, GROUPGAP, NSKIP/DROPFRM1, NINTS): each group
  averages ``nframes`` consecutive frames, then ``groupgap`` frames are dropped.
* **Roman-style multi-accumulation (MA) tables**: a list of ``(first_read, nreads)``
  resultants of unequal size, possibly skipping reads between resultants.

Model
-----
An integration starts with a reset.  Reads (frames) are counted from the reset,
0-based: read 0 is the first read after the reset.  A **resultant** is the average of
a list of reads; the resultants of a readout use strictly increasing read indices
(within and across resultants).  The readout is repeated for ``nints`` integrations,
with a reset between them.  Reads that no resultant uses are never materialised by
the simulator (charge still accumulates across them and the noise time line still
runs through them), so only :attr:`Readout.needed_reads` are produced.

MULTIACCUM group ``g`` (0-based) with ``nskip`` frames dropped after the reset uses::

    start = nskip + g * (nframes + groupgap);   reads start .. start + nframes - 1

Read times (``docs/CONVENTIONS.md``), seconds from the pixel's own reset:

* rolling reset (default, JWST-like): each pixel is reset one frame time before its
  first read, so read ``k`` is at ``(k + 1) * t_frame`` for every pixel;
* global reset: all pixels are reset at the start of the first read frame, so read
  ``k`` of a pixel with clock offset ``t_pix`` (``noise.Detector.pixel_time()``) is at
  ``k * t_frame + t_pix``, i.e. the rolling times shifted by ``t_pix - t_frame``.

Exposure time line: read ``k`` of integration ``i`` sits in absolute frame slot
:func:`noise.clock.frame_slot` ``(i, k, nreads)`` (:meth:`Readout.frame_slots`).

Resultant times (Brandt 2024, PASP 136, 045004, eqs. 28-29)
------------------------------------------------------------
For a resultant of ``N`` reads at sorted times ``t_1 < ... < t_N``:

* mean time ``t_bar = (1/N) sum_k t_k``;
* ``tau = (1/N^2) sum_{k=1}^{N} (2N - 2k + 1) t_k``, so that the Poisson variance of
  the resultant for a constant rate ``f`` is ``f * tau``.  It follows from
  ``Var = (f/N^2) sum_j sum_k min(t_j, t_k)``: the time ``t_k`` is the minimum of
  ``2(N - k) + 1`` of the ``N^2`` ordered pairs.

For ``N`` reads evenly spaced by ``d`` from ``t_1``:
``t_bar = t_1 + d (N - 1)/2`` and ``tau = t_1 + d (N - 1)(2N - 1)/(6N)``.
Adding a constant to every read time adds it to both ``t_bar`` and ``tau`` (the
weights of ``tau`` sum to 1), which is why a global reset only shifts them.

Named patterns
--------------
NIRCam and NIRSpec MULTIACCUM patterns, ``(NFRAMES, GROUPGAP)``, all with
``nskip = 0`` (JDox "NIRCam Detector Readout Patterns" and "NIRSpec Detector Readout
Patterns").  Instrument limits on NGROUPS are not enforced.

==========  ========  =========  ==========
pattern     NFRAMES   GROUPGAP   instrument
==========  ========  =========  ==========
RAPID       1         0          NIRCam
BRIGHT1     1         1          NIRCam
BRIGHT2     2         0          NIRCam
SHALLOW2    2         3          NIRCam
SHALLOW4    4         1          NIRCam
MEDIUM2     2         8          NIRCam
MEDIUM8     8         2          NIRCam
DEEP2       2         18         NIRCam
DEEP8       8         12         NIRCam
NRSRAPID    1         0          NIRSpec
NRSRAPIDD1  1         1          NIRSpec
NRSRAPIDD2  1         2          NIRSpec
NRSRAPIDD6  1         6          NIRSpec
NRS         4         0          NIRSpec
NISRAPID    1         0          NIRISS
NIS         4         0          NIRISS
==========  ========  =========  ==========

NIRSpec's IRS2 patterns: ``NRSIRS2RAPID`` (1 frame per group, no gap) and ``NRSIRS2`` (5
frames, no gap): group times of 14.589 s and 72.944 s in JWST planning tools, 1 and 5
IRS2 frames of 14.5889 s; use them with the ``NIRSPEC-IRS2`` detector.  A named pattern
that contradicts the detector (an IRS2 pattern on a detector without interleaved
reference samples, or ``NRSRAPID``/``NRS`` on one with them) is refused by the engine
and the scene (:func:`check_pattern_detector`).

Roman-like tables
-----------------
:data:`ROMAN_LIKE_TABLE` and :data:`ROMAN_LIKE_SKIP_TABLE` are **illustrative**
multi-accumulation tables in the style of Roman WFI (uneven resultants, the last ones
longest); they are not official Roman MA tables.

* ``ROMAN_LIKE_TABLE``: 9 contiguous resultants of 1, 2, 3, 4, 6, 6, 8, 8, 6 reads
  covering reads 0..43 (44 reads).
* ``ROMAN_LIKE_SKIP_TABLE``: 6 resultants of 1, 1, 2, 4, 4, 8 reads that skip reads
  2, 5-7, 12-15 and 20-27: 20 reads used out of 36.
"""

import difflib
import math
import numbers
from dataclasses import dataclass

import numpy as np
from astropy.table import Table

from noise.clock import frame_slot
from noise.errors import FileFormatError, ParameterError
from noise.validate import (check_choice, check_float, check_int, check_str, describe,
                            is_sequence)

__all__ = [
    "Readout",
    "read_index_dtype",
    "NAMED_PATTERNS",
    "IRS2_PATTERNS",
    "NIRSPEC_PATTERNS",
    "NIRISS_PATTERNS",
    "check_pattern_detector",
    "ROMAN_LIKE_TABLE",
    "ROMAN_LIKE_SKIP_TABLE",
    "RESET_MODES",
    "MAX_READS",
    "resultant_moments",
]

#: Most reads per integration (read indices run from 0 to ``MAX_READS - 1``): about a
#: million frames, far beyond any instrument's pattern, and a bound that keeps building
#: a readout (a tuple per resultant) cheap; a 64x64 window reads one in ~5 ms, so the
#: limit is ~1.4 hours of continuous reads in one integration.
MAX_READS = 2 ** 20


def read_index_dtype(nreads):
    """The integer type of read and resultant indices (``-1``: none) of a readout of
    ``nreads`` reads: int16, or int32 beyond 32767 reads (up to :data:`MAX_READS`;
    int16 overflowed at read 32768 of such a readout)."""
    return np.dtype(np.int16 if nreads <= np.iinfo(np.int16).max else np.int32)

#: Reset modes accepted by :class:`Readout`.
RESET_MODES = ("rolling", "global")

#: Named MULTIACCUM patterns: upper-case name -> ``(nframes, groupgap)``.
NAMED_PATTERNS = {
    "RAPID": (1, 0),
    "BRIGHT1": (1, 1),
    "BRIGHT2": (2, 0),
    "SHALLOW2": (2, 3),
    "SHALLOW4": (4, 1),
    "MEDIUM2": (2, 8),
    "MEDIUM8": (8, 2),
    "DEEP2": (2, 18),
    "DEEP8": (8, 12),
    "NRSRAPID": (1, 0),
    "NRSRAPIDD1": (1, 1),
    "NRSRAPIDD2": (1, 2),
    "NRSRAPIDD6": (1, 6),
    "NRS": (4, 0),
    "NISRAPID": (1, 0),
    "NIS": (4, 0),
    "NRSIRS2RAPID": (1, 0),
    "NRSIRS2": (5, 0),
}

#: Named patterns of NIRSpec's IRS2 readout: for a detector with interleaved
#: reference samples only.
IRS2_PATTERNS = ("NRSIRS2RAPID", "NRSIRS2")
#: NIRSpec's traditional (non-IRS2) patterns: never on a detector that interleaves.
NIRSPEC_PATTERNS = ("NRSRAPID", "NRSRAPIDD1", "NRSRAPIDD2", "NRSRAPIDD6", "NRS")
#: NIRISS's patterns.
NIRISS_PATTERNS = ("NISRAPID", "NIS")


def _check_label(name, nframes=None, groupgap=None, what="an MA table or read lists"):
    """Refuse a custom readout's label that is a JWST pattern name it is not: files
    carry it as ``READPATT``, which JWST software selects by, beside ``NFRAMES`` and
    ``GROUPGAP`` cards that would contradict it (a probe's ``nframes = 4`` named
    ``'RAPID'``; an MA table named ``'DEEP8'``)."""
    key = str(name).strip().upper()
    if key not in NAMED_PATTERNS:
        return
    nf, gg = NAMED_PATTERNS[key]
    if nframes is None:
        raise ParameterError(
            f"'name' = {name!r} is a JWST MULTIACCUM pattern (NFRAMES {nf}, GROUPGAP "
            f"{gg}), but this readout is {what}; give it another name")
    if (nframes, groupgap) != (nf, gg):
        raise ParameterError(
            f"'name' = {name!r} is the JWST pattern of NFRAMES {nf}, GROUPGAP {gg}, but "
            f"this readout has 'nframes' = {nframes}, 'groupgap' = {groupgap}; use "
            f"that pattern's numbers, or another name")


def check_pattern_detector(pattern, detector, *, key="pattern"):
    """Refuse a named pattern that contradicts the detector's readout: an IRS2
    pattern without interleaved reference samples, or NIRSpec's traditional
    ``NRSRAPID``/``NRS`` on a detector that interleaves them (NIRSpec reads either
    way, and its files would carry one layout and name the other: jwst tells IRS2
    data by its shape, reference files by ``READPATT``).  Other names (NIRCam's, used
    as generic MULTIACCUM labels) and the unnamed forms fit any detector.

    Parameters
    ----------
    pattern : str or None
        Pattern name (:data:`NAMED_PATTERNS`, any case), or None.
    detector : noise.clock.Detector
    key : str, keyword-only
        The key that named it, for the message (``'name'`` for a custom readout).

    Raises
    ------
    noise.errors.ParameterError
        Naming the pattern, the detector and the patterns it allows.
    """
    if pattern is None or str(pattern).strip().upper() not in NAMED_PATTERNS:
        return
    pattern = str(pattern).strip().upper()
    irs2 = detector.interleave is not None
    if pattern in IRS2_PATTERNS and not irs2:
        raise ParameterError(
            f"{key!r} = {pattern!r} is an IRS2 pattern, but detector "
            f"{detector.name!r} has no interleaved reference samples ('interleave'); "
            f"use preset 'NIRSPEC-IRS2', or pattern 'NRSRAPID'/'NRS'")
    if irs2 and pattern in NIRSPEC_PATTERNS:
        raise ParameterError(
            f"{key!r} = {pattern!r} is not an IRS2 pattern, but detector "
            f"{detector.name!r} interleaves reference samples; use NIRSpec's IRS2 "
            f"pattern {' or '.join(repr(p) for p in IRS2_PATTERNS)}")


#: Illustrative Roman-style MA table (not an official Roman table): ``(first_read,
#: nreads)`` pairs, 0-based, 9 contiguous resultants over 44 reads.
ROMAN_LIKE_TABLE = ((0, 1), (1, 2), (3, 3), (6, 4), (10, 6), (16, 6), (22, 8), (30, 8),
                    (38, 6))

#: Illustrative Roman-style MA table that skips reads between resultants (not an
#: official Roman table): 6 resultants, 20 reads used out of 36.
ROMAN_LIKE_SKIP_TABLE = ((0, 1), (1, 1), (3, 2), (8, 4), (16, 4), (28, 8))


# ---------------------------------------------------------------------- validators
def _check_reset_mode(value):
    return check_choice("reset_mode", value, RESET_MODES)


def _check_name(value):
    return check_str("name", value, nonempty=True, label=True)


def _check_t_frame(value):
    return check_float("t_frame", value, minimum=0.0, strict_min=True)


def _check_pixel_time(value):
    try:
        arr = np.asarray(value, dtype=float)
    except (TypeError, ValueError) as exc:
        raise ParameterError(
            f"'pixel_time' must be a number or array of seconds >= 0, got "
            f"{describe(value)}"
        ) from exc
    if not np.all(np.isfinite(arr)) or np.any(arr < 0):
        bad = arr if arr.ndim == 0 else arr[~(np.isfinite(arr) & (arr >= 0))][0]
        raise ParameterError(
            f"'pixel_time' must be finite and >= 0 seconds, got {float(bad)!r}")
    return arr


def _check_resultants(name, value):
    """Normalise ``value`` to a tuple of tuples of int and check the read order."""
    if isinstance(value, (str, bytes)) or not is_sequence(value):
        raise ParameterError(
            f"{name!r} must be a non-empty sequence of read-index sequences, "
            f"got {describe(value)}")
    out = []
    previous = -1
    for r, res in enumerate(value):
        if isinstance(res, (str, bytes)) or not is_sequence(res):
            raise ParameterError(
                f"{name!r}: resultant {r} must be a sequence of read indices, "
                f"got {describe(res)}")
        reads = []
        for k in res:
            if isinstance(k, bool) or not isinstance(k, numbers.Integral):
                raise ParameterError(
                    f"{name!r}: resultant {r} read indices must be integers >= 0, "
                    f"got {describe(k)}")
            k = int(k)
            if k < 0:
                raise ParameterError(
                    f"{name!r}: resultant {r} read indices must be >= 0 (0 is the "
                    f"first read after reset), got {k}")
            if k >= MAX_READS:
                raise ParameterError(
                    f"{name!r}: resultant {r} read index {k} is beyond the limit of "
                    f"{MAX_READS} reads per integration (indices 0 to {MAX_READS - 1})")
            if k <= previous:
                raise ParameterError(
                    f"{name!r}: read indices must be strictly increasing within and "
                    f"across resultants; resultant {r} has read {k} after read "
                    f"{previous}")
            reads.append(k)
            previous = k
        if not reads:
            raise ParameterError(
                f"{name!r}: resultant {r} is empty; every resultant needs >= 1 read")
        out.append(tuple(reads))
    if not out:
        raise ParameterError(f"{name!r} must contain >= 1 resultant, got {describe(value)}")
    return tuple(out)


def _multiaccum_reads(nframes, ngroups, groupgap, nskip):
    step = nframes + groupgap
    return tuple(tuple(range(nskip + g * step, nskip + g * step + nframes))
                 for g in range(ngroups))


def _as_multiaccum(reads):
    """``(nframes, groupgap, nskip)`` of read lists that are exactly a MULTIACCUM
    pattern (groups of equal length of consecutive reads, evenly spaced), or None."""
    nframes = len(reads[0])
    step = reads[1][0] - reads[0][0] if len(reads) > 1 else nframes
    groupgap, nskip = step - nframes, reads[0][0]
    if groupgap < 0 or tuple(map(tuple, reads)) != _multiaccum_reads(
            nframes, len(reads), groupgap, nskip):
        return None
    return nframes, groupgap, nskip


# ---------------------------------------------------------------------- Readout
@dataclass(frozen=True)
class Readout:
    """Frozen description of a readout: resultants, integrations and reset mode.

    Parameters
    ----------
    resultants : sequence of sequence of int
        Read indices (0-based, counted from reset) averaged into each resultant;
        strictly increasing within and across resultants.  Stored as a tuple of
        tuples.
    nints : int
        Number of integrations (>= 1), with a reset before each.
    reset_mode : {'rolling', 'global'}
        Rolling reset (each pixel reset one frame before its first read) or global
        reset (all pixels at once); see the module notes for the read times.
    name : str
        Pattern name written to the ``READPATT`` keyword.
    nframes : int or None
        Frames per group of a MULTIACCUM pattern (>= 1); ``None`` otherwise.  When
        set, ``resultants`` must be exactly the MULTIACCUM pattern of ``nframes``,
        ``groupgap`` and ``nskip``.
    groupgap : int or None
        Frames dropped between groups of a MULTIACCUM pattern (>= 0); set together
        with ``nframes``, ``None`` otherwise.
    nskip : int
        Frames dropped after each reset before the first group (JWST ``DROPFRM1``,
        >= 0); the first read used must be >= ``nskip``.  Without ``nframes`` (read
        lists that are not a MULTIACCUM pattern) it is the first read's index
        (a smaller value given is raised to it): those frames are dropped (a probe found ``DROPFRM1 = 0``
        written for the reads ``[[5], [7, 8]]``).

    Raises
    ------
    noise.errors.ParameterError
        On any invalid field, naming the field, the bad value and what is allowed.

    Notes
    -----
    Prefer the constructors :meth:`multiaccum`, :meth:`named`, :meth:`from_ma_table`
    and :meth:`from_reads`.
    """

    resultants: tuple[tuple[int, ...], ...]
    nints: int = 1
    reset_mode: str = "rolling"
    name: str = "CUSTOM"
    nframes: int | None = None
    groupgap: int | None = None
    nskip: int = 0

    def __post_init__(self):
        res = _check_resultants("resultants", self.resultants)
        object.__setattr__(self, "resultants", res)
        object.__setattr__(self, "nints", check_int("nints", self.nints, minimum=1))
        _check_reset_mode(self.reset_mode)
        _check_name(self.name)
        object.__setattr__(self, "nskip", check_int("nskip", self.nskip, minimum=0))
        if (self.nframes is None) != (self.groupgap is None):
            raise ParameterError(
                f"'nframes' and 'groupgap' are MULTIACCUM metadata and must be both "
                f"set or both None, got nframes={self.nframes!r}, "
                f"groupgap={self.groupgap!r}")
        if self.nframes is not None:
            # bounded before the pattern's read lists are built (a header's
            # NFRAMES = 2**62 must not allocate them)
            object.__setattr__(self, "nframes", check_int("nframes", self.nframes,
                                                          minimum=1, maximum=MAX_READS))
            object.__setattr__(self, "groupgap",
                               check_int("groupgap", self.groupgap, minimum=0,
                                         maximum=MAX_READS))
            last = self.nskip + len(res) * (self.nframes + self.groupgap)
            if last > MAX_READS + self.groupgap:
                raise ParameterError(
                    f"the MULTIACCUM pattern of nframes={self.nframes}, "
                    f"groupgap={self.groupgap}, nskip={self.nskip} and {len(res)} groups "
                    f"needs reads up to {last - self.groupgap - 1}; at most "
                    f"{MAX_READS} reads per integration")
            expected = _multiaccum_reads(self.nframes, len(res), self.groupgap,
                                         self.nskip)
            if res != expected:
                raise ParameterError(
                    f"'resultants' {res!r} do not match the MULTIACCUM pattern of "
                    f"nframes={self.nframes}, groupgap={self.groupgap}, "
                    f"nskip={self.nskip}, which is {expected!r}")
        if res[0][0] < self.nskip:
            raise ParameterError(
                f"'nskip'={self.nskip} frames are dropped after reset, so the first "
                f"read used must be >= {self.nskip}; got first read {res[0][0]} "
                f"(allowed nskip: 0..{res[0][0]})")
        if self.nframes is None:
            object.__setattr__(self, "nskip", res[0][0])

    # ------------------------------------------------------------ constructors
    @classmethod
    def multiaccum(cls, nframes, ngroups, *, groupgap=0, nskip=0, nints=1,
                   reset_mode="rolling", name="CUSTOM"):
        """JWST MULTIACCUM readout.

        Parameters
        ----------
        nframes : int
            Frames averaged per group (>= 1).
        ngroups : int
            Groups (resultants) per integration (>= 1).
        groupgap : int, keyword-only
            Frames dropped between groups (>= 0).
        nskip : int, keyword-only
            Frames dropped after reset before the first group (>= 0, ``DROPFRM1``).
        nints : int, keyword-only
            Integrations (>= 1).
        reset_mode : {'rolling', 'global'}, keyword-only
        name : str, keyword-only
            ``READPATT`` value.

        Returns
        -------
        Readout
            Group ``g`` averages reads ``nskip + g*(nframes+groupgap)`` to
            ``nskip + g*(nframes+groupgap) + nframes - 1``.
        """
        nframes = check_int("nframes", nframes, minimum=1)
        ngroups = check_int("ngroups", ngroups, minimum=1)
        groupgap = check_int("groupgap", groupgap, minimum=0)
        nskip = check_int("nskip", nskip, minimum=0)
        nreads = nskip + (ngroups - 1) * (nframes + groupgap) + nframes
        if nreads > MAX_READS:
            raise ParameterError(
                f"'ngroups' = {ngroups} groups of 'nframes' = {nframes} frames (+ "
                f"'groupgap' = {groupgap}, 'nskip' = {nskip}) take {nreads} reads per "
                f"integration; at most {MAX_READS} are allowed")
        _check_label(name, nframes, groupgap)
        return cls(_multiaccum_reads(nframes, ngroups, groupgap, nskip), nints=nints,
                   reset_mode=reset_mode, name=name, nframes=nframes,
                   groupgap=groupgap, nskip=nskip)

    @classmethod
    def named(cls, pattern, ngroups, *, nints=1, reset_mode="rolling"):
        """A named NIRCam or NIRSpec MULTIACCUM pattern (case-insensitive).

        Parameters
        ----------
        pattern : str
            One of :data:`NAMED_PATTERNS` (e.g. ``'DEEP8'``, ``'nrsrapid'``).
        ngroups : int
            Groups per integration (>= 1; instrument limits are not enforced).
        nints : int, keyword-only
        reset_mode : {'rolling', 'global'}, keyword-only

        Returns
        -------
        Readout
            With ``name`` the upper-case pattern name and ``nskip = 0``.
        """
        key = pattern.upper() if isinstance(pattern, str) else None
        if key not in NAMED_PATTERNS:
            close = difflib.get_close_matches(key, NAMED_PATTERNS, n=1) if key else []
            hint = f"; did you mean {close[0]!r}?" if close else ""
            raise ParameterError(
                f"'pattern' must be one of {sorted(NAMED_PATTERNS)} (case-insensitive), "
                f"got {describe(pattern)}{hint}")
        nframes, groupgap = NAMED_PATTERNS[key]
        return cls.multiaccum(nframes, ngroups, groupgap=groupgap, nskip=0,
                              nints=nints, reset_mode=reset_mode, name=key)

    @classmethod
    def from_ma_table(cls, table, *, nints=1, reset_mode="rolling", name="MA_TABLE"):
        """Readout from a multi-accumulation table of ``(first_read, nreads)`` pairs.

        Parameters
        ----------
        table : sequence of (int, int)
            Per resultant, the first read (0-based, from reset) and the number of
            consecutive reads averaged (>= 1).  Reads may be skipped between
            resultants but resultants must not overlap or go backwards.
        nints : int, keyword-only
        reset_mode : {'rolling', 'global'}, keyword-only
        name : str, keyword-only
            ``READPATT`` value.

        Returns
        -------
        Readout
        """
        if isinstance(table, (str, bytes)) or not is_sequence(table) or len(table) == 0:
            raise ParameterError(
                f"'table' must be a non-empty sequence of (first_read, nreads) pairs, "
                f"got {describe(table)}")
        reads = []
        previous_last = -1
        for r, entry in enumerate(table):
            if isinstance(entry, (str, bytes)) or not is_sequence(entry) \
                    or len(entry) != 2:
                raise ParameterError(
                    f"'table' entry {r} must be a (first_read, nreads) pair, "
                    f"got {describe(entry)}")
            first = check_int(f"table[{r}] first_read", entry[0], minimum=0)
            n = check_int(f"table[{r}] nreads", entry[1], minimum=1)
            if first <= previous_last:
                raise ParameterError(
                    f"'table' has non-increasing reads: entry {r} starts at read "
                    f"{first} but the previous resultant ends at read {previous_last}; "
                    f"first_read must be >= {previous_last + 1}")
            if first + n > MAX_READS:
                raise ParameterError(
                    f"'table' entry {r} ({first}, {n}) reads up to read {first + n - 1}, "
                    f"beyond the limit of {MAX_READS} reads per integration")
            reads.append(tuple(range(first, first + n)))
            previous_last = first + n - 1
        return cls._from_lists(tuple(reads), nints, reset_mode, name, "an MA table")

    @classmethod
    def _from_lists(cls, reads, nints, reset_mode, name, what):
        """A readout of read lists; one that is exactly a MULTIACCUM pattern is
        recognised as one (its numbers recorded, so that it may carry that pattern's
        name and have a JWST uncal, as the same reads by the 'nframes' form)."""
        mac = _as_multiaccum(reads)
        if mac is None:
            _check_label(name, what=what)
            return cls(reads, nints=nints, reset_mode=reset_mode, name=name)
        _check_label(name, mac[0], mac[1])
        return cls(reads, nints=nints, reset_mode=reset_mode, name=name,
                   nframes=mac[0], groupgap=mac[1], nskip=mac[2])

    @classmethod
    def from_reads(cls, read_lists, *, nints=1, reset_mode="rolling", name="CUSTOM"):
        """Readout from explicit read-index lists, one per resultant.

        Parameters
        ----------
        read_lists : sequence of sequence of int
            Read indices (0-based, from reset), strictly increasing within and
            across resultants.
        nints : int, keyword-only
        reset_mode : {'rolling', 'global'}, keyword-only
        name : str, keyword-only

        Returns
        -------
        Readout
        """
        return cls._from_lists(_check_resultants("read_lists", read_lists), nints,
                               reset_mode, name, "read lists")

    # ------------------------------------------------------------ structure
    @property
    def is_multiaccum(self):
        """True if this is a JWST MULTIACCUM pattern (``nframes`` is set)."""
        return self.nframes is not None

    @property
    def ngroups(self):
        """Number of resultants per integration (int)."""
        return len(self.resultants)

    @property
    def nreads(self):
        """Frames per integration up to the last needed read: ``max index + 1`` (int).

        Skipped reads and the ``nskip`` dropped frames are counted.
        """
        return self.resultants[-1][-1] + 1

    @property
    def needed_reads(self):
        """Sorted read indices that some resultant uses, tuple of int."""
        return tuple(k for res in self.resultants for k in res)

    @property
    def n_per_resultant(self):
        """Reads per resultant, ndarray of shape (ngroups,), int64."""
        return np.array([len(res) for res in self.resultants], dtype=np.int64)

    @property
    def is_uniform(self):
        """True if all resultants have the same read layout and evenly spaced starts.

        "Same layout" means identical read offsets relative to the resultant's first
        read (hence the same size); then ``t_bar`` and ``tau`` are evenly spaced too.
        A single resultant is uniform.
        """
        res = self.resultants
        shape = tuple(k - res[0][0] for k in res[0])
        if any(tuple(k - r[0] for k in r) != shape for r in res[1:]):
            return False
        starts = [r[0] for r in res]
        return len(set(np.diff(starts).tolist())) <= 1

    # ------------------------------------------------------------ times
    def _needed_base_times(self, t_frame):
        """Times of the needed reads for a pixel at clock offset 0, shape (nneeded,)."""
        k = np.asarray(self.needed_reads, dtype=np.float64)
        if self.reset_mode == "rolling":
            return (k + 1.0) * t_frame
        return k * t_frame

    def _broadcast(self, base, pix):
        """``base`` (n,) plus the pixel offset of the reset mode: shape (n,) + S."""
        offset = pix if self.reset_mode == "global" else np.zeros_like(pix)
        return base.reshape(base.shape + (1,) * pix.ndim) + offset

    def read_times(self, t_frame, pixel_time=0.0):
        """Time of every read of every resultant, from the pixel's reset.

        Parameters
        ----------
        t_frame : float
            Frame time, seconds (> 0).
        pixel_time : float or ndarray, shape S, seconds
            Clock offset of the pixel within its frame (``Detector.pixel_time()``).
            Used by the global reset only; with a rolling reset every pixel has the
            same times and ``pixel_time`` only sets the output shape.

        Returns
        -------
        list of ndarray
            One array per resultant, shape ``(n_r,) + S``, float64, seconds:
            ``(k + 1) * t_frame`` (rolling) or ``k * t_frame + pixel_time`` (global).
        """
        t_frame = _check_t_frame(t_frame)
        pix = _check_pixel_time(pixel_time)
        times = self._broadcast(self._needed_base_times(t_frame), pix)
        return np.split(times, np.cumsum(self.n_per_resultant)[:-1], axis=0)

    def _moments(self, t_frame):
        """:func:`resultant_moments` of the resultants of a pixel at clock offset 0."""
        base = self._needed_base_times(t_frame)
        return resultant_moments(np.split(base, np.cumsum(self.n_per_resultant)[:-1]))

    def mean_times(self, t_frame, pixel_time=0.0):
        """Mean read time ``t_bar`` of each resultant, from the pixel's reset.

        Parameters
        ----------
        t_frame : float
            Frame time, seconds (> 0).
        pixel_time : float or ndarray, shape S, seconds
            As in :meth:`read_times`.

        Returns
        -------
        ndarray, shape (ngroups,) + S, float64, seconds
        """
        t_frame = _check_t_frame(t_frame)
        pix = _check_pixel_time(pixel_time)
        return self._broadcast(self._moments(t_frame)[1], pix)

    def tau(self, t_frame, pixel_time=0.0):
        """Brandt (2024) ``tau`` of each resultant: Poisson variance per unit rate.

        ``tau = (1/N^2) sum_{k=1}^{N} (2N - 2k + 1) t_k`` over the resultant's sorted
        read times; the variance of a resultant from a constant rate ``f`` (e-/s) is
        ``f * tau`` (e-^2).

        Parameters
        ----------
        t_frame : float
            Frame time, seconds (> 0).
        pixel_time : float or ndarray, shape S, seconds
            As in :meth:`read_times`.

        Returns
        -------
        ndarray, shape (ngroups,) + S, float64, seconds
        """
        t_frame = _check_t_frame(t_frame)
        pix = _check_pixel_time(pixel_time)
        return self._broadcast(self._moments(t_frame)[2], pix)

    def tgroup(self, t_frame):
        """Time between the starts of consecutive groups, seconds (float).

        ``(nframes + groupgap) * t_frame`` for MULTIACCUM patterns; otherwise the
        mean spacing of ``t_bar``, ``(t_bar[-1] - t_bar[0]) / (ngroups - 1)``, and for
        a single custom resultant the time it spans,
        ``(last - first + 1) * t_frame``.
        """
        t_frame = _check_t_frame(t_frame)
        if self.is_multiaccum:
            return (self.nframes + self.groupgap) * t_frame
        if self.ngroups == 1:
            res = self.resultants[0]
            return (res[-1] - res[0] + 1) * t_frame
        tbar = self.mean_times(t_frame)
        return float((tbar[-1] - tbar[0]) / (self.ngroups - 1))

    def frame_slots(self):
        """Absolute frame slot of every needed read of every integration.

        Returns
        -------
        ndarray, shape (nints, len(needed_reads)), int64
            ``i * (1 + nreads) + 1 + k`` for integration ``i`` and read ``k``; slot
            ``i * (1 + nreads)`` is the reset of integration ``i``.
        """
        k = np.asarray(self.needed_reads, dtype=np.int64)
        i = np.arange(self.nints, dtype=np.int64)
        return frame_slot(i[:, None], k[None, :], self.nreads)

    def resultant_matrix(self):
        """Weights that average the needed reads into resultants.

        Returns
        -------
        ndarray, shape (ngroups, len(needed_reads)), float64
            Row ``r`` is ``1/N_r`` on the reads of resultant ``r`` and 0 elsewhere;
            ``resultants = M @ reads`` for reads stacked along the first axis.
        """
        n = self.n_per_resultant
        rows = np.repeat(np.arange(self.ngroups), n)
        mat = np.zeros((self.ngroups, int(n.sum())))
        mat[rows, np.arange(int(n.sum()))] = 1.0 / n[rows]
        return mat

    # ------------------------------------------------------------ files
    def _groupgap_card(self):
        if self.is_multiaccum:
            return self.groupgap
        if self.ngroups == 1:
            return 0
        return self.resultants[1][0] - self.resultants[0][-1] - 1

    def to_header_cards(self, t_frame):
        """``(key, value, comment)`` FITS cards describing the readout.

        For non-MULTIACCUM readouts ``NFRAMES`` is the size of the first resultant and
        ``GROUPGAP`` the number of reads skipped between the first two resultants;
        the full description is the read table (:meth:`read_table`).

        Parameters
        ----------
        t_frame : float
            Frame time, seconds (> 0).

        Returns
        -------
        list of (str, int | float | str, str)
        """
        t_frame = _check_t_frame(t_frame)
        nframes = self.nframes if self.is_multiaccum else len(self.resultants[0])
        return [
            ("NINTS", self.nints, "integrations in exposure"),
            ("NGROUPS", self.ngroups, "groups (resultants) per integration"),
            ("NFRAMES", nframes, "frames per group"),
            ("GROUPGAP", self._groupgap_card(), "frames dropped between groups"),
            ("DROPFRM1", self.nskip, "frames dropped after reset"),
            ("READPATT", self.name, "readout pattern"),
            ("TFRAME", t_frame, "[s] frame time"),
            ("TGROUP", self.tgroup(t_frame), "[s] time between group starts"),
            ("RESETMD", self.reset_mode, "reset mode (rolling or global)"),
            ("NREADS", self.nreads, "frames per integration to last read used"),
            ("EFFINTTM", self.effective_integration_time(t_frame),
             "[s] effective integration time (tbar_last - tbar_first)"
             if self.ngroups > 1 else "[s] effective integration time (tbar_0)"),
        ]

    def effective_integration_time(self, t_frame):
        """``EFFINTTM``, s: the span of the resultants' mean times, ``tbar_last -
        tbar_first``, over which a slope is measured; with one resultant, its mean
        time from reset, ``tbar_0`` (the time a one-group slope divides by; 0 there
        before, while the JWST uncal of the same exposure said ``tbar_0``)."""
        tbar = self.mean_times(t_frame)
        return float(tbar[-1] - tbar[0]) if self.ngroups > 1 else float(tbar[0])

    def read_table(self, t_frame):
        """Table describing every resultant, one row each.

        Times are from the pixel's reset.  With a rolling reset they hold for every
        pixel; with a global reset they are those of a pixel at clock offset 0 (add
        the pixel's ``pixel_time``, or call :meth:`read_times` with it).

        Parameters
        ----------
        t_frame : float
            Frame time, seconds (> 0).

        Returns
        -------
        astropy.table.Table
            Columns ``RESULTANT`` (0-based index), ``NREADS``, ``FIRST_READ``,
            ``READS`` (int64 array of length ``max N``, padded with -1), ``TMEAN``
            (s), ``TAU`` (s) and ``READ_TIMES`` (float64 array, padded with NaN, s).
            ``meta`` holds ``NINTS``, ``READPATT``, ``RESETMD``, ``DROPFRM1``,
            ``TFRAME``, ``MULTIACC`` (bool) and, for MULTIACCUM patterns only,
            ``NFRAMES`` and ``GROUPGAP`` (read back by :meth:`from_read_table`).
        """
        t_frame = _check_t_frame(t_frame)
        n = self.n_per_resultant
        width = int(n.max())
        reads = np.full((self.ngroups, width), -1, dtype=np.int64)
        times = np.full((self.ngroups, width), np.nan)
        for r, (res, t) in enumerate(zip(self.resultants, self.read_times(t_frame))):
            reads[r, :len(res)] = res
            times[r, :len(res)] = t
        table = Table()
        table["RESULTANT"] = np.arange(self.ngroups, dtype=np.int64)
        table["NREADS"] = n
        table["FIRST_READ"] = np.array([res[0] for res in self.resultants],
                                       dtype=np.int64)
        table["READS"] = reads
        table["TMEAN"] = self.mean_times(t_frame)
        table["TMEAN"].unit = "s"
        table["TAU"] = self.tau(t_frame)
        table["TAU"].unit = "s"
        table["READ_TIMES"] = times
        table["READ_TIMES"].unit = "s"
        table.meta.update({"NINTS": self.nints, "READPATT": self.name,
                           "RESETMD": self.reset_mode, "DROPFRM1": self.nskip,
                           "TFRAME": t_frame, "MULTIACC": self.is_multiaccum})
        if self.is_multiaccum:
            table.meta.update({"NFRAMES": self.nframes, "GROUPGAP": self.groupgap})
        return table

    @classmethod
    def from_read_table(cls, table, *, nints, reset_mode, name):
        """Rebuild a readout from a table written by :meth:`read_table`.

        Parameters
        ----------
        table : astropy.table.Table or FITS record array
            Needs a ``READS`` column (read indices per row, padded with negative
            values); ``NREADS`` and ``FIRST_READ`` are checked when present.
            ``meta`` (or the FITS header of the table HDU) may hold ``DROPFRM1``;
            ``NFRAMES`` and ``GROUPGAP`` are used only when ``MULTIACC`` is true
            (so header cards of a custom readout copied beside the table are
            harmless).
        nints : int, keyword-only
        reset_mode : {'rolling', 'global'}, keyword-only
        name : str, keyword-only

        Returns
        -------
        Readout

        Raises
        ------
        noise.errors.ParameterError
            For bad ``nints``, ``reset_mode`` or ``name``.
        noise.errors.FileFormatError
            If the table lacks ``READS`` or describes an invalid readout.
        """
        nints = check_int("nints", nints, minimum=1)
        _check_reset_mode(reset_mode)
        _check_name(name)
        try:
            tab = table if isinstance(table, Table) else Table(table)
        except Exception as exc:  # astropy raises several types for non-tables
            raise FileFormatError(
                f"'table' must be an astropy Table or FITS table with a 'READS' "
                f"column, got {type(table).__name__}") from exc
        if "READS" not in tab.colnames:
            raise FileFormatError(
                f"'table' has no 'READS' column; columns are {tab.colnames}")
        reads = np.asarray(tab["READS"])
        reads = reads.reshape(len(reads), -1)
        read_lists = [tuple(int(k) for k in row if k >= 0) for row in reads]
        for col, values in (("NREADS", [len(r) for r in read_lists]),
                            ("FIRST_READ", [r[0] if r else -1 for r in read_lists])):
            if col in tab.colnames and list(np.asarray(tab[col]).tolist()) != values:
                raise FileFormatError(
                    f"'table' column {col!r} = {np.asarray(tab[col]).tolist()} does "
                    f"not match the 'READS' column, which gives {values}")
        meta = {str(k).upper(): v for k, v in tab.meta.items()}
        multiaccum = bool(meta.get("MULTIACC", False))
        try:
            return cls(tuple(read_lists), nints=nints, reset_mode=reset_mode, name=name,
                       nframes=meta.get("NFRAMES") if multiaccum else None,
                       groupgap=meta.get("GROUPGAP") if multiaccum else None,
                       nskip=meta.get("DROPFRM1", 0))
        except ParameterError as exc:
            raise FileFormatError(f"'table' describes an invalid readout: {exc}") from exc


def resultant_moments(read_times):
    """Reads, mean read time and Brandt's ``tau`` of every resultant (module notes).

    The one implementation of the resultant time moments: :meth:`Readout.mean_times`
    and :meth:`Readout.tau` use it, and so does the ramp fitter
    (:class:`scenesim.rampfit.covariance.RampCovariance`).

    Parameters
    ----------
    read_times : sequence of 1-D array_like, seconds
        Sorted read times of each resultant, one array (>= 1 read) per resultant.

    Returns
    -------
    n : ndarray, shape (nres,), float64
        Reads averaged into each resultant, ``N``.
    tbar : ndarray, shape (nres,), float64, s
        Mean read time ``(1/N) sum_k t_k``.
    tau : ndarray, shape (nres,), float64, s
        ``(1/N^2) sum_{k=1}^{N} (2N - 2k + 1) t_k``: the Poisson variance of the
        resultant per unit rate (e-^2 per e-/s).

    Raises
    ------
    noise.errors.ParameterError
        An entry that is not a non-empty 1-D array of times.
    """
    nres = len(read_times)
    n, tbar, tau = np.empty(nres), np.empty(nres), np.empty(nres)
    for r, t in enumerate(read_times):
        t = np.ascontiguousarray(t, dtype=np.float64)
        if t.ndim != 1 or t.size == 0:
            raise ParameterError(
                f"'read_times'[{r}] must be a non-empty 1-D array of read times (s), "
                f"got shape {t.shape}")
        m = t.size
        k = np.arange(1, m + 1)
        n[r] = m
        # exactly rounded sums (math.fsum), not a dot product: BLAS's dot kernels
        # depend on the CPU, and their last bits differed between two machines
        tbar[r] = math.fsum(t.tolist()) / m
        tau[r] = math.fsum(((2 * m - 2 * k + 1) * t).tolist()) / float(m * m)
    return n, tbar, tau
