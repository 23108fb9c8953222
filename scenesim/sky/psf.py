"""Point-spread functions and flux-conserving rendering of point sources.

A point source of rate ``F`` (e-/s) at sub-pixel position ``(x, y)`` puts into pixel
``(i, j)`` (row ``j``, column ``i``; pixel centres at integers, a pixel covers
``[i - 1/2, i + 1/2] x [j - 1/2, j + 1/2]``) the rate::

    R_ij = F * integral over the pixel of psf(x' - x, y' - y) dx' dy'

i.e. the *pixel-integrated* PSF (the PRF of photutils).  Every PSF here is normalised
to a unit integral over the plane, so the rendered image conserves flux: the sum over a
stamp is ``F`` times the PSF fraction inside the stamp, and the sum over the array is
``F`` times the fraction of the stamp that lands on the array.  Both numbers are
returned per source (``info`` table of :func:`render_point_sources`).

PSF models
----------
:class:`GaussianPSF`
    Circular Gaussian of full width at half maximum ``fwhm`` (pixels),
    ``sigma = fwhm / (2 sqrt(2 ln 2))``.  The pixel integral is separable and exact::

        R_ij / F = 1/4 [erf((i - x + 1/2)/(sqrt(2) sigma)) - erf((i - x - 1/2)/(sqrt(2) sigma))]
                     * [erf((j - y + 1/2)/(sqrt(2) sigma)) - erf((j - y - 1/2)/(sqrt(2) sigma))]

    which is photutils' :class:`~photutils.psf.CircularGaussianPRF` (its ``evaluate``
    formula).  We evaluate it from the erf at the pixel *edges* of a stamp (one erf per
    edge instead of two per pixel), so the stamp sum telescopes to the exact product of
    the 1-D fractions.

:class:`AiryPSF`
    Airy pattern of a circular unobstructed pupil with first dark ring at ``radius``
    pixels (photutils :class:`~photutils.psf.AiryDiskPSF`, whose normalisation and
    radius convention we use): with ``a = radius / R_z``, ``R_z = j_{1,1} / pi =
    1.21967`` and ``v = pi r / a``::

        psf(r) = pi / (4 a**2) * (2 J1(v) / v)**2,      EE(r) = 1 - J0(v)**2 - J1(v)**2

    (Born & Wolf, Principles of Optics, section 8.5.2).  There is no closed form for the
    pixel integral; it is computed by an ``n x n`` Gauss-Legendre rule per pixel.  The
    Airy intensity is band-limited (the optical transfer function of a circular pupil is
    zero beyond ``1/a`` cycles per pixel), so by Bernstein's inequality its ``2n``-th
    derivative is at most ``(2 pi / a)**(2n)`` times its maximum, and the ``n``-point
    Gauss-Legendre error on a unit interval is at most
    ``(n!)**4 / ((2n + 1) ((2n)!)**3) * (2 pi / a)**(2n)`` relative to the peak (Davis &
    Rabinowitz, Methods of Numerical Integration, eq. 2.7.12).  ``n`` is the smallest
    value making this below 1e-6 (:attr:`AiryPSF.quadrature_order`: ``n = 7, 5, 5,
    4`` for ``radius = 1, 2, 3, 6`` pixels; capped at 16).  The bound is pessimistic
    (``docs/VALIDATION_SCENE.md`` has the errors measured against a finer rule).
    The profile ``(2 J1(v) / v)**2`` itself is tabulated once per call at a step of
    5e-4 in ``v`` (from photutils' model) and interpolated linearly: error at most
    ``h**2 / 8 * max|f''| = 1.6e-8`` of the peak, because ``|f''| <= 1/2``.  Cost is
    ``n**2`` profile evaluations per stamp pixel.

    The Airy wings fall as ``r**-3``, so a stamp of radius ``R`` misses a fraction of
    about ``1 - EE(R) ~ 2 a / (pi**2 R)`` of the flux (0.9 % for ``radius = 2``,
    ``R = 32``).  This
    is reported per source as ``flux_lost_stamp``; raise ``max_stamp_radius`` (or set
    ``stamp_radius``) to render more of it.

:class:`ImagePSF`
    A user image of the PSF sampled on a grid ``oversample`` times finer than the
    detector pixels.  Convention (that of STPSF/WebbPSF ``OVERSAMP`` products): each
    element is the **flux in that sub-pixel**, the PSF centre is the geometric centre of
    the array (element index ``(n - 1) / 2`` along each axis) and the elements sum to 1
    (the flux outside the image is the shortfall from 1).  This is *not* the photutils
    ePSF convention (an ePSF holds pixel-integrated values at fine offsets and sums to
    ``oversample**2``); a clear error names the mismatch.  Rendering treats the flux of
    a sub-pixel as spread uniformly over its square and gives each detector pixel the
    overlapping share (area-weighted rebinning).  The overlap weights along each axis
    sum to 1 for every sub-pixel, so the rendering conserves the flux exactly at any
    sub-pixel position; the centroid it conserves only where a sub-pixel straddles no
    pixel edge (the weights are a trapezoid, not a tent: a PSF whose flux is all in one
    sub-pixel of 1/4 pixel renders at the pixel centre for any offset within it).  The
    rendering is the exact pixel integral of the uniform-sub-pixel model.  It is
    computed from the cumulative sums of the image, interpolated at the pixel edges
    (first along x, then along y), vectorised over sources.  Where sub-pixel edges line
    up with pixel edges (position a multiple of ``1/oversample`` from the aligned one)
    the result is the exact pixel integral of the sampled PSF; elsewhere the
    uniform-sub-pixel assumption errs by at most ``h**2 / 2 * max|grad psf|`` per pixel,
    ``h = 1/oversample`` (derivation in ``tests/sky/test_psf.py``).  With
    ``oversample = 1`` the image is treated as a flux-per-pixel image and a half-pixel
    shift smooths it by an extra pixel box, so supply oversampled PSFs (4 or more) for
    sub-pixel work.

Stamps
------
Each source gets a square stamp of ``(2R + 1)**2`` pixels centred on the pixel nearest
to it.  By default ``R`` adapts to the source: the smallest radius such that every pixel
outside the stamp would receive less than ``min_rate`` e-/s (the DESIGN rule "skip PSF
stamps far below the noise"), from an upper envelope ``E(R)`` of the PSF surface
brightness at Chebyshev distance ``>= R`` from the source (a pixel outside the stamp
lies wholly at that distance or more, so it receives at most ``F * E(R)``).  ``R`` is then
rounded up to one of a few sizes (about four per octave, so sources can be rendered in
vectorised groups of equal stamp size) and capped at ``max_stamp_radius`` and at the
radius beyond which the PSF carries nothing (``7.5 sigma`` plus one pixel for the
Gaussian, 1e-13 of the flux; the image half-size for :class:`ImagePSF`).  Stamps are
clipped to the array and added with :func:`numpy.add.at`.  Sources whose stamp misses the
array entirely are skipped (nothing rendered, ``rendered = False`` in the table).

Stamps are built in chunks of at most about 250 000 array elements (sources, and
for the Airy pattern rows of a stamp), so the temporaries stay in cache; the chunking
does not change the result.  Cost grows with the stamp area times the quadrature
nodes per pixel (``n**2`` for Airy), so pass ``min_rate`` to keep Airy stamps small
(timings: ``docs/VALIDATION_SCENE.md``).

photutils is imported inside the functions that use it (the photutils conversions,
the Airy profile table, image-PSF encircled energies), not at the top: its import
takes ~0.7 s and ~55 MB (``photutils.psf`` pulls in matplotlib), which a noise-only or
Gaussian-PSF run does not need.
"""

import math
import numbers
import os
from dataclasses import dataclass, field

import numpy as np
from astropy.table import Table
from scipy.special import erf, j0, j1

from noise.errors import FileFormatError, ParameterError, ParameterTypeError
from noise.fitsio import open_fits
from noise.validate import (check_bool, check_float, check_instance, check_int,
                            check_map, check_mask, check_path, check_shape, describe)

__all__ = [
    "GaussianPSF",
    "AiryPSF",
    "ImagePSF",
    "render_point_sources",
    "encircled_energy",
    "MAX_PSF_WIDTH",
    "MIN_AIRY_RADIUS",
]

#: Largest Gaussian ``fwhm`` and Airy ``radius``, pixels: 250 times the widest HxRG
#: (a PSF wider than that is flat over any array), and the Airy profile table's radii
#: (``radius / 1.22`` times a few hundred) stay far from float64 overflow.
MAX_PSF_WIDTH = 1e6
#: Smallest Airy ``radius``, pixels: the profile is tabulated at a step of
#: ``5e-4 * radius / 3.83`` pixels out to the stamp corner, 7 million entries for a
#: 64-pixel stamp at 0.1 pixel (and 10 times more per decade below); so narrow a
#: pattern is a point at the detector's sampling anyway.
MIN_AIRY_RADIUS = 0.1

_FWHM_TO_SIGMA = 1.0 / (2.0 * math.sqrt(2.0 * math.log(2.0)))
#: First zero of J1 divided by pi (photutils ``AiryDiskPSF._rz``).
_AIRY_RZ = 1.2196698912665045
#: Relative tolerance on the sum of a PSF image for ``normalize=True``.
_SUM_RTOL = 1e-3
#: Bound on the Airy pixel-quadrature error, relative to the peak (module notes).
_AIRY_QUAD_TOL = 1e-6
#: Step in v = pi r / a of the tabulated Airy profile.
_AIRY_TABLE_STEP = 5e-4
#: Elements handled at once when building stamps: small enough that the temporaries
#: stay in cache (see the module notes).
_CHUNK_ELEMENTS = 250_000


# ----------------------------------------------------------------------------- models
@dataclass(frozen=True)
class GaussianPSF:
    """Circular Gaussian PSF, rendered as its exact pixel integral.

    Parameters
    ----------
    fwhm : float
        Full width at half maximum, pixels (> 0).
    """

    fwhm: float

    def __post_init__(self):
        object.__setattr__(self, "fwhm",
                           check_float("fwhm", self.fwhm, minimum=0.0, strict_min=True,
                                       maximum=MAX_PSF_WIDTH))

    @property
    def sigma(self):
        """Standard deviation, pixels: ``fwhm / (2 sqrt(2 ln 2))``."""
        return self.fwhm * _FWHM_TO_SIGMA

    def to_photutils(self, flux=1.0, x_0=0.0, y_0=0.0):
        """The same PSF as a photutils :class:`~photutils.psf.CircularGaussianPRF`.

        The photutils model is pixel-integrated too, so it evaluates to the values
        rendered here (useful for PSF photometry of simulated images).
        """
        from photutils.psf import CircularGaussianPRF     # lazy (module notes)
        return CircularGaussianPRF(flux=flux, x_0=x_0, y_0=y_0, fwhm=self.fwhm)

    # private protocol used by render_point_sources --------------------------
    def _useful_radius(self):
        # Outside |d| > 7.5 sigma the 1-D tail is erfc(7.5/sqrt2) = 6e-14.
        return int(math.ceil(7.5 * self.sigma)) + 1

    def _envelope(self, rmax):
        r = np.arange(rmax + 1, dtype=float)
        s2 = self.sigma ** 2
        return np.exp(-0.5 * r * r / s2) / (2.0 * math.pi * s2)

    def _stamp_factory(self, rmax):
        sig = self.sigma

        def stamps(dx0, dy0, radius):
            edges = np.arange(-radius, radius + 2, dtype=float) - 0.5
            scale = 1.0 / (math.sqrt(2.0) * sig)
            cx = 0.5 * erf((dx0[:, None] + edges[None, :]) * scale)
            cy = 0.5 * erf((dy0[:, None] + edges[None, :]) * scale)
            px = np.diff(cx, axis=1)
            py = np.diff(cy, axis=1)
            return py[:, :, None] * px[:, None, :]

        return stamps


@dataclass(frozen=True)
class AiryPSF:
    """Airy pattern of a circular pupil, pixel-integrated by Gauss-Legendre quadrature.

    Parameters
    ----------
    radius : float
        Radius of the first dark ring, pixels (> 0); ``1.22 lambda / D`` in pixels.
    """

    radius: float

    def __post_init__(self):
        radius = check_float("radius", self.radius, minimum=0.0, strict_min=True,
                             maximum=MAX_PSF_WIDTH)
        if radius < MIN_AIRY_RADIUS:
            raise ParameterError(
                f"'radius' must be >= {MIN_AIRY_RADIUS} pixels (an Airy pattern narrower "
                f"than that is a point at the detector's sampling, and its profile table "
                f"would outgrow memory), got {self.radius!r}")
        object.__setattr__(self, "radius", radius)

    @property
    def fwhm(self):
        """Full width at half maximum, pixels (``0.84367 * radius``)."""
        return 2.0 * 1.616339948310703 * self.radius / _AIRY_RZ / math.pi

    @property
    def _a(self):
        return self.radius / _AIRY_RZ

    def to_photutils(self, flux=1.0, x_0=0.0, y_0=0.0):
        """The same PSF as a photutils :class:`~photutils.psf.AiryDiskPSF`.

        Note that the photutils model is *sampled* at pixel centres, not integrated
        over pixels.
        """
        from photutils.psf import AiryDiskPSF             # lazy (module notes)
        return AiryDiskPSF(flux=flux, x_0=x_0, y_0=y_0, radius=self.radius)

    def _useful_radius(self):
        return math.inf

    @property
    def quadrature_order(self):
        """Gauss-Legendre nodes per pixel axis: the smallest order whose error bound
        is below 1e-6 of the peak (module notes), at most 16."""
        k = 2.0 * math.pi / self._a
        for n in range(2, 17):
            bound = (math.lgamma(n + 1) * 4 - math.log(2 * n + 1)
                     - 3 * math.lgamma(2 * n + 1) + 2 * n * math.log(k))
            if bound < math.log(_AIRY_QUAD_TOL):
                return n
        return 16

    def _profile_table(self, rmax):
        """Unit-flux surface brightness tabulated on ``r = 0 .. rmax`` (step in v)."""
        a = self._a
        step_r = _AIRY_TABLE_STEP * a / math.pi
        nstep = int(math.ceil(rmax / step_r)) + 2
        r = np.arange(nstep + 1) * step_r
        from photutils.psf import AiryDiskPSF             # lazy (module notes)
        model = AiryDiskPSF(flux=1.0, x_0=0.0, y_0=0.0, radius=self.radius)
        values = model.evaluate(r, np.zeros_like(r), 1.0, 0.0, 0.0, self.radius)
        return step_r, np.asarray(values, dtype=float)

    def _envelope(self, rmax):
        step_r, table = self._profile_table(rmax + 1.0)
        suffix_max = np.maximum.accumulate(table[::-1])[::-1]
        idx = np.minimum(np.floor(np.arange(rmax + 1) / step_r).astype(int),
                         table.size - 1)
        return suffix_max[idx]

    def _stamp_factory(self, rmax):
        # Largest distance of a quadrature node from the source: corner of the stamp.
        step_r, table = self._profile_table(math.sqrt(2.0) * (rmax + 1.0) + 1.0)
        slope = np.append(np.diff(table), 0.0)
        inv_step = 1.0 / step_r
        n = self.quadrature_order
        nodes, weights = np.polynomial.legendre.leggauss(n)
        nodes = 0.5 * nodes
        weights = 0.5 * weights

        # Work buffers reused across chunks: fresh multi-MB temporaries cost more in
        # page faults than the arithmetic itself.
        buffers = {}

        def buffer(name, size, dtype):
            buf = buffers.get(name)
            if buf is None or buf.size < size:
                buf = buffers[name] = np.empty(size, dtype=dtype)
            return buf[:size]

        def block(dx0, dy0, sub_x, sub_y):
            """Pixel integrals for stamp rows/columns given by node offsets."""
            ux2 = np.square(dx0[:, None] + sub_x[None, :])            # (N, Sx*n)
            uy2 = np.square(dy0[:, None] + sub_y[None, :])            # (N, Sy*n)
            shape = (dx0.size, sub_y.size, sub_x.size)
            count = shape[0] * shape[1] * shape[2]
            pos = buffer("pos", count, np.float64).reshape(shape)
            idx = buffer("idx", count, np.intp).reshape(shape)
            val = buffer("val", count, np.float64).reshape(shape)
            tmp = buffer("tmp", count, np.float64).reshape(shape)
            np.add(uy2[:, :, None], ux2[:, None, :], out=pos)        # r**2
            np.sqrt(pos, out=pos)
            pos *= inv_step                                           # table coordinate
            np.copyto(idx, pos, casting="unsafe")                     # floor (pos >= 0)
            pos -= idx                                                # fraction in step
            np.take(slope, idx, out=val)
            val *= pos
            np.take(table, idx, out=tmp)
            val += tmp                                                # linear interpolation
            val5 = val.reshape(dx0.size, sub_y.size // n, n, sub_x.size // n, n)
            # the quadrature sums node by node, in a fixed order (einsum's optimised
            # path goes through BLAS, whose last bits depend on the CPU)
            out = val5[:, :, :, :, 0] * weights[0]
            for c in range(1, n):
                out += val5[:, :, :, :, c] * weights[c]
            acc = out[:, :, 0] * weights[0]
            for b in range(1, n):
                acc += out[:, :, b] * weights[b]
            return acc

        def stamps(dx0, dy0, radius):
            size = 2 * radius + 1
            offs = np.arange(-radius, radius + 1, dtype=float)
            sub = (offs[:, None] + nodes[None, :]).ravel()          # (S*n,) node offsets
            # rows per block so that one block stays within the chunk budget
            rows = max(1, _CHUNK_ELEMENTS // (dx0.size * size * n * n))
            if rows >= size:
                return block(dx0, dy0, sub, sub)
            out = np.empty((dx0.size, size, size))
            for r0 in range(0, size, rows):
                r1 = min(size, r0 + rows)
                out[:, r0:r1] = block(dx0, dy0, sub, sub[r0 * n:r1 * n])
            return out

        stamps.cost_per_pixel = n * n
        return stamps


@dataclass(frozen=True, eq=False)
class ImagePSF:
    """A PSF given as an (oversampled) image of flux per sub-pixel.

    Parameters
    ----------
    data : array_like, shape (ny_sub, nx_sub), float
        Flux fraction in each sub-pixel (>= 0, finite).  The PSF centre is the
        geometric centre of the array.  Stored as a read-only float64 copy.
    oversample : int
        Sub-pixels per detector pixel along each axis (>= 1).
    normalize : bool
        ``True`` (default): the image must already sum to 1 within a relative 1e-3
        (it is then rescaled to exactly 1); otherwise :class:`ParameterError`.  Use
        :meth:`normalized` to rescale an image explicitly.  ``False``: the image is used
        as given; it must sum to at most ``1 + 1e-3`` and the shortfall from 1 is
        treated as flux outside the image (reported as ``flux_lost_stamp``).

    Notes
    -----
    Equality and hashing use the data bytes, the oversampling and ``normalize``, so
    the object is a hashable, picklable value like the other settings.
    """

    data: np.ndarray = field(repr=False)
    oversample: int = 1
    normalize: bool = True

    def __post_init__(self):
        os_ = check_int("oversample", self.oversample, minimum=1)
        check_bool("normalize", self.normalize)
        try:
            data = np.array(self.data, dtype=np.float64, order="C", copy=True)
        except (TypeError, ValueError) as exc:
            raise ParameterError(
                f"'data' must be a 2-D array of numbers, got {type(self.data).__name__}"
            ) from exc
        if data.ndim != 2 or min(data.shape) < 1:
            raise ParameterError(
                f"'data' must be a non-empty 2-D array (PSF image), got shape {data.shape}")
        if not np.all(np.isfinite(data)):
            raise ParameterError("'data' (PSF image) contains NaN or infinite values")
        if np.any(data < 0):
            raise ParameterError(
                f"'data' (PSF image) must be >= 0 everywhere, minimum is {float(data.min())!r}; "
                f"clip negative values first")
        total = float(data.sum())
        if self.normalize:
            if abs(total - 1.0) > _SUM_RTOL:
                hint = ""
                if os_ > 1 and abs(total / os_ ** 2 - 1.0) <= _SUM_RTOL:
                    hint = (f"; it sums to oversample**2 = {os_ ** 2}, the photutils ePSF "
                            f"convention, but scenesim expects flux per sub-pixel summing "
                            f"to 1 (divide by oversample**2)")
                raise ParameterError(
                    f"PSF image 'data' sums to {total!r} but normalize=True requires a "
                    f"sum of 1 within {_SUM_RTOL} (flux per sub-pixel){hint}; use "
                    f"ImagePSF.normalized(data, oversample) to rescale it, or "
                    f"normalize=False (a scene: [sources.psf] normalize = false) to use "
                    f"it as given")
            data /= total
        elif total > 1.0 + _SUM_RTOL:
            raise ParameterError(
                f"PSF image 'data' sums to {total!r} > 1: a PSF cannot hold more than "
                f"the source flux (flux per sub-pixel must sum to <= 1)")
        elif total <= 0.0:
            raise ParameterError("PSF image 'data' sums to 0: it holds no flux")
        data.setflags(write=False)
        object.__setattr__(self, "data", data)
        object.__setattr__(self, "oversample", os_)
        object.__setattr__(self, "normalize", bool(self.normalize))

    # value semantics -------------------------------------------------------
    def _key(self):
        return (self.data.shape, self.data.tobytes(), self.oversample, self.normalize)

    def __eq__(self, other):
        if not isinstance(other, ImagePSF):
            return NotImplemented
        return self._key() == other._key()

    def __hash__(self):
        return hash(self._key())

    def __reduce__(self):
        return (type(self), (np.array(self.data), self.oversample, self.normalize))

    def __repr__(self):
        return (f"ImagePSF(data=<{self.data.shape[0]}x{self.data.shape[1]} float64, "
                f"sum={self.data.sum():.6g}>, oversample={self.oversample}, "
                f"normalize={self.normalize})")

    # constructors ----------------------------------------------------------
    @classmethod
    def normalized(cls, data, oversample=1):
        """Build an :class:`ImagePSF` from ``data`` rescaled to sum to exactly 1.

        Parameters
        ----------
        data : array_like, shape (ny_sub, nx_sub)
            PSF image (flux per sub-pixel, any positive total).
        oversample : int
            Sub-pixels per detector pixel along each axis.
        """
        arr = np.asarray(data, dtype=np.float64)
        total = float(np.sum(arr)) if arr.size else 0.0
        if not math.isfinite(total) or total <= 0:
            raise ParameterError(
                f"ImagePSF.normalized needs a PSF image with a finite positive sum, "
                f"got sum {total!r}")
        return cls(arr / total, oversample=oversample, normalize=True)

    @classmethod
    def from_fits(cls, path, oversample=None, normalize=True, *, ext=None):
        """Read a PSF image from a FITS file.

        Parameters
        ----------
        path : str or os.PathLike
            FITS file.
        oversample : int or None
            Sub-pixels per pixel.  ``None``: the ``OVERSAMP`` header keyword of the HDU
            (as written by STPSF/WebbPSF), or 1 if absent.  If both are given they must
            agree.
        normalize : bool
            See :class:`ImagePSF`.
        ext : int, str or None
            HDU to read; ``None``: the first HDU holding a 2-D image.

        Raises
        ------
        FileFormatError
            Missing or unreadable file, no 2-D image, or a non-integer ``OVERSAMP``.
        ParameterError
            ``oversample`` disagrees with ``OVERSAMP``, or the image is not a valid PSF.
        """
        if oversample is not None:
            oversample = check_int("oversample", oversample, minimum=1)
        path = os.path.abspath(check_path("path", path))
        with open_fits(path, "PSF file", memmap=False) as hdul:
            try:
                if ext is None:
                    hdus = [h for h in hdul if h.data is not None and np.ndim(h.data) == 2]
                    if not hdus:
                        raise FileFormatError(f"PSF file {path!r} has no 2-D image HDU")
                    hdu = hdus[0]
                else:
                    hdu = hdul[ext]
                    if hdu.data is None or np.ndim(hdu.data) != 2:
                        raise FileFormatError(
                            f"HDU {ext!r} of PSF file {path!r} is not a 2-D image")
                data = np.array(hdu.data, dtype=np.float64)
                header_os = hdu.header.get("OVERSAMP")
            except (KeyError, IndexError) as exc:
                raise FileFormatError(
                    f"PSF file {path!r} has no HDU {ext!r}") from exc
        if header_os is not None:
            if isinstance(header_os, (bool, np.bool_)) or not (
                    isinstance(header_os, numbers.Real)
                    and float(header_os).is_integer() and header_os >= 1):
                raise FileFormatError(
                    f"PSF file {path!r}: OVERSAMP = {header_os!r} is not an integer >= 1")
            header_os = int(header_os)
            if oversample is not None and oversample != header_os:
                raise ParameterError(
                    f"'oversample'={oversample} disagrees with OVERSAMP={header_os} in "
                    f"PSF file {path!r}")
        os_ = oversample if oversample is not None else (header_os or 1)
        try:
            return cls(data, oversample=os_, normalize=normalize)
        except ParameterError as exc:
            raise type(exc)(f"PSF file {path!r}: {exc}") from exc

    def to_photutils(self, flux=1.0, x_0=0.0, y_0=0.0):
        """The same PSF as a photutils :class:`~photutils.psf.ImagePSF` (an ePSF).

        The flux-per-sub-pixel image is integrated over a detector-pixel box centred
        on each sub-pixel (weights 1, and 1/2 at the two ends for even
        ``oversample``), which gives the pixel-integrated PSF at fine offsets: the
        photutils ePSF convention (sum ``oversample**2``).  The ePSF extends half a
        pixel beyond the image on each side.  photutils interpolates it with a cubic
        spline, so the model equals :func:`render_point_sources` exactly where the
        sub-pixel centres fall on pixel centres, and approximately elsewhere.
        """
        os_ = self.oversample
        if os_ % 2:
            kern = np.ones(os_)
        else:
            kern = np.ones(os_ + 1)
            kern[[0, -1]] = 0.5
        # 'full' convolution: the ePSF grows by half a pixel on each side, so pixels
        # that overlap the image edge keep their share (the array stays centred).
        tmp = np.apply_along_axis(np.convolve, 1, self.data, kern, mode="full")
        epsf = np.apply_along_axis(np.convolve, 0, tmp, kern, mode="full")
        from photutils.psf import ImagePSF as PhotutilsImagePSF   # lazy (module notes)
        return PhotutilsImagePSF(epsf, flux=flux, x_0=x_0, y_0=y_0, oversampling=os_)

    # private protocol ------------------------------------------------------
    def _useful_radius(self):
        ny, nx = self.data.shape
        return int(math.ceil(max(ny, nx) / (2.0 * self.oversample)))

    def _envelope(self, rmax):
        ny, nx = self.data.shape
        h = 1.0 / self.oversample
        cx = np.abs((np.arange(nx) - (nx - 1) / 2.0) * h)
        cy = np.abs((np.arange(ny) - (ny - 1) / 2.0) * h)
        cheb = np.maximum(cy[:, None], cx[None, :]) + 0.5 * h   # outer Chebyshev distance
        sb = self.data * self.oversample ** 2         # surface brightness per pixel^2
        r = np.arange(rmax + 1)
        order = np.argsort(cheb, axis=None)
        dist = cheb.ravel()[order]
        suffix = np.maximum.accumulate(sb.ravel()[order][::-1])[::-1]
        pos = np.searchsorted(dist, r, side="right")
        return np.where(pos < dist.size, suffix[np.minimum(pos, dist.size - 1)], 0.0)

    def _stamp_factory(self, rmax):
        # The sub-pixel image is piecewise constant, so the flux between two
        # coordinates is a difference of its cumulative sum interpolated linearly
        # within a sub-pixel.  Integrating along x at the pixel edges, then along y,
        # gives the same numbers as the overlap-weight product W_y @ D @ W_x.T at a
        # cost of O(ny_sub * S) per source instead of O(ny_sub * nx_sub * S).
        ny, nx = self.data.shape
        os_ = self.oversample
        # cumulative sum along x, stored transposed: cum_xt[i, j] = sum(data[j, :i])
        cum_xt = np.zeros((nx + 1, ny))
        np.cumsum(self.data.T, axis=0, out=cum_xt[1:])

        def interp(pos, axis_len):
            # cell index and fraction of fine coordinates, clipped to the image
            pos = np.clip(pos, 0.0, axis_len)
            k = np.minimum(pos.astype(np.intp), axis_len - 1)
            return k, pos - k

        def stamps(dx0, dy0, radius):
            edges = np.arange(-radius, radius + 2, dtype=float) - 0.5       # (S+1,)
            fx = (dx0[:, None] + edges[None, :]) * os_ + nx / 2.0            # (N, S+1)
            fy = (dy0[:, None] + edges[None, :]) * os_ + ny / 2.0
            # only sub-pixel rows within R + 1 pixels of the source can reach the stamp
            r_lo = max(0, int(math.floor(ny / 2.0 - (radius + 1) * os_)))
            r_hi = min(ny, int(math.ceil(ny / 2.0 + (radius + 1) * os_)))
            cols = cum_xt[:, r_lo:r_hi]
            k, t = interp(fx, nx)
            lo = cols[k]                                                     # (N, S+1, ny')
            at_edges = lo + t[:, :, None] * (cols[k + 1] - lo)
            band = np.diff(at_edges, axis=1)                                 # (N, Sx, ny')
            cum_y = np.zeros(band.shape[:2] + (r_hi - r_lo + 1,))
            np.cumsum(band, axis=2, out=cum_y[:, :, 1:])
            k, t = interp(fy - r_lo, r_hi - r_lo)
            lo = np.take_along_axis(cum_y, k[:, None, :], axis=2)            # (N, Sx, Sy+1)
            hi = np.take_along_axis(cum_y, k[:, None, :] + 1, axis=2)
            at_edges = lo + t[:, None, :] * (hi - lo)
            return np.diff(at_edges, axis=2).transpose(0, 2, 1)             # (N, Sy, Sx)

        # elements per stamp pixel: ny * S for the column integrals, S**2 for the rest
        stamps.cost_per_pixel = 1.0 + ny / (2 * rmax + 1)
        return stamps


_PSF_TYPES = (GaussianPSF, AiryPSF, ImagePSF)

#: Allowed adaptive stamp radii: 0..8, then about four per octave.
_LADDER = np.array(sorted(set(list(range(9)) + [10, 12, 14, 16, 20, 24, 28, 32, 40, 48, 56,
                                                64, 80, 96, 112, 128, 160, 192, 224, 256,
                                                320, 384, 448, 512])))


def _ladder_round_up(r):
    idx = np.searchsorted(_LADDER, r, side="left")
    big = idx >= _LADDER.size
    out = _LADDER[np.minimum(idx, _LADDER.size - 1)]
    return np.where(big, r, out)


def _as_1d(name, value):
    if isinstance(value, (str, bytes, dict)) or value is None:
        raise ParameterTypeError(
            f"{name!r} must be a number or a 1-D array of numbers, got {describe(value)}")
    try:
        arr = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise ParameterTypeError(
            f"{name!r} must be a number or a 1-D array of numbers, got "
            f"{describe(value)}") from exc
    if arr.ndim > 1:
        raise ParameterError(f"{name!r} must be a scalar or 1-D array, got shape {arr.shape}")
    return arr


def _source_arrays(x, y, flux):
    """``x``, ``y``, ``flux`` as float64 1-D arrays of one length (scalars broadcast)
    and checked."""
    arrays = {"x": _as_1d("x", x), "y": _as_1d("y", y), "flux": _as_1d("flux", flux)}
    lengths = {k: a.size for k, a in arrays.items() if a.ndim == 1}
    if len(set(lengths.values())) > 1:
        raise ParameterError(
            "'x', 'y' and 'flux' must have the same length (or be scalars), got "
            + ", ".join(f"{k!r} of length {n}" for k, n in lengths.items()))
    n = next(iter(lengths.values())) if lengths else 1
    xs, ys, fl = (np.array(np.broadcast_to(a, (n,)), dtype=np.float64)
                  for a in arrays.values())
    for name, arr in (("x", xs), ("y", ys)):
        bad = ~np.isfinite(arr)
        if bad.any():
            raise ParameterError(
                f"{name!r} must be finite; source index {int(np.flatnonzero(bad)[0])} has "
                f"{name}={arr[bad][0]!r}")
    bad = ~np.isfinite(fl) | (fl < 0)
    if bad.any():
        raise ParameterError(
            f"'flux' must be finite and >= 0 (e-/s); source index "
            f"{int(np.flatnonzero(bad)[0])} has flux={fl[bad][0]!r}")
    return xs, ys, fl


def _stamp_radii(psf, fl, stamp_radius, min_rate, max_stamp_radius):
    """Stamp radius per source: fixed, or adaptive (module notes), as intp."""
    n = fl.size
    if stamp_radius is not None:
        return np.full(n, stamp_radius, dtype=np.intp)
    cap = int(min(max_stamp_radius, psf._useful_radius()))
    radius = np.full(n, cap, dtype=np.intp)
    if min_rate > 0 and n:
        env = psf._envelope(cap)            # non-increasing, length cap + 1
        # smallest R with flux * env(R) <= min_rate
        with np.errstate(divide="ignore"):
            thresh = np.where(fl > 0, min_rate / fl, np.inf)
        need = np.searchsorted(-env, -thresh, side="left")
        radius = np.minimum(_ladder_round_up(need), cap).astype(np.intp)
    return radius


def render_point_sources(shape, x, y, flux, psf, *, stamp_radius=None, min_rate=0.0,
                         max_stamp_radius=64, blind=None, qe=None):
    """Render point sources as pixel-integrated PSFs, conserving flux.

    Parameters
    ----------
    shape : tuple of int
        ``(ny, nx)`` of the output image (pixels).
    x, y : float or array_like, shape (n,)
        Source positions, pixels (column, row; pixel centres at integers).  Finite;
        sources may lie partly or wholly off the array.
    flux : float or array_like, shape (n,)
        Source rates, e-/s (finite, >= 0).  ``x``, ``y`` and ``flux`` broadcast together.
    psf : GaussianPSF, AiryPSF or ImagePSF
        The PSF (the same for all sources).
    stamp_radius : int or None
        Fixed stamp radius ``R`` (stamps of ``(2R + 1)**2`` pixels) for every source,
        or ``None`` (default) for the adaptive radius described in the module notes.
    min_rate : float
        Adaptive stamps cover every pixel where the source would put at least this
        rate, e-/s (>= 0; 0 renders out to the cap).  Ignored when ``stamp_radius``
        is given.
    max_stamp_radius : int
        Cap on the adaptive radius, pixels (default 64).
    blind : ndarray of bool, shape (ny, nx), optional
        Pixels that collect nothing (the reference pixels): they get no flux and
        their share counts as off the array.
    qe : ndarray, shape (ny, nx), optional
        Relative quantum efficiency (the flat field, finite and >= 0): each pixel
        collects its share times its QE, and ``flux_on_array`` counts what it
        collects (the rate a photometry of the slopes finds).

    Returns
    -------
    image : ndarray, shape (ny, nx), float64, e-/s
        Sum of the rendered sources.
    info : astropy.table.Table, one row per source in input order
        ``x``, ``y``, ``flux`` (as given); ``flux_on_array`` (e-/s actually added to
        ``image``, so none on ``blind`` pixels, the ``qe`` included);
        ``frac_on_array`` (the PSF's fraction on the collecting pixels, computed from
        the unit PSF so defined for zero flux: ``flux_on_array / flux`` without
        ``qe``); ``flux_lost_stamp`` (e-/s of PSF outside the
        stamp, wherever the stamp lies); ``stamp_radius`` (pixels); ``rendered``
        (False when the stamp misses the array: then nothing is added and the other
        numbers are 0).  ``flux - flux_on_array - flux_lost_stamp`` is the flux of the
        stamp that fell off the array (without ``qe``).

    Raises
    ------
    ParameterError
        Bad shape, non-finite position, negative or non-finite flux, unknown PSF
        type, or bad radius/rate settings (checked before any work).
    """
    ny, nx = check_shape("shape", shape)
    check_instance("psf", psf, _PSF_TYPES, "a GaussianPSF, AiryPSF or ImagePSF")
    xs, ys, fl = _source_arrays(x, y, flux)
    min_rate = check_float("min_rate", min_rate, minimum=0.0)
    max_stamp_radius = check_int("max_stamp_radius", max_stamp_radius, minimum=0)
    if stamp_radius is not None:
        stamp_radius = check_int("stamp_radius", stamp_radius, minimum=0)
    blind_flat = None
    if blind is not None:
        blind_flat = check_mask("blind", blind, (ny, nx)).reshape(-1)
    qe_flat = None
    if qe is not None:
        qe_flat = np.broadcast_to(check_map("qe", qe, (ny, nx), minimum=0.0),
                                  (ny, nx)).reshape(-1)

    n = xs.size
    image = np.zeros((ny, nx), dtype=np.float64)
    on_frac = np.zeros(n)
    on_qe = on_frac if qe is None else np.zeros(n)      # the share collected, QE in
    stamp_frac = np.zeros(n)
    rendered = np.zeros(n, dtype=bool)
    radius = _stamp_radii(psf, fl, stamp_radius, min_rate, max_stamp_radius)

    ix0 = np.floor(xs + 0.5)
    iy0 = np.floor(ys + 0.5)
    overlaps = ((ix0 + radius >= 0) & (ix0 - radius <= nx - 1)
                & (iy0 + radius >= 0) & (iy0 - radius <= ny - 1))
    if not overlaps.any():
        return image, _info_table(xs, ys, fl, on_frac, on_qe, stamp_frac, radius,
                                  rendered)

    rmax = int(radius[overlaps].max())
    stamps = psf._stamp_factory(rmax)
    cost = float(getattr(stamps, "cost_per_pixel", 1.0))
    flat_image = image.reshape(-1)

    for r in np.unique(radius[overlaps]):
        members = np.flatnonzero(overlaps & (radius == r))
        size = 2 * int(r) + 1
        per_source = size * size * cost
        chunk = max(1, int(_CHUNK_ELEMENTS // per_source))
        for start in range(0, members.size, chunk):
            sel = members[start:start + chunk]
            ixc = ix0[sel].astype(np.intp)
            iyc = iy0[sel].astype(np.intp)
            st = stamps(ixc - xs[sel], iyc - ys[sel], int(r))          # (m, S, S)
            stamp_frac[sel] = st.sum(axis=(1, 2))
            offs = np.arange(-int(r), int(r) + 1)
            cols = ixc[:, None] + offs[None, :]                           # (m, S)
            rows = iyc[:, None] + offs[None, :]
            okx = (cols >= 0) & (cols < nx)
            oky = (rows >= 0) & (rows < ny)
            ok = oky[:, :, None] & okx[:, None, :]
            idx = rows[:, :, None] * nx + cols[:, None, :]
            if blind_flat is not None:                 # reference pixels: nothing
                ok[ok] = ~blind_flat[idx[ok]]
            on_frac[sel] = np.where(ok, st, 0.0).sum(axis=(1, 2))
            if qe_flat is not None:
                st = st * np.where(ok, qe_flat[np.where(ok, idx, 0)], 0.0)
                on_qe[sel] = np.where(ok, st, 0.0).sum(axis=(1, 2))
            weights = st * fl[sel][:, None, None]
            np.add.at(flat_image, idx[ok], weights[ok])
            rendered[sel] = True
    return image, _info_table(xs, ys, fl, on_frac, on_qe, stamp_frac, radius, rendered)


def _info_table(xs, ys, fl, on_frac, on_qe, stamp_frac, radius, rendered):
    lost = np.where(rendered, fl * (1.0 - stamp_frac), 0.0)
    table = Table()
    table["x"] = xs
    table["y"] = ys
    table["flux"] = fl
    table["flux_on_array"] = fl * on_qe
    table["frac_on_array"] = on_frac
    table["flux_lost_stamp"] = lost
    table["stamp_radius"] = np.asarray(radius, dtype=np.int64)
    table["rendered"] = rendered
    for name in ("x", "y", "stamp_radius"):
        table[name].unit = "pix"
    for name in ("flux", "flux_on_array", "flux_lost_stamp"):
        table[name].unit = "electron / s"
    return table


def encircled_energy(psf, radius):
    """Fraction of the PSF flux within ``radius`` pixels of its centre.

    Parameters
    ----------
    psf : GaussianPSF, AiryPSF or ImagePSF
        The PSF (the optical PSF, before pixel integration).
    radius : float or array_like
        Aperture radius, pixels (>= 0, finite).

    Returns
    -------
    float or ndarray (shape of ``radius``), float64
        ``1 - exp(-r**2 / (2 sigma**2))`` for the Gaussian; ``1 - J0(v)**2 - J1(v)**2``,
        ``v = pi r / a``, for the Airy pattern; for an image, the exact overlap of the
        circle with the sub-pixel squares (each holding its flux uniformly), by
        photutils' exact circular-aperture photometry.  An :class:`ImagePSF` with
        ``normalize=False`` tends to its image sum, not 1, at large radius.
    """
    if not isinstance(psf, _PSF_TYPES):
        raise ParameterError(
            f"'psf' must be a GaussianPSF, AiryPSF or ImagePSF, got {type(psf).__name__}")
    try:
        r = np.asarray(radius, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise ParameterError(f"'radius' must be numbers (pixels), got {radius!r}") from exc
    if not np.all(np.isfinite(r)) or np.any(r < 0):
        raise ParameterError(f"'radius' must be finite and >= 0 (pixels), got {radius!r}")
    if isinstance(psf, GaussianPSF):
        out = -np.expm1(-0.5 * r * r / psf.sigma ** 2)
    elif isinstance(psf, AiryPSF):
        v = math.pi * r / psf._a
        out = 1.0 - j0(v) ** 2 - j1(v) ** 2
    else:
        ny, nx = psf.data.shape
        centre = ((nx - 1) / 2.0, (ny - 1) / 2.0)
        flat = r.ravel()
        vals = np.empty(flat.size)
        for k, rk in enumerate(flat):        # one aperture per requested radius
            if rk == 0:
                vals[k] = 0.0
                continue
            from photutils.aperture import CircularAperture   # lazy (module notes)
            ap = CircularAperture(centre, r=rk * psf.oversample)
            vals[k] = ap.do_photometry(psf.data, method="exact")[0][0]
        out = vals.reshape(r.shape)
    return out[()] if np.ndim(out) == 0 else out
