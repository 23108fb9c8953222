"""The flat field is a quantum efficiency: it scales the light before the Poisson draws.

Physics (``scenesim.detector.flat``): a pixel of QE ``F`` converts a fraction ``F`` of
the photons that reach it, so the charge it collects from light of rate ``r`` over a
read interval ``t`` is Poisson with mean ``F r t`` and variance equal to that mean.
Dark current is not light and is not scaled.  A gain applied to the charge after
collection would instead give variance ``F**2 r t`` (old behaviour: the engine scaled
the charge by the flat after IPC, so ``var / mean`` was ``F``, not 1).
"""

import dataclasses
import os
import tempfile

import numpy as np
from astropy.io import fits

from scenesim.run import build_engine
from scenesim.scene import parse_scene


def _scene(flat, dark=0.0, background=0.0):
    return parse_scene({
        "seed": 11,
        "detector": {"preset": "H2RG", "naxis1": 128, "naxis2": 128},
        "noise": {"preset": "none"},
        "readout": {"pattern": "RAPID", "ngroups": 12},
        "sources": {"dark_current": dark, "background": background},
        "effects": {"flat": flat},
    })


def _increments(scene):
    engine, _ = build_engine(scene)
    with engine.simulate(save_charge=True) as run:
        q = np.stack([res.charge for res in run])          # (reads, ny, nx) e-
    reg = ~engine.detector.reference_mask()
    return np.diff(q, axis=0)[:, reg].ravel(), engine.detector.frame_time


def test_qe_flat_scales_the_mean_and_keeps_poisson_variance():
    flat, bg = 0.5, 400.0
    d, tf = _increments(_scene(flat, background=bg))
    lam = flat * bg * tf                                  # 0.5 * 400 * 0.074 s = 14.8 e-
    n = d.size                                            # 11 x 120^2 = 158,400
    # mean: standard error sqrt(lam / n); 5 sigma
    assert abs(d.mean() - lam) < 5 * np.sqrt(lam / n)
    # variance / mean of a Poisson variable is 1: the sample variance has standard
    # error sqrt((2 lam^2 + lam) / n) (fourth central moment lam + 3 lam^2); 5 sigma of
    # the ratio.  A gain after collection would give var / mean = flat = 0.5.
    ratio = d.var() / d.mean()
    assert abs(ratio - 1.0) < 5 * np.sqrt((2 * lam ** 2 + lam) / n) / lam


def _half_flat(tmp):
    """A 128^2 flat of 1 on the left half and 0.25 on the right, written to ``tmp``:
    (the map, its path)."""
    flat_map = np.full((128, 128), 1.0)
    flat_map[:, 64:] = 0.25
    path = os.path.join(tmp, "flat.fits")
    fits.PrimaryHDU(flat_map).writeto(path)
    return flat_map, path


def test_flat_map_scales_light_per_pixel_but_not_dark_current():
    with tempfile.TemporaryDirectory() as tmp:
        _, path = _half_flat(tmp)
        light, tf = _increments(_scene(path, background=300.0))
        dark, _ = _increments(_scene(path, dark=300.0))
    half = light.reshape(11, 120, 120)
    lam_left, lam_right = 300.0 * tf, 0.25 * 300.0 * tf
    n = 11 * 120 * 60
    # 5 sigma of each mean (Poisson: variance = mean)
    assert abs(half[:, :, :60].mean() - lam_left) < 5 * np.sqrt(lam_left / n)
    assert abs(half[:, :, 60:].mean() - lam_right) < 5 * np.sqrt(lam_right / n)
    d = dark.reshape(11, 120, 120)
    assert abs(d[:, :, 60:].mean() - lam_left) < 5 * np.sqrt(lam_left / n)


def test_unit_flat_changes_nothing():
    a, _ = _increments(_scene(1.0, background=50.0))
    b, _ = _increments(parse_scene({
        "seed": 11, "detector": {"preset": "H2RG", "naxis1": 128, "naxis2": 128},
        "noise": {"preset": "none"}, "readout": {"pattern": "RAPID", "ngroups": 12},
        "sources": {"dark_current": 0.0, "background": 50.0}}))
    np.testing.assert_array_equal(a, b)


def test_the_rendered_catalogue_counts_what_the_flat_lets_in():
    # A 1000 e-/s star on a flat of 0.5 (scalar) and on a map that is 0.25 on its
    # right half: the catalogue's flux_on_array is what its pixels collect, the sum
    # of the star's rate map (before, 1000 on both: the flat was left out).
    from scenesim.sky.rates import scene_rates
    with tempfile.TemporaryDirectory() as tmp:
        flat_map, path = _half_flat(tmp)
        for flat in (0.5, path):
            scene = _scene(flat).replace(sources=parse_scene({
                "seed": 1, "readout": {"pattern": "RAPID", "ngroups": 2},
                "sources": {"stars": [{"x": 64.0, "y": 60.3, "flux": 1000.0}]}}).sources)
            rate, _, rendered = scene_rates(scene)
            on = float(rendered["flux_on_array"][0])
            assert abs(on - rate.sum()) < 1e-9 * on
            # the star rendered without a flat, times the flat pixel by pixel
            plain, _, _ = scene_rates(scene.replace(
                effects=dataclasses.replace(scene.effects, flat=1.0)))
            qe = 0.5 if flat == 0.5 else flat_map
            assert abs(on - float((plain * qe).sum())) < 1e-9 * on
