"""The batched small-frame path of NoiseGenerator.frames equals the per-frame path exactly.

Frames of fewer than ``Layout.pool_min_pixels`` pixels are made several at a time (the
batched path; the tests force it with a ``Layout`` whose threshold is above every
frame here).  The design promise is bit-identity with
:meth:`NoiseGenerator.frame` called slot by slot on a generator with the same seed (what
``frames`` did before batching): the same streams, the same 1/f samples and the same
float32 operation order.  So every comparison here is exact, on the bit patterns
(``-0.0`` and ``0.0`` differ), not to a tolerance.
"""

import numpy as np
import pytest

from noise import NIRSPEC_DEFAULTS, ZERO_NOISE, NoiseGenerator, preset
from noise.generator import Layout

#: every frame of these tests takes the batched path
BATCHED = Layout(pool_min_pixels=1 << 40)

WINDOW = preset("H2RG").window(992, 992, 64, 64, name="W64")     # 1 output
FULL4 = preset("H2RG", naxis1=128, naxis2=128, n_out=4)          # 4 outputs of 32


def _per_frame(det, params, nreads, *, reads=None, nints=1, integrations=None,
               dn_gain=None, rng=5):
    """Reference: ``frame()`` for every requested slot in time order (the old path)."""
    gen = NoiseGenerator(det, params, rng=rng, threads=1)
    reads = range(nreads) if reads is None else sorted(set(reads))
    ints = range(nints) if integrations is None else sorted(set(integrations))
    return [(i, k, gen.frame(i * (1 + nreads) + 1 + k, i, dn_gain=dn_gain))
            for i in ints for k in reads]


def _batched(det, params, nreads, *, reuse=0, rng=5, layout=BATCHED, **kwargs):
    gen = NoiseGenerator(det, params, rng=rng, threads=1, layout=layout)
    return [(i, k, f.copy()) for i, k, f in gen.frames(nreads, nints=kwargs.pop(
        "nints", 1), reuse=reuse, **kwargs)]


def _assert_bit_identical(got, ref):
    assert [(i, k) for i, k, _ in got] == [(i, k) for i, k, _ in ref]
    for (i, k, a), (_, _, b) in zip(got, ref):
        assert a.dtype == b.dtype and a.shape == b.shape, (i, k)
        bits = np.uint32 if a.dtype == np.float32 else a.dtype
        np.testing.assert_array_equal(a.view(bits), b.view(bits), err_msg=f"{(i, k)}")


NO_RESET_MAPS = NIRSPEC_DEFAULTS.replace(pca0=0.0, ktc=0.0, bias_amp=0.0)


@pytest.mark.parametrize("det, params, nreads, kwargs", [
    (WINDOW, NIRSPEC_DEFAULTS, 5, dict(nints=3)),
    (FULL4, NIRSPEC_DEFAULTS, 5, dict(nints=3)),
    (FULL4, NO_RESET_MAPS, 5, dict(nints=3)),
    (WINDOW, NO_RESET_MAPS.replace(bias_offset=1234.5), 4, dict(nints=3)),
    (FULL4, NIRSPEC_DEFAULTS.replace(rtn_fraction=0.02), 4, dict(nints=3)),
    (WINDOW, NIRSPEC_DEFAULTS, 8, dict(nints=3, reads=[0, 3, 4, 7])),
    (FULL4, NIRSPEC_DEFAULTS, 6, dict(nints=4, reads=[1, 5], integrations=[0, 3])),
    (WINDOW, NIRSPEC_DEFAULTS, 1, dict(nints=5)),
    (FULL4, NIRSPEC_DEFAULTS, 3, dict(nints=2, dn_gain=2.7)),
    (WINDOW, ZERO_NOISE.replace(pedestal=3.0), 3, dict(nints=2)),
    (WINDOW, ZERO_NOISE.replace(rd_noise=5.0), 3, dict(nints=2)),
])
def test_batched_frames_equal_per_frame_path(det, params, nreads, kwargs):
    """Window and 4-output array (outputs 1 and 3 read reversed), with and without the
    kTC/bias/picture-frame maps, RTN, read and integration subsets (skipped slots split
    the 1/f fetches), one read per integration (every slot gap is a reset slot) and
    uint16 DN."""
    assert any(det.output_reversed(o) for o in range(det.n_out_active)) == (det is FULL4)
    got = _batched(det, params, nreads, **kwargs)
    ref = _per_frame(det, params, nreads, **kwargs)
    _assert_bit_identical(got, ref)


@pytest.mark.parametrize("batch_frames", [1, 3, 7])
def test_batch_boundaries_do_not_change_frames(batch_frames):
    """Batches that end mid-integration or mid-gap give the same frames."""
    got = _batched(FULL4, NIRSPEC_DEFAULTS, 4, nints=3, reads=[0, 2, 3],
                   layout=Layout(pool_min_pixels=1 << 40, batch_frames=batch_frames))
    _assert_bit_identical(got, _per_frame(FULL4, NIRSPEC_DEFAULTS, 4, nints=3,
                                          reads=[0, 2, 3]))


@pytest.mark.parametrize("reuse, dn_gain", [(1, None), (2, None), (2, 1.5), (0, 1.5)])
def test_reuse_semantics_on_the_batched_path(reuse, dn_gain):
    """``reuse=n`` yields ``n`` arrays in turn, each overwritten exactly ``n`` frames
    later; ``reuse=0`` yields arrays that are never overwritten."""
    ref = _per_frame(WINDOW, NIRSPEC_DEFAULTS, 5, nints=3, dn_gain=dn_gain)
    gen = NoiseGenerator(WINDOW, NIRSPEC_DEFAULTS, rng=5, threads=1)
    kept, ids = [], []
    for n, (i, k, f) in enumerate(gen.frames(5, nints=3, reuse=reuse, dn_gain=dn_gain)):
        ids.append(id(f))
        # a frame still held is unchanged until n frames later (then it may be reused)
        for m, (held, want) in enumerate(kept):
            if reuse == 0 or n - m < reuse:
                np.testing.assert_array_equal(held, want)
        kept.append((f, ref[n][2]))
    if reuse:
        assert len({id(f) for f, _ in kept}) == reuse
    else:
        assert len({id(f) for f, _ in kept}) == len(kept)
    assert len(ids) == len(ref)


def test_zero_noise_batched_is_exactly_zero():
    for *_, f in NoiseGenerator(WINDOW, ZERO_NOISE, rng=3, threads=1).frames(
            4, nints=2, reuse=1):
        assert not f.any()
