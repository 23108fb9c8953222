"""Which JWST instrument and detector an exposure claims to be (``[instrument]``).

A scenesim detector is an HxRG with a clock; a JWST file must also say which
instrument, detector, exposure type and subarray it comes from, from the lists the
JWST data models accept (``stdatamodels`` 6.0, ``core.schema.yaml`` and
``subarray.schema.yaml``: ``INSTRUME``, ``DETECTOR``, ``EXP_TYPE``, ``READPATT``,
``SUBARRAY``).  :class:`InstrumentConfig` holds that choice; an empty field is
inferred from the readout (:func:`resolve_instrument`):

* the instrument: NIRSpec for the NIRSpec patterns (``NRSRAPID``, ``NRS``, ...),
  NIRISS for ``NISRAPID`` and ``NIS``, NIRCam
  otherwise;
* the detector: the instrument's first (``NRCA1``, ``NRS1``, ``NIS``, ``GUIDER1``);
* the exposure type: ``NRC_IMAGE``, ``NRS_IMAGE``, ``NIS_IMAGE``, ``FGS_IMAGE``;
* the subarray: ``FULL`` for a full-frame readout, else ``GENERIC`` (the JWST name of
  a subarray not in its lists; its place is in ``SUBSTRT1/2`` and ``SUBSIZE1/2``).

The readout pattern is the scenesim pattern's name when JWST knows it, else
``'ANY'`` (scenesim's own name stays in ``SSREADPT``; the group times in the file are
exact either way).
"""

from dataclasses import dataclass

from noise.errors import ParameterError
from noise.validate import check_str, suggest

__all__ = ["InstrumentConfig", "INSTRUMENTS", "JWST_READPATT", "resolve_instrument"]

#: JWST instruments with HxRG detectors: detectors (the first is the default) and
#: the default exposure type.  Values from the stdatamodels 6.0 core schema enums.
INSTRUMENTS = {
    "NIRCAM": (("NRCA1", "NRCA2", "NRCA3", "NRCA4", "NRCALONG", "NRCB1", "NRCB2",
                "NRCB3", "NRCB4", "NRCBLONG"), "NRC_IMAGE"),
    "NIRSPEC": (("NRS1", "NRS2"), "NRS_IMAGE"),
    "NIRISS": (("NIS",), "NIS_IMAGE"),
    "FGS": (("GUIDER1", "GUIDER2"), "FGS_IMAGE"),
}

#: Readout patterns of the JWST ``READPATT`` enum that scenesim's named patterns use.
JWST_READPATT = ("RAPID", "BRIGHT1", "BRIGHT2", "SHALLOW2", "SHALLOW4", "MEDIUM2",
                 "MEDIUM8", "DEEP2", "DEEP8", "NRSRAPID", "NRSRAPIDD1", "NRSRAPIDD2",
                 "NRSRAPIDD6", "NRS", "NRSIRS2RAPID", "NRSIRS2", "NISRAPID", "NIS")

_NIRSPEC_PATTERNS = ("NRSRAPID", "NRSRAPIDD1", "NRSRAPIDD2", "NRSRAPIDD6", "NRS",
                     "NRSIRS2RAPID", "NRSIRS2")
_NIRISS_PATTERNS = ("NISRAPID", "NIS")


@dataclass(frozen=True)
class InstrumentConfig:
    """The JWST identity of an exposure (every field optional; see the module notes).

    Parameters
    ----------
    name : str
        ``'NIRCAM'``, ``'NIRSPEC'``, ``'NIRISS'``, ``'FGS'`` or ``''`` (inferred).
    detector : str
        One of the instrument's detectors (e.g. ``'NRS1'``) or ``''``.
    exp_type : str
        JWST ``EXP_TYPE`` (e.g. ``'NRC_IMAGE'``, ``'NRS_DARK'``) or ``''``.  It must
        start with the instrument's prefix (``NRC_``, ``NRS_``, ``NIS_``, ``FGS_``).
    subarray : str
        JWST subarray name (e.g. ``'SUB64P'``), or ``''`` (``FULL`` or ``GENERIC``).
    """

    name: str = ""
    detector: str = ""
    exp_type: str = ""
    subarray: str = ""

    def __post_init__(self):
        for key in ("name", "detector", "exp_type", "subarray"):
            object.__setattr__(self, key, check_str(key, getattr(self, key), label=True).upper())
        if self.name and self.name not in INSTRUMENTS:
            raise ParameterError(
                f"'name' must be one of {sorted(INSTRUMENTS)} (JWST instruments with "
                f"HxRG detectors), got {self.name!r}{suggest(self.name, INSTRUMENTS)}")
        if self.detector:
            allowed = INSTRUMENTS[self.name][0] if self.name else tuple(
                d for dets, _ in INSTRUMENTS.values() for d in dets)
            if self.detector not in allowed:
                raise ParameterError(
                    f"'detector' must be one of {list(allowed)}, got {self.detector!r}"
                    f"{suggest(self.detector, allowed)}")
        if self.exp_type and self.name:
            prefix = INSTRUMENTS[self.name][1].split("_")[0] + "_"
            if not self.exp_type.startswith(prefix):
                raise ParameterError(
                    f"'exp_type' of a {self.name} exposure must start with {prefix!r}, "
                    f"got {self.exp_type!r}")

    @property
    def is_set(self):
        """True when any field was given."""
        return any((self.name, self.detector, self.exp_type, self.subarray))


def resolve_instrument(config, detector, readout_name):
    """Every field of ``config`` filled in for ``detector`` read out with pattern
    ``readout_name`` (module notes).

    Returns
    -------
    dict
        ``name``, ``detector``, ``exp_type``, ``subarray`` and ``readpatt``.
    """
    config = config if config is not None else InstrumentConfig()
    name = config.name
    if not name and config.detector:
        name = next(n for n, (dets, _) in INSTRUMENTS.items() if config.detector in dets)
    if not name:
        name = ("NIRSPEC" if readout_name.upper() in _NIRSPEC_PATTERNS else
                "NIRISS" if readout_name.upper() in _NIRISS_PATTERNS else "NIRCAM")
    dets, exp_type = INSTRUMENTS[name]
    prefix = exp_type.split("_")[0] + "_"
    if config.exp_type and not config.exp_type.startswith(prefix):
        # checked in InstrumentConfig only with a name; an inferred one too (a probe's
        # uncal said INSTRUME = NIRCAM, EXP_TYPE = MIR_IMAGE)
        whence = (f"of detector {config.detector!r}" if config.detector
                  else "inferred from the readout")
        raise ParameterError(
            f"[instrument] 'exp_type' {config.exp_type!r} is not a {name} exposure type "
            f"(the instrument {whence}): it must start with {prefix!r}; or set "
            f"[instrument] 'name'")
    subarray = config.subarray or ("FULL" if detector.subarray is None else "GENERIC")
    readpatt = readout_name.upper() if readout_name.upper() in JWST_READPATT else "ANY"
    return {"name": name, "detector": config.detector or dets[0],
            "exp_type": config.exp_type or exp_type, "subarray": subarray,
            "readpatt": readpatt}
