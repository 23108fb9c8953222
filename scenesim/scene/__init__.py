"""Declarative scene files: TOML validated into frozen dataclasses.

A scene file says *what* to simulate: the detector and its clocking, the noise, the
readout pattern, the sources of charge, the detector effects, the outputs and the seed.
It is read with the standard library (:mod:`tomllib`; ``tomli`` on Python 3.10) and
validated, before any work starts, into frozen (hashable, picklable) dataclasses
(:mod:`scenesim.scene.schema`) by :func:`load_scene` / :func:`parse_scene`
(:mod:`scenesim.scene.parse`):

=========================  ==================================================
TOML table                 dataclass
=========================  ==================================================
``[detector]``             :class:`noise.clock.Detector` (with ``Subarray``)
``[noise]``                :class:`noise.params.NoiseParams`
``[readout]``              :class:`ReadoutConfig` (``build()`` -> ``Readout``)
``[sources]``              :class:`SourcesConfig`, :class:`PSFConfig`,
                           :class:`StarConfig`, :class:`LightCurveConfig`
``[effects]``              :class:`EffectsConfig`
``[output]``               :class:`OutputConfig`
``[instrument]``           :class:`~scenesim.pipelines.instrument.InstrumentConfig`
top level                  :class:`Scene` (``seed``, ``description``)
=========================  ==================================================

Every key
---------
Units: rates e-/s, charges e-, times s, positions pixels, ``gain`` e-/DN.  "Required"
keys have no default; every other key may be left out.

Top level

* ``seed``: integer in ``[0, 2**63 - 1]``; default none (see *Seeds*).
* ``description``: free text; default ``""``.

``[detector]`` -- the array and its clock (:class:`noise.clock.Detector`)

* ``preset``: ``"H1RG"``, ``"H2RG"``, ``"H4RG-10"``, ``"H4RG-15"``, or an
  instrument's clock: ``"NIRCAM"``, ``"NIRSPEC"`` (JWST; a one-output window matches
  JWST's frame time with ``nfoh = 2``), ``"NIRSPEC-IRS2"`` (NIRSpec's IRS2 readout,
  14.589 s frames) or ``"WFI"`` (Roman, 3.04 s frames)
  (case-insensitive); default ``"H2RG"``.  ``noise.clock.PRESETS`` cites the source
  of every value.  Every key below defaults to the preset's
  value (``noise.clock.PRESETS``; H2RG values in brackets).
* ``name``: label [``"H2RG"``].
* ``naxis1``, ``naxis2``: full-array columns and rows, reference pixels included
  [2048, 2048].
* ``n_out``: video outputs of the full array, dividing ``naxis1`` [4].
* ``nroh``: new-row overhead, pixel times [12].  ``nfoh``: new-frame overhead, rows
  [1].
* ``dt``: pixel dwell time per output, s [1e-5].
* ``ref_border``: width of the reference-pixel border, pixels [4].
* ``reverse_scan``: reverse every output's fast-scan direction [false].
* ``pixel_pitch``: micrometres, for cosmic-ray rates per cm^2 [18].
* ``interleave``: interleaved reference samples (IRS2) in every output row, a table
  ``{normal = 16, reference = 4, jump = 1}`` or a list ``[16, 4, 1]``
  (``noise.clock.Interleave``) [none; ``NIRSPEC-IRS2``: 16, 4, 1].
* ``ref_output``: a reference output read in step with the science outputs [false;
  ``NIRSPEC-IRS2``: true].

``[detector.subarray]`` -- a readout window (absent: full frame)

* ``kind``: ``"window"`` (read through one output; default) or ``"stripe"`` (full
  width, all outputs).
* ``x0``, ``y0``: first column and row on the full array; default 0.
* ``nx``: columns (required for a window; a stripe is ``naxis1`` wide).
* ``ny``: rows (required).
* ``name``: label written to headers; default ``""``.

``[noise]`` -- amplitudes in e-, read noise **per read** (not CDS)
(:class:`noise.params.NoiseParams`, whose docstring defines the amplitudes)

* ``preset``: ``"nirspec"`` (default; Rauscher 2015 Table 1) or ``"none"`` (every
  amplitude 0, including the bias).  The keys below override the preset's values;
  ``"nirspec"`` values in brackets.
* ``rd_noise``: white read noise per read, e- rms; one value or one per active output
  [5.2].
* ``ref_ratio``: reference-pixel / regular-pixel white noise [0.8].
* ``c_pink``: correlated 1/f noise [3.0].  ``u_pink``: uncorrelated 1/f noise, one
  value or one per active output [1.0].  ``acn``: alternating column noise, one value
  or one per active output [0.5].  ``pca0``: picture-frame noise [0.2].
* ``pedestal``: per-frame offset, rms [4.0].  ``ktc``: reset noise per pixel per
  integration, rms [29.0].
* ``bias_offset``: constant reset level [5000]; with the bias pattern's extremes it
  must lie 5 rms spreads of the other components (each 1/f one at its whole rms)
  inside the ADC range ``[0, gain (2**adc_bits - 1)]`` e-, so that the ADC clips no
  noise (:meth:`noise.NoiseParams.check_adc`; ``preset = "none"`` sets it to 0: with
  any noise added, set it too).  ``bias_amp``: fixed bias pattern amplitude [500].
* ``rtn_fraction``: fraction of regular pixels with random telegraph noise, in [0, 1]
  [0].  ``rtn_amp``: step between its levels [20].  ``rtn_tau_low``,
  ``rtn_tau_high``: mean dwell times, s [1.0, 0.3].
* ``f_min``: frequency below which the 1/f PSD is flat, Hz [1e-4].
* ``pink_spectrum``: ``[[f_Hz, psd], ...]``, a PSD shape replacing 1/f for every pink
  component [none].
* ``pca0_file``: FITS picture-frame/bias template, the full array or the read-out
  image [none: the synthetic template].

``[readout]`` -- required, in exactly one of four forms (:class:`ReadoutConfig`)

* ``pattern`` with ``ngroups``: a named JWST-like pattern (e.g. ``"RAPID"``,
  ``"MEDIUM8"``; case-insensitive, see :data:`scenesim.detector.readout.NAMED_PATTERNS`).
* ``nframes`` with ``ngroups``, ``groupgap``, ``nskip``: MULTIACCUM by numbers:
  frames averaged per group (>= 1), groups (>= 1), frames dropped between groups
  (default 0) and after reset (default 0).
* ``ma_table``: ``[[first_read, nreads], ...]``, Roman-like, reads counted from 0
  after reset.
* ``resultants``: ``[[read, ...], ...]``, the read indices averaged into each
  resultant.
* With any form: ``nints`` (integrations, >= 1; default 1), ``reset``
  (``"rolling"``, default, or ``"global"``; ``docs/CONVENTIONS.md``).  ``name``
  labels an ``nframes``/``ma_table``/``resultants`` pattern (default ``"CUSTOM"``,
  ``"MA_TABLE"`` for an MA table).

``[sources]`` -- what makes charge (:class:`SourcesConfig`)

* ``dark_current``: e-/s per pixel (>= 0) or a FITS map; default 0.
* ``hot_pixel_fraction``: fraction of regular pixels that are hot, in [0, 1];
  default 0.
* ``hot_pixel_rate``: extra dark current of a hot pixel, e-/s: one value, or ``[min,
  max]`` drawn log-uniformly (``0 < min <= max``); default ``[1, 100]``.
* ``background``: sky/thermal background, e-/s per pixel (>= 0) or a FITS map;
  default 0.
* ``catalogue``: ECSV/FITS table of point sources (default none), read by
  :func:`scenesim.sky.sources.read_catalogue`: columns ``x``, ``y`` (pixels of the
  read-out image), ``flux`` (e-/s, converted if it has a unit), optional ``id`` and
  ``light_curve`` (the **name** of a ``[sources.light_curves.NAME]`` entry; empty for
  a constant source).  Column names are case-insensitive.  The truth file's
  ``SOURCES`` lists the inline ``[[sources.stars]]`` first, then the catalogue's rows
  in its order (catalogue row ``i`` is ``SOURCES`` row ``len(stars) + i``), with the
  catalogue's ``id`` and its other columns (null on the inline stars' rows; one named
  as a rendering column, e.g. ``flux_on_array``, as ``catalogue_flux_on_array``).

``[sources.psf]`` -- the PSF of every point source (:class:`PSFConfig`)

* ``kind``: ``"gaussian"`` (default), ``"airy"`` or ``"image"``.
* ``fwhm`` (gaussian): full width at half maximum, pixels (> 0); default 2.0.
* ``radius`` (airy): radius of the first dark ring, pixels (> 0); default 2.5.
* ``file`` (image, required): FITS image of flux per sub-pixel summing to 1;
  ``oversample`` (image): sub-pixels per pixel (>= 1; default the file's ``OVERSAMP``,
  else 1); ``normalize`` (image): require a unit sum within 1e-3 and rescale to it
  (default true; false uses the image as given).
* ``min_rate``: stamp pixels below this rate are skipped, e-/s (>= 0); default 0.

``[[sources.stars]]`` -- inline point sources (:class:`StarConfig`), any number

* ``x``, ``y`` (required): position, pixels of the read-out image.
* ``flux`` (required): total rate over the PSF, e-/s (>= 0).
* ``light_curve``: name of a ``[sources.light_curves.NAME]`` entry; default none
  (constant).

``[sources.light_curves.NAME]`` -- ``kind`` (required) and its keys, see *Light
curves* (:class:`LightCurveConfig`).

``[effects]`` -- the detector on the charge, and the ADC (:class:`EffectsConfig`)

* ``cosmic_ray_rate``: hits per cm^2 per s (>= 0); default 0 (about 5 in space at
  L2).
* ``cosmic_ray_charge``: ``[median_e, sigma_ln]``, log-normal charge per hit: median
  e- (> 0) and sigma of ln(charge) (>= 0); default ``[1000, 0.7]``.
* ``full_well``: e- (> 0) or a FITS map; default none (no saturation).
* ``nonlinearity``: ``[c2, c3, ...]`` of ``m = q + c2 q**2 + c3 q**3 + ...``; default
  ``[]`` (linear).  Needs ``full_well`` and must be monotonic up to it.
* ``ipc_alpha``, ``ipc_alpha_diag``: nearest-neighbour and diagonal IPC coupling
  (>= 0); default 0.  ``ipc_kernel``: an explicit 3x3 kernel (>= 0, summing to 1)
  instead; default none.
* ``flat``: relative quantum efficiency (>= 0), scalar or FITS map; default 1.  It
  scales the light (background and sources) before the Poisson draws, so the charge
  stays Poisson; dark current and hot pixels are not scaled
  (:mod:`scenesim.detector.flat`).
* ``gain``: e-/DN (> 0); default 1.
* ``adc_bits``: ADC resolution, 1 to 16; default 16.

``[instrument]`` -- the JWST identity of the exposure, used by the JWST uncal file
(``scenesim run --uncal``; :class:`scenesim.pipelines.instrument.InstrumentConfig`).
Every key is optional and inferred when absent:

* ``name``: ``"NIRCAM"``, ``"NIRSPEC"``, ``"NIRISS"`` or ``"FGS"``; default NIRSpec
  for the NIRSpec patterns (``NRSRAPID``, ``NRSRAPIDD1``/``D2``/``D6``, ``NRS``), NIRISS
  for ``NISRAPID``/``NIS``, else NIRCam.
* ``detector``: one of the instrument's (``"NRCA1"`` ... ``"NRCBLONG"``, ``"NRS1"``,
  ``"NRS2"``, ``"NIS"``, ``"GUIDER1"``, ``"GUIDER2"``); default the first.
* ``exp_type``: JWST ``EXP_TYPE`` with the instrument's prefix (``"NRC_IMAGE"``,
  ``"NRS_DARK"``, ...); default ``NRC_IMAGE``, ``NRS_IMAGE``, ``NIS_IMAGE`` or
  ``FGS_IMAGE``.
* ``subarray``: a JWST subarray name; default ``"FULL"`` for a full frame, else
  ``"GENERIC"`` (the place is in ``SUBSTRT``/``SUBSIZE``).

``[output]`` -- what to write (:class:`OutputConfig`)

* ``path``: exposure file, ``.fits`` or ``.fits.gz``; default ``"exposure.fits"``
  (see *Paths*).
* ``truth``: also write ``<stem>_truth.fits``; default true.
* ``save_charge``, ``save_noise``: put the noise-free signal (the charge after
  saturation, nonlinearity and IPC) / the noise-only resultants in the truth file
  (need ``truth``); default false.
* ``ramp``: write the ramp file; default true (false keeps only the slopes and needs
  ``fit``).
* ``fit``: ``""`` (none, default), ``"cds"``, ``"ols"`` or ``"gls"``.
* ``refpix``: reference-pixel correction before the fit, ``"none"``, ``"median"``,
  ``"jwst"`` (default) or ``"irs2"`` (interleaved reference samples; an IRS2
  detector).  A correction the readout cannot support is refused (``"median"``
  without top/bottom reference rows, ``"irs2"`` without interleaving); ``"jwst"`` on
  a window with no reference pixel has nothing to subtract, and the fit records
  ``REFPIX = 'none'`` (:func:`scenesim.calib.refpix.applied_scheme`).
* ``compare``: compare the fitted slopes with the truth (needs ``fit``); default false.

Validation rules
----------------
* Unknown keys are rejected with the nearest valid name and the table path, e.g.
  ``unknown key 'backgroud' in [sources]; did you mean 'background'?``.
* Types and ranges are checked (a negative or NaN rate names its key); files named by
  the scene must exist (:class:`~noise.errors.FileFormatError`).
* Files are opened once, when the scene is loaded (:func:`check_files`): FITS maps
  have their shape checked against the detector from the header alone (their values
  are checked when the run loads them, :func:`scenesim.sky.maps.load_map`); the
  catalogue and light-curve files are read and their columns checked; an image PSF is
  read.  Changing a scene (``Scene.replace``, ``dataclasses.replace``) re-checks the
  values but reads no file.
* Cross-checks: stars and catalogue rows reference defined light curves, exactly one
  readout form, per-output noise amplitudes match the active outputs, the
  nonlinearity is monotonic up to the full well, ``ramp = false`` needs a fit, ...
* :func:`load_scene` builds the readout once (:meth:`ReadoutConfig.build`) so an unknown
  pattern name or a bad MA table fails at load time.
* Charge: no pixel may collect more than 2**53 e- in an integration.  Scalar rates are
  checked when the scene is built; the sum in each pixel (maps, flat, catalogue rows,
  ``file`` light curves at their peak) when the run loads them, before any work
  (:func:`scenesim.sky.rates.scene_rates`), naming what puts the charge there: the map
  file and the pixel, the catalogue file, row and ``id``, the inline star, the light
  curve and its peak.

Every error is a :class:`~noise.errors.ParameterError` or
:class:`~noise.errors.FileFormatError` (both :class:`ValueError`) whose message names the
table, the key, the bad value and what is allowed; :func:`load_scene` prefixes the scene
file's path.

Paths
-----
Every relative file path *inside* a scene (maps, catalogue, PSF image, light-curve
files, ``noise.pca0_file``) is resolved relative to the scene file's directory and
stored as an absolute path string.  The exception is ``[output] path``: it is kept as
written and is relative to the current working directory of the process that runs the
scene, so the same scene can be run from anywhere and writes there.  A FITS map holds
the full array (the read-out window is cut from it) or the read-out image
(:mod:`scenesim.sky.maps`).

Coordinates, times and units
----------------------------
Star positions ``x, y`` are 0-based pixel coordinates of the read-out image (column, row;
for a subarray, relative to its first pixel), with pixel centres at integers.  Rates are
e-/s (star ``flux`` is the total rate over the whole PSF); charges e-; ``gain`` e-/DN.
Light-curve times are seconds from the start of the exposure: the start of the reset
frame of integration 0, the same clock as ``docs/CONVENTIONS.md`` (slot ``s`` of a pixel
is at ``s * t_frame + t_pix``).

Light curves
------------
A light curve is a dimensionless factor ``f(t) >= 0`` multiplying a star's flux,
built by :meth:`LightCurveConfig.build` as a
:class:`scenesim.sky.lightcurve.LightCurve` (piecewise linear, with exact interval
integrals):

* ``transit`` (``t0``, ``duration``, ``depth``, ``ingress = 0``): trapezoid centred on
  ``t0``, ``f = 1 - depth`` on the flat bottom, total length ``duration`` from first to
  fourth contact, linear ingress and egress of length ``ingress`` each
  (``ingress <= duration / 2``; 0 is a box).
* ``step`` (``t_on``, ``before = 1``, ``after``): ``f = before`` for ``t < t_on``, else
  ``after``.  :meth:`LightCurve.step <scenesim.sky.lightcurve.LightCurve.step>` has
  the same default.
* ``flare`` (``t0``, ``amplitude``, ``rise = 0``, ``decay``): ``f = 1`` before
  ``t0 - rise``, then a **linear** rise to the peak ``1 + amplitude`` at ``t0``
  (``rise`` is the rise's duration; 0 is a jump), then an exponential decay
  ``f = 1 + amplitude * exp(-(t - t0) / decay)``, sampled finely enough that ``f`` is
  within ``1e-4 * amplitude`` of it.
* ``table`` (``time``, ``flux``): samples at strictly increasing times, linear
  interpolation, constant beyond the ends.
* ``file`` (``file``): ECSV or FITS table with columns ``time`` and ``flux``
  (relative), read by :meth:`LightCurve.from_file
  <scenesim.sky.lightcurve.LightCurve.from_file>`: a ``time`` column with a unit (e.g.
  ``h``, ``d``) is converted to seconds, without one it is seconds; ``flux`` has no
  unit or a dimensionless one (``%`` is converted), any other (``mag``, ``Jy``) is
  refused; used like ``table`` (two equal consecutive times make a step).

Seeds
-----
``seed`` (an integer in ``[0, 2**63 - 1]``, so it fits TOML and FITS) is stored in the
scene and written to every output header.  Without one the scene is random:
:meth:`Scene.ensure_seed` draws a fresh seed from OS entropy and returns a scene that
records it, so any run can be repeated.
"""

from scenesim.scene.parse import NOISE_PRESETS, check_files, load_scene, parse_scene
from scenesim.scene.schema import (EffectsConfig, LightCurveConfig, OutputConfig,
                                   PSFConfig, ReadoutConfig, Scene, SourcesConfig,
                                   StarConfig)

__all__ = [
    "PSFConfig",
    "StarConfig",
    "LightCurveConfig",
    "SourcesConfig",
    "ReadoutConfig",
    "EffectsConfig",
    "OutputConfig",
    "Scene",
    "load_scene",
    "parse_scene",
    "check_files",
    "NOISE_PRESETS",
]
