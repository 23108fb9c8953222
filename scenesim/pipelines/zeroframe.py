"""The JWST zero frame: the first read of each integration, digitised on its own.

NIRCam can downlink, besides the groups, the image of the first read after each
reset (``ZEROFRAME``, ``ZEROFRAM = T``).  When a group averages several frames
(``NFRAMES > 1``) that read is not in the file otherwise, and Detector1 uses it: the
``saturation`` step flags it, ``superbias`` and ``refpix`` correct it, and
``ramp_fit`` takes ``ZEROFRAME / t_frame`` as the rate of a pixel saturated already in
group 1 (stcal ``ols_fit``; jwst documentation, "calwebb_detector1", Frame 0).  With
``NFRAMES = 1`` the zero frame *is* group 1 and is not written.

The run keeps it: ``ChargeEngine.simulate(zero_frame=True)`` copies the codes of
each integration's first read before the group's other reads are added to them
(``run_scene(products=('uncal',))`` asks for it when the uncal needs one).  For a
finished exposure whose run did not keep it, :func:`zero_frames` runs the scene a
second time with the first group split into one-read resultants (every other group
unchanged); the tests check the two against each other.  The reads simulated, and so every random draw (Poisson arrivals per
needed read, the noise frames, the cosmic rays), are the same as in the exposure's
own run; only the averaging of group 1 is deferred.  Group 1 is then rebuilt from the
split reads with the ADC's own on-board mean (:meth:`noise.adc.ADC.mean_codes`) and
checked against the exposure, every group bit for bit: the zero frame provably
belongs to that realisation, or :func:`zero_frames` refuses it.  Its cost is a second
run of the scene; ``scenesim run --uncal`` does not pay it.
"""

import numpy as np

from noise.errors import FileFormatError

__all__ = ["has_zero_frame", "split_first_group", "zero_frames",
           "ZERO_FRAME_INSTRUMENTS"]

#: Instruments whose uncal files carry a zero frame (jwst documentation,
#: "calwebb_detector1": NIRCam's Frame 0).
ZERO_FRAME_INSTRUMENTS = ("NIRCAM",)


def has_zero_frame(readout, instrument):
    """True when a JWST uncal of ``readout`` from ``instrument`` (JWST name) carries a
    ``ZEROFRAME``: a NIRCam MULTIACCUM pattern with ``nframes > 1``."""
    return (instrument in ZERO_FRAME_INSTRUMENTS and readout.is_multiaccum
            and readout.nframes > 1)


def split_first_group(readout):
    """``readout``'s resultants with the first group split into one-read resultants
    (tuple of tuples; the other groups unchanged)."""
    first = readout.resultants[0]
    return tuple((k,) for k in first) + tuple(readout.resultants[1:])


def zero_frames(scene, exposure_sci, *, options=None):
    """The zero frame of each integration of ``scene``'s exposure (module notes).

    Parameters
    ----------
    scene : scenesim.scene.Scene
        The scene that was run, with its seed set.
    exposure_sci : ndarray, shape (nints, ngroups, ny, nx), uint16
        The exposure's resultants (DN): the rebuilt groups must equal them.
    options : scenesim.engine.EngineOptions or None, keyword-only
        The run's engine options (the same options give the same draws).

    Returns
    -------
    ndarray, shape (nints, ny, nx), uint16, DN

    Raises
    ------
    noise.errors.FileFormatError
        The rebuilt groups differ from ``exposure_sci`` (not the same realisation:
        another seed, scene or engine option).
    """
    from scenesim.engine import EngineOptions
    from scenesim.run import build_engine
    from scenesim.scene.schema import ReadoutConfig

    ro = scene.readout.build()
    split = split_first_group(ro)
    nsplit = len(ro.resultants[0])
    cfg = ReadoutConfig(resultants=split, nints=ro.nints, reset=ro.reset_mode,
                        name=f"{ro.name}_SPLIT")     # read lists: not the pattern's name
    engine, _ = build_engine(scene.replace(readout=cfg),
                             options=options if options is not None else EngineOptions())
    sci = np.asarray(exposure_sci)
    nints, ngroups = sci.shape[:2]
    shape = engine.detector.shape
    zero = np.empty((nints,) + shape, dtype=np.uint16)
    code_sum = np.zeros(shape, dtype=np.uint32)
    group = np.empty(shape, dtype=np.uint16)
    with engine.simulate() as run:
        for res in run:
            i, r = res.integration, res.index
            if r < nsplit:
                if r == 0:
                    zero[i] = res.dn
                    code_sum[:] = 0
                code_sum += res.dn
                if r < nsplit - 1:
                    continue
                engine.adc.mean_codes(code_sum, nsplit, out=group)
                got, g = group, 0
            else:
                got, g = res.dn, r - nsplit + 1
            if not np.array_equal(got, sci[i, g]):
                raise FileFormatError(
                    f"zero frame: integration {i}, group {g} of the re-run differs from "
                    f"the exposure's; the exposure is not this scene's realisation "
                    f"(seed {scene.seed})")
    return zero
