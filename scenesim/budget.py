"""The memory and disk a scene's run needs, estimated before anything is built.

:func:`check_budget` takes a validated :class:`~scenesim.scene.Scene` and, in a
fraction of a millisecond (arithmetic on the scene's numbers: no array is made, no
file is read), estimates

* the **peak memory** of the run: the simulation (the charge engine's frames, the
  noise generator, the cosmic rays), then the fit and the comparison when the scene
  asks for them, then the pipeline products (``--uncal``, ``--reffiles``) when the
  command writes them (their peaks do not overlap: the engine's frames are freed
  first; the engine's maps and noise generator stay);
* the **output**: the exposure, the truth file (with the temporary raw cubes of
  ``save_charge`` / ``save_noise``, which sit beside it while it is written) and the
  fit file, uncompressed (a ``.fits.gz`` output is smaller; the estimate is an upper
  bound);

and compares them with the machine: the memory available now (``MemAvailable`` of
``/proc/meminfo``, bounded by the cgroup limit ``memory.max - memory.current`` when
there is one; else ``os.sysconf`` ``SC_AVPHYS_PAGES * SC_PAGE_SIZE``) and the free
space of the output directory (:func:`shutil.disk_usage`).  A run is refused
(:class:`~noise.errors.ParameterError`, one line naming the estimate, the limit, the
scene keys that drive it and the override ``--force``) when

* its memory exceeds :data:`MEMORY_FRACTION` (80 %) of the available memory: the
  rest is left to the page cache and the other processes; above it a run thrashes
  or dies with a MemoryError, or the kernel kills it, after minutes of work;
* its output exceeds the free disk space;

and :meth:`Budget.warning` returns a one-line warning (nothing is refused) above
:data:`WARN_FRACTION` (50 %) of either, which :meth:`Budget.warn` issues as a
:class:`BudgetWarning` (the commands print it as one line: :func:`one_line_warnings`).
:func:`scenesim.run.run_scene` (``force=False``) and the commands ``scenesim run`` and
``scenesim noise`` (``--force``) check the budget after the output paths and before
anything is built, read or removed.  Before (issue 12) ``naxis = 400000`` or
``cosmic_ray_rate = 1e12`` ended in a MemoryError traceback after the work had
started; both are now refused in milliseconds.

The model
---------
``P = ny * nx`` pixels read out, ``N = nints * ngroups * P`` resultant values; a
detector with interleaved reference samples or a reference output (IRS2:
``Detector.interleave``, ``ref_output``) reads ``X = ny * raw_nx`` samples a frame
(:meth:`~noise.clock.Detector.raw_columns`), ``R = X - P`` of them not pixels
(NIRSpec IRS2: ``X = 3200 x 2048 = 1.5625 P``), ``N_R = nints * ngroups * R`` and
``N_raw = nints * ngroups * X`` over the exposure (otherwise ``R = N_R = 0``, ``X =
P``, ``N_raw = N``); ``E``
the expected cosmic-ray hits, ``rate * A * T``: ``rate`` (/cm^2/s) times the read-out
area ``A = P * (pixel_pitch * 1e-4)**2`` cm^2 times the exposure time ``T =
nints * (1 + nreads) * t_frame``.  Bytes (each part is listed in
:attr:`Budget.memory_parts`, labelled with the scene keys that drive it):

=============================  ===========================================================
part                           bytes
=============================  ===========================================================
rate and pixel maps            ``33 P``: the scene's rate map and the engine's copy
                               (float64 each), the reference mask, the clock's sample
                               index (int32), the truth's expected rate (float64 and
                               float32)
charge frames                  ``18 P``: the integer charge (int64 at most), the float32
                               charge after the effects, one uint32 DN sum of the open
                               resultant (resultants never overlap) and its uint16 mean
IPC                            ``16 P`` with IPC: the convolved frame (float64 and
                               float32)
FITS maps                      ``8 naxis1 naxis2 + 8 P`` per map file (dark current,
                               background, flat, full well): the file's data (the full
                               array at most) and its window (float64)
saturation                     ``6 nints P``: first saturated read and resultant (int16;
                               int32 beyond 32767 reads, twice that) and a temporary
saved cubes                    ``28 P`` per ``save_charge`` / ``save_noise``: the float64
                               sum, its mean, the float32 and big-endian copies written
raw samples                    (IRS2, reference output) ``36 R``: their noise and its
                               kTC level (float32), the level's draw, the samples in
                               float64 and their codes, the DN sum of the open
                               resultant and its mean, the gather; with noise ``+ 4 X``
                               (the raw frame, float32) ``+ 4 P`` (the image frame
                               taken out of it) ``+ 8 (ny + nfoh) row_samples`` (two
                               time lines of a frame)
hot pixels                     ``24 hot_pixel_fraction P``
variable stars                 ``266 kB`` per inline star with a light curve (its stamp,
                               at most 129 x 129 pixels of index and weight)
cosmic rays                    ``1700 E``: 9 deposits per hit, through the draw (offsets,
                               multinomial split), the engine's arrays and the truth's
                               table (measured: 1.62 kB per hit on a 256 x 256 array)
noise generator                frames: ``4 P`` for the noise frame, ``+ 4 P`` for the
                               reset level (``ktc`` or ``bias_amp``), ``+ 4 P`` for the
                               template (``pca0`` or ``bias_amp``); the 1/f line buffers
                               ``s * njobs * min(512, ny) * row_samples * 4`` (``njobs``:
                               the correlated series, and one per output with ``u_pink``,
                               with ``acn``; ``s = 3`` sets for frames of at least
                               :data:`LARGE_FRAME_PIXELS`, whose lines forked helpers may
                               make, else 2); the 1/f synthesis: 36 MB once, 12 MB per
                               distinct sample rate (pixel rate, half of it for ACN, row
                               rate for ``pca0``) and 3 MB per series (ACN: 2 per
                               output; a reference output has its own ``u_pink`` and
                               ACN pair); the bias template (``pca0`` or ``bias_amp``):
                               ``48 (naxis1 + naxis2)`` for the synthetic one (its row
                               and column profiles), ``8 naxis1 naxis2 + 24 P`` for a
                               ``pca0_file``
slopes only                    ``2 (N + N_R)`` with ``ramp = false``: the resultants
                               (and ``RAWREF``) are kept in memory for the fit
fit                            ``44 MB + 72 P + 8 N + 4 nints P`` (``+ 4 N`` with IPC,
                               undone first): the prepared resultants (float32) and
                               flags, the fitter's row chunks and its maps; on top of
                               the engine's rate maps and noise generator, which the
                               run keeps
IRS2 correction                ``2 N_R + 4 N_raw + 12 N_raw / n_out`` with ``refpix =
                               'irs2'``: the exposure's ``RAWREF``, the raw resultants
                               (float32), one output's samples (float32 and float64); its
                               float64 cube (``8 N``) is gone before the fitter's arrays
                               are made
products                       after the run, on top of the engine's maps and noise
                               generator: 32 MB (the data models' schemas) and the
                               larger of the uncal, ``2 (N + N_R)`` (the exposure read
                               back) ``+ 2 N_raw`` (IRS2: the raw cube assembled) ``+ 6
                               N_u`` (``SCI`` and ``GROUPDQ`` and their big-endian copies
                               as written; ``N_u = N_raw`` for IRS2, else ``N``), and the
                               references: ``36 P`` (the ``DetectorReference``: read
                               noise, bias, saturation, dark float64, mask uint32) plus
                               the larger family peak.  JWST writes one model at a time,
                               the largest the dark, ``20 G P + 4 P`` (``G = ngroups``:
                               its float64 cube, float32 data and err, their big-endian
                               copies, dq), or the linearity ``(8 nc + 4) P`` (``nc =
                               7`` planes and their copy), or IRS2's refpix table
                               ``136 ny row_samples``.  Roman holds every array at once:
                               ``28 P`` (gain, readnoise, mask, saturation, one zero dq,
                               dark and its error, float32), nonlinear ``+ (4 n_nl + 4 nc
                               + 32) P``: the inverse (``n_nl = 2 +`` the scene's
                               nonlinearity terms) and linearity cubes (float32), built
                               from the float64 bias in DN by Horner steps (``-b``, the
                               running sum and its next value)
=============================  ===========================================================

The coefficients were fitted to the peak RSS (``VmHWM`` after the imports; MB =
2**20 bytes) of runs on this machine, to stay at or a little above it.  A 1024 x 1024
H2RG-like array, RAPID x 10, background only: 48 MB measured (estimate 57 MB); with
IPC 63 MB (73 MB); with both saved cubes 102 MB (113 MB); with an OLS fit 208 MB (233
MB); with a GLS fit of RAPID x 5 189 MB (193 MB), of RAPID x 20 311 MB (313 MB); with
the paper's noise 162 MB (193 MB).  512 x 512 with noise 115 MB (136 MB), with noise
and a GLS fit 192 MB (213 MB); noise alone on a 4096 x 4096, 32-output array 574 MB
(596 MB); 10**6 cosmic-ray hits on a 256 x 256 array 1623 MB (1631 MB); a 64 x 64
window with noise, 200 integrations, 59 MB (89 MB: the 1/f costs, fitted on full
frames, are smaller for short time lines).  IRS2 (preset ``NIRSPEC-IRS2`` on 512 x
512, 4 groups, 2 integrations, the paper's noise): the simulation 141 MB (157 MB), an
OLS fit with ``refpix = 'irs2'`` 197 MB (244 MB), with ``refpix = 'none'`` 178 MB
(221 MB).  The products, nonlinear with dark current and hot pixels, the whole run's
peak: Roman references of a 4096 x 4096 WFI frame (no noise) 1897 MB (2800 MB), of
2048 x 2048 with noise 743 MB (905 MB), of 1024 x 1024 281 MB (341 MB), of 512 x 512
(no noise) 51 MB (75 MB); JWST references of 1024 x 1024 RAPID x 10 375 MB (441 MB),
of 512 x 512 72 MB (100 MB); the uncal of 1024 x 1024 RAPID x 10 246 MB (281 MB).
Pages of zeros that are never written (zero dq and error arrays, a zero bias or read
noise without noise) and the allocator's reuse of freed memory on small arrays make
the products' measured peaks 1.2 to 1.5 times below the estimate.  The estimates in
parentheses were made with two 1/f line sets; frames of 65536 pixels or more now count
a third (the forked helpers' result slots, 2026-11-27): with the paper's noise 2.5 MB
more at 512 x 512, 4.7 MB at 1024 x 1024, 9.2 MB at 2048 x 2048 and 18.8 MB at 4096 x
4096 with 32 outputs.
``tests/test_budget.py`` checks the formula against hand-computed values and against
measured runs.

Outputs (bytes): exposure ``2 N + 4 N_R`` (``SCI``; ``RAWREF`` and its temporary
raw copy, which sits beside it until the file is complete; none with ``ramp =
false``); truth ``8 P + 4 nints
P + 33 * 9 E`` (``RATE`` and ``RATE_IPC`` float32, ``SATREAD`` and ``SATGROUP`` int16,
int32 beyond 32767 reads,
the ``CRS`` table) ``+ 8 N`` per saved cube (the cube in the file and its temporary
raw copy); fit file ``32 P + 8 nints P`` (eight maps and two per-integration cubes);
plus 64 kB of headers and tables per file.  The pipeline products of ``scenesim run``
(:data:`PRODUCTS`): the JWST uncal ``3 N + 4 P + 2 nints P`` (uint16 ``SCI``, uint8
``GROUPDQ``, uint32 ``PIXELDQ``, uint16 ``ZEROFRAME``), for IRS2 ``3 N_raw + 4 X``
(every raw sample, no ``ZEROFRAME``); the Roman L1 ``2 N`` plus the amp33 channel,
``2 x 128 ny`` per resultant; the reference files (float32 or uint32 planes of ``4
P``, uncompressed): JWST 16 planes (gain, readnoise, mask; saturation and dq;
superbias, err and dq; 7 linearity planes and dq) ``+ (8 G + 4) P`` (the dark's data
and err cubes, dq) ``+ 64 ny row_samples`` for IRS2 (the refpix table: ``2 ny
row_samples`` rows of 8 float32 columns); Roman 8 planes (gain, readnoise, mask;
saturation and dq; dark, error and dq) and, nonlinear, ``nc + 1 + n_nl + 1`` more (the
linearity and inverse cubes with their dq); the families ``--reffiles`` writes
(:func:`scenesim.pipelines.command.reference_families`: JWST for a JWST-sized
MULTIACCUM readout, Roman with ``--l1`` or else), plus their headers.  A ``ZEROFRAME``
re-run happens after the run and needs no more memory.  The L1's memory is not
estimated (1024 x 1024, 3 resultants: 174 MB over the whole run, 163 MB without it;
not measured with many resultants).
"""

import contextlib
import dataclasses
import math
import os
import shutil
import sys
import warnings
from dataclasses import dataclass

import numpy as np

from noise.clock import Detector, exposure_slots
from noise.errors import ParameterError, ScenesimWarning
from noise.fast.memory import available_memory
from noise.fitsio import derived_path
from noise.params import NoiseParams
from noise.validate import check_bool, check_choice, check_instance, check_int, check_path

__all__ = ["Budget", "BudgetWarning", "estimate_budget", "check_budget",
           "check_noise_budget", "check_batch_budget", "one_line_warnings", "available_memory", "free_disk",
           "MEMORY_FRACTION", "WARN_FRACTION"]

#: A run is refused when its memory exceeds this fraction of the available memory.
MEMORY_FRACTION = 0.8
#: :meth:`Budget.warning` warns above this fraction of the available memory or of the
#: free disk space.
WARN_FRACTION = 0.5

_MB = 2.0 ** 20
_HEADERS = 64 * 1024              # headers and small tables of one output file
_CR_BYTES = 1700.0                # memory per cosmic-ray hit
_CR_DEPOSITS = 9                  # pixels per hit (the 3 x 3 footprint)
_CRS_ROW = 33                     # bytes per row of the truth's CRS table
_STAMP = (2 * 64 + 1) ** 2 * 16   # a variable star's stamp: index and weight
_PINK_FIXED = 36 * _MB            # 1/f synthesis: once
_PINK_RATE = 12 * _MB             # ... per distinct sample rate
_PINK_SERIES = 3 * _MB            # ... per series
_FIT_FIXED = 44 * _MB
#: Bytes per resultant value of the row-block chunks a fit has in flight (the
#: differences, weights, masks and the L D L^T recursion's arrays, float32 and
#: float64), beyond the prepared cube's 8 per value.  Measured by a hostile probe
#: (2026-11-27) on 256^2 x 20-200 RAPID resultants, gls and ols on two threads: the
#: peak rose 29 (gls) to 36 (ols) bytes per added value where the estimate rose 8;
#: the larger, so that the estimate bounds every fitter (256^2 x 200: 723 MB
#: estimated, 595 MB gls and 677 MB ols measured, VmHWM with the interpreter).
_FIT_CHUNK_BYTES = 36
_PRODUCT_FIXED = 32 * _MB         # the data models' schemas and validation


class BudgetWarning(ScenesimWarning):
    """A run uses more than :data:`WARN_FRACTION` of the available memory or of the
    free disk space, or exceeds a limit and was forced (:meth:`Budget.warn`)."""


@contextlib.contextmanager
def one_line_warnings(prog):
    """Inside the block, a :class:`~noise.errors.ScenesimWarning` (a
    :class:`BudgetWarning`, a :class:`scenesim.sky.rates.SceneWarning`) is printed on
    stderr as the one line
    ``'<prog>: warning: <message>'`` (Python's default adds the file, the line number
    and the source line); other warnings are shown as before."""
    with warnings.catch_warnings():
        # a command says its own warnings, whatever filter the caller set
        warnings.filterwarnings("always", category=ScenesimWarning)
        show = warnings.showwarning

        def _show(message, category, filename, lineno, file=None, line=None):
            if issubclass(category, ScenesimWarning):
                print(f"{prog}: warning: {message}", file=sys.stderr)
            else:
                show(message, category, filename, lineno, file, line)

        warnings.showwarning = _show
        yield


def _size(n):
    """``n`` bytes for a message: ``'1.5 GB'``."""
    if not math.isfinite(n):
        return "an unbounded amount"
    for unit in ("B", "kB", "MB", "GB", "TB", "PB", "EB"):
        if abs(n) < 1024 or unit == "EB":
            return f"{n:.3g} {unit}" if unit != "B" else f"{n:.0f} B"
        n /= 1024.0
    return f"{n:.3g} EB"


def free_disk(path):
    """Free bytes on the file system of ``path``'s directory (its nearest existing
    ancestor), or None if unknown."""
    directory = os.path.dirname(os.path.abspath(os.fspath(path))) or "."
    while not os.path.isdir(directory):
        parent = os.path.dirname(directory)
        if parent == directory:
            return None
        directory = parent
    try:
        return float(shutil.disk_usage(directory).free)
    except OSError:
        return None


@dataclass(frozen=True)
class Budget:
    """What a run needs, and what the machine has.

    Attributes
    ----------
    memory : float
        Estimated peak memory of the run, bytes (``inf`` when beyond any machine).
    output : float
        Bytes written to the output directory (temporary raw cubes included).
    memory_parts, output_parts : tuple of (str, float)
        The parts that add up to ``memory`` (the peak is the larger of the
        simulation and the fit) and to ``output``: a label naming the scene keys
        that drive the part (or the file), and its bytes.
    cosmic_ray_events : float
        Expected cosmic-ray hits over the exposure.
    available_memory, free_disk : float or None
        Bytes available now (:func:`available_memory`) and free in the output
        directory (:func:`free_disk`); None when unknown (then not checked).
    output_dir : str
        The output directory.
    peak : str
        When the memory peaks (``'simulating'``, ``'fitting (gls)'`` or ``'writing the
        pipeline products (reffiles)'``), named in the messages; empty if not known.
    """

    memory: float
    output: float
    memory_parts: tuple
    output_parts: tuple
    cosmic_ray_events: float
    available_memory: float | None
    free_disk: float | None
    output_dir: str
    peak: str = ""

    def _largest(self, parts):
        label, size = max(parts, key=lambda p: p[1])
        return f"largest part: {_size(size)} for {label}"

    def _memory_where(self):
        where = self._largest(self.memory_parts)
        return f"peak while {self.peak}; {where}" if self.peak else where

    def problems(self):
        """One-line descriptions of the limits this run exceeds (empty if none)."""
        out = []
        if self.available_memory is not None and \
                not self.memory <= MEMORY_FRACTION * self.available_memory:
            out.append(
                f"the run needs about {_size(self.memory)} of memory "
                f"({self._memory_where()}), more than the limit of "
                f"{MEMORY_FRACTION:.0%} of the {_size(self.available_memory)} available "
                f"({_size(MEMORY_FRACTION * self.available_memory)})")
        if self.free_disk is not None and not self.output <= self.free_disk:
            out.append(
                f"the run writes about {_size(self.output)} "
                f"({self._largest(self.output_parts)}), more than the "
                f"{_size(self.free_disk)} free in {self.output_dir!r}")
        return out

    def check(self):
        """Raise :class:`~noise.errors.ParameterError` if a limit is exceeded: one
        line naming the estimate, the limit and the override."""
        problems = self.problems()
        if problems:
            raise ParameterError(
                "; ".join(problems) + "; reduce the scene or pass --force "
                "(force=True) to run anyway")

    def warning(self):
        """A one-line warning when the run uses more than :data:`WARN_FRACTION` of
        the available memory or of the free disk space (or exceeds a limit, when
        forced), else None."""
        problems = self.problems()
        if problems:
            return "forced: " + "; ".join(problems)
        notes = []
        if self.available_memory is not None and \
                self.memory > WARN_FRACTION * self.available_memory:
            notes.append(f"about {_size(self.memory)} of memory "
                         f"({self.memory / self.available_memory:.0%} of the "
                         f"{_size(self.available_memory)} available)")
        if self.free_disk is not None and self.output > WARN_FRACTION * self.free_disk:
            notes.append(f"about {_size(self.output)} of output "
                         f"({self.output / self.free_disk:.0%} of the "
                         f"{_size(self.free_disk)} free in {self.output_dir!r})")
        return ("the run needs " + " and ".join(notes)) if notes else None

    def warn(self, stacklevel=2):
        """Issue :meth:`warning` as a :class:`BudgetWarning`, if there is one."""
        message = self.warning()
        if message is not None:
            warnings.warn(message, BudgetWarning, stacklevel=stacklevel + 1)

    def summary(self):
        """``'memory ~188 MB (available 23 GB), output ~21 MB (free 50 GB)'``."""
        def of(x):
            return "unknown" if x is None else _size(x)
        return (f"memory ~{_size(self.memory)} (available {of(self.available_memory)}), "
                f"output ~{_size(self.output)} (free {of(self.free_disk)})")


def _noise_parts(det, p):
    """Memory parts of the noise generator for ``det`` and amplitudes ``p``."""
    if p.is_silent():
        return []
    P = float(det.ny) * det.nx
    nout = det.n_out_active
    frames = 4 * P
    if p.ktc > 0 or p.bias_amp > 0:
        frames += 4 * P
    if p.pca0 > 0 or p.bias_amp > 0:
        frames += 4 * P
    u_on = int(np.count_nonzero(p.per_output("u_pink", nout))) if p.enabled("u_pink") else 0
    acn_on = int(np.count_nonzero(p.per_output("acn", nout))) if p.enabled("acn") else 0
    merged = nout == 1 and p.c_pink > 0 and u_on > 0
    series = (p.c_pink > 0) + (0 if merged else u_on) + 2 * acn_on + (p.pca0 > 0)
    if det.ref_output:
        # the reference output's own series: one u_pink, an ACN pair
        series += (u_on > 0) + 2 * (acn_on > 0)
    jobs = (p.c_pink > 0) + (0 if merged else u_on) + acn_on
    rates = (p.c_pink > 0 or u_on > 0) + (acn_on > 0) + (p.pca0 > 0)
    # band buffers: two sets on the thread pool; large frames may have their lines
    # made by forked helpers, into three result slots (noise.generator._ForkedLines)
    sets = 3 if P >= LARGE_FRAME_PIXELS else 2
    lines = float(sets) * jobs * min(512, det.ny) * det.row_samples * 4
    pink = (_PINK_FIXED + _PINK_RATE * rates + _PINK_SERIES * series) if series else 0.0
    template = 0.0
    if p.pca0 > 0 or p.bias_amp > 0:
        full = float(det.naxis1) * det.naxis2
        # a FITS template is read whole (float64) and normalised in the window; the
        # synthetic one is made from row and column profiles of the full array
        template = 8 * full + 24 * P if p.pca0_file else \
            48.0 * (det.naxis1 + det.naxis2)
    return [("the noise frames ([noise], [detector] naxis1 x naxis2)", frames + lines),
            ("the 1/f noise synthesis ([noise] c_pink, u_pink, acn, pca0)", pink),
            ("the bias template ([noise] pca0, bias_amp, pca0_file; [detector] naxis1, "
             "naxis2)", template)]


#: Frames of at least this many pixels are made in bands (the default
#: ``noise.generator.Layout().pool_min_pixels``; not imported here: the budget is
#: checked before the heavy imports).
LARGE_FRAME_PIXELS = 1 << 16

#: Pipeline products of ``scenesim run`` counted in the output estimate.
PRODUCTS = ("uncal", "l1", "reffiles")
#: Coefficient planes of a linearity reference
#: (:data:`scenesim.pipelines.reffiles.LINEARITY_DEGREE` + 1).
_LINEARITY_PLANES = 7


def _raw_memory(det, p, P, R, X):
    """Memory of a detector's raw samples during the run (module notes): with noise,
    the raw frame (float32) 4 X, the image frame taken out of it 4 P and two time
    lines of a frame (float32, the correlated one and an output's) 8 (ny + nfoh)
    row_samples; always 36 R: the noise of the samples and its kTC level (float32)
    8 R, the level's draw 2 R, the samples in float64 and their codes 16 R, the DN sum
    of the open resultant (uint32) 4 R and its mean (uint16) 2 R, the gather 4 R."""
    if R == 0:
        return 0.0
    frames = 0.0 if p.is_silent() else \
        4 * X + 4 * P + 8.0 * (det.ny + det.nfoh) * det.row_samples
    return frames + 36 * R


def _raw_sizes(det, nints, ngroups):
    """``(R, N_R, X, N_raw)`` of a detector's raw samples (module notes): the samples
    per frame that are not image pixels, ``ny (raw_nx - nx)`` (0 without interleave or
    reference output), their values over the exposure, the samples per raw frame
    ``ny raw_nx`` and the raw values over the exposure."""
    X = float(det.ny) * det.raw_nx
    R = X - float(det.ny) * det.nx
    return R, nints * ngroups * R, X, nints * ngroups * X


def _reference_sizes(scene, det, ro, products):
    """``(jwst, roman, output, memory)`` of the reference files (``--reffiles``;
    module notes): which families are written, their bytes on disk (uncompressed)
    and the peak memory of writing them (on top of what the run keeps)."""
    from scenesim.pipelines.command import reference_families
    P = float(det.ny) * det.nx
    G = ro.ngroups
    jwst, roman = reference_families(det, ro, l1="l1" in products)
    nonlinear = len(scene.effects.nonlinearity) > 0
    nc = _LINEARITY_PLANES
    n_nl = len(scene.effects.nonlinearity) + 2      # [0, 1, c2 g, c3 g^2, ...]
    irs2 = jwst and det.interleave is not None
    n_line = float(det.ny) * det.row_samples        # samples of a frame's time line
    output, peaks = 0.0, []
    if jwst:
        # gain, readnoise, mask 4 P each; saturation data + dq 8 P; superbias data,
        # err, dq 12 P; linearity nc planes + dq; dark G planes of data and err + dq;
        # IRS2: the refpix table of 2 n_line rows of 8 float32 columns
        output += (4 + 4 + 4 + 8 + 12) * P + 4 * (nc + 1) * P + (8 * G + 4) * P
        output += 64 * n_line if irs2 else 0.0
        # one model at a time; the largest is the dark: its float64 cube 8 G P, the
        # float32 data and err 8 G P, dq 4 P, and a big-endian copy of data and err
        # as it is written 4 G P; the linearity: nc planes, dq and its copy
        # (8 nc + 4) P; IRS2: the filter (float64 frequencies, response, complex64
        # and its float32 pairs, ~40 n_line), the table 32 n_line, its copy written
        # and read back 64 n_line
        peaks += [20 * G * P + 4 * P, (8 * nc + 4) * P]
        if irs2:
            peaks.append(136 * n_line)
    if roman:
        # gain, readnoise, mask 4 P each, saturation and dark as JWST's (8 + 12 P);
        # nonlinear: the linearity (nc planes) and inverse (n_nl planes) with dq each
        output += (4 + 4 + 4 + 8 + 12) * P
        output += 4 * (nc + 1 + n_nl + 1) * P if nonlinear else 0.0
        # every array at once (float32): gain, readnoise, mask, saturation, a shared
        # zero dq 20 P, dark and its error 8 P; nonlinear: the inverse 4 n_nl P and
        # the linearity 4 nc P, built from the float64 bias in DN (8 P) by Horner
        # steps (-b, the running sum and its next value: 24 P)
        peaks.append(28 * P + ((4 * n_nl + 4 * nc + 32) * P if nonlinear else 0.0))
    # the DetectorReference both families are written from: read noise, bias,
    # saturation and dark (float64) and the mask (uint32), 36 P; the data models'
    # schemas and validation, fixed
    memory = _PRODUCT_FIXED + 36 * P + max(peaks, default=0.0)
    return jwst, roman, output, memory


def _product_outputs(scene, path, products, P, N, det, ro):
    """The pipeline products: their outputs (label, bytes) and the peak memory of
    writing them, on top of what the run keeps (module notes)."""
    stem = path[:-len(".fits.gz")] if path.lower().endswith(".fits.gz") else \
        os.path.splitext(path)[0]
    nints, ngroups, ny = ro.nints, ro.ngroups, det.ny
    _, NR, X, Nraw = _raw_sizes(det, nints, ngroups)
    out, memory = [], [0.0]
    if "uncal" in products:
        if det.interleave is not None:
            # IRS2: every raw sample, in the raw frame layout (uint16 SCI and uint8
            # GROUPDQ of the raw cube, uint32 PIXELDQ of the raw frame); no ZEROFRAME
            Nu, size = Nraw, 3 * Nraw + 4 * X
        else:
            Nu, size = N, 3 * N + 4 * P + 2 * nints * P
        out.append((f"the JWST uncal {stem + '_uncal.fits'!r} (--uncal)",
                    size + _HEADERS))
        # the exposure read back (SCI and RAWREF), IRS2: the raw cube assembled
        # (uint16), then the uncal's SCI and GROUPDQ and their big-endian copies
        # as they are written
        memory.append(_PRODUCT_FIXED + 2 * (N + NR)
                      + (2 * Nraw if det.interleave is not None else 0.0) + 6 * Nu)
    if "l1" in products:
        out.append((f"the Roman L1 {stem + '_l1.asdf'!r} (--l1)",
                    2 * N + 2 * 128 * ny * ngroups * nints + _HEADERS))
    if "reffiles" in products:
        _, _, size, mem = _reference_sizes(scene, det, ro, products)
        out.append((f"the reference files in {stem + '_refs'!r} (--reffiles)",
                    size + 10 * _HEADERS))
        memory.append(mem)
    return out, max(memory)


def _index_bytes(nreads):
    """Bytes of a read index (``SATREAD``, ``SATGROUP``), as
    :func:`scenesim.detector.readout.read_index_dtype` gives it (not imported: it
    brings astropy.table to the ``noise`` command)."""
    return 2 if nreads <= 32767 else 4


def fit_values_in_flight(pixels, values_per_pixel, threads=None):
    """Resultant values in the row-block chunks a fit holds at once: each of its
    threads (``PrepareOptions``' default: the cores, at most 8) keeps
    ``scenesim.rampfit.fitter._WINDOW`` chunks of
    :func:`scenesim.rampfit.solver.chunk_pixels` pixels, at most every value."""
    from scenesim.rampfit.fitter import _WINDOW
    from scenesim.rampfit.solver import chunk_pixels
    threads = min(os.cpu_count() or 1, 8) if threads is None else int(threads)
    per = chunk_pixels(values_per_pixel, threads=threads, pixels=int(pixels))
    return min(float(pixels), float(per) * _WINDOW * threads) * values_per_pixel


def estimate_budget(scene, *, options=None, products=()):
    """The :class:`Budget` of running ``scene`` (module notes), without checking it.

    Parameters
    ----------
    scene : scenesim.scene.Scene
        Validated; its ``[output]`` as the run will use it (``path``, ``fit``,
        ``ramp``, ...).
    options : scenesim.engine.EngineOptions, optional
        The engine options of the run (the '2d' shortcut and ``shot_noise = false``
        keep the charge in float64, which the estimate already assumes).
    products : sequence of {'uncal', 'l1', 'reffiles'}
        Pipeline products the command writes after the run (``--uncal``, ``--l1``,
        ``--reffiles``), counted in the output (module notes).
    """
    # imported here: the noise command's budget needs neither (nor their imports)
    from scenesim.engine import EngineOptions
    from scenesim.scene.schema import Scene
    check_instance("scene", scene, Scene, "a scenesim.scene.Scene")
    products = tuple(check_choice("products", p, PRODUCTS) for p in products)
    check_instance("options", options, EngineOptions, "a scenesim.engine.EngineOptions",
                   allow_none=True)
    det, src, eff, out = scene.detector, scene.sources, scene.effects, scene.output
    ro = scene.readout.build()
    P = float(det.ny) * det.nx
    nints, ngroups = ro.nints, ro.ngroups
    N = nints * ngroups * P
    R, NR, X, Nraw = _raw_sizes(det, nints, ngroups)
    t_total = exposure_slots(nints, ro.nreads) * det.frame_time
    cm = det.pixel_pitch * 1e-4
    events = eff.cosmic_ray_rate * (P * cm * cm) * t_total if eff.cosmic_ray_rate else 0.0
    size = f"{det.ny} x {det.nx} pixels"
    maps = len(src.map_files) + len(eff.map_files)
    variable = sum(1 for s in src.stars if s.light_curve is not None)
    sim = [
        (f"the rate and pixel maps ({size}, [detector] naxis1 x naxis2 or the subarray)",
         33 * P),
        (f"the charge frames ({size})", 18 * P),
        ("the IPC frames ([effects] ipc_alpha / ipc_kernel)",
         16 * P if eff.ipc() is not None else 0.0),
        ("the FITS maps ([sources] dark_current, background, [effects] flat, full_well)",
         (8 * float(det.naxis1) * det.naxis2 + 8 * P) * maps),
        ("the saturation maps ([readout] nints)",
         3 * _index_bytes(ro.nreads) * nints * P),
        ("the saved cubes ([output] save_charge, save_noise)",
         28 * P * (out.save_charge + out.save_noise)),
        ("the hot pixels ([sources] hot_pixel_fraction)", 24 * src.hot_pixel_fraction * P),
        ("the variable stars ([[sources.stars]] light_curve)", float(_STAMP * variable)),
        (f"{events:.3g} cosmic-ray hits ([effects] cosmic_ray_rate = "
         f"{eff.cosmic_ray_rate:g} /cm^2/s)", _CR_BYTES * events),
        (f"the raw samples ({R:.3g} per frame besides the pixels, [detector] "
         f"interleave, ref_output)", _raw_memory(det, scene.noise, P, R, X)),
    ]
    # what stays from the simulation through the fit: the engine (its maps and its
    # noise generator, with the 1/f filters) and the resultants of a slopes-only run
    noise = _noise_parts(det, scene.noise)
    kept = [sim[0], ("the resultants kept for the fit ([output] ramp = false)",
                     2 * (N + NR) if not out.ramp else 0.0)] + noise
    fit = []
    if out.fit:
        ipc_copy = 4 * N if eff.ipc() is not None else 0.0      # undo_ipc's output
        fit = kept + [(f"the {out.fit} fit of {N:.3g} resultant values ({size}, "
                       f"[detector] naxis1 x naxis2, [readout] ngroups x nints, [output] "
                       f"fit)",
                       _FIT_FIXED + 72 * P + 8 * N + 4 * nints * P + ipc_copy
                       + _FIT_CHUNK_BYTES * fit_values_in_flight(P, nints * ngroups))]
        if out.refpix == "irs2":
            # the exposure's RAWREF 2 N_R, the raw resultants in float32 4 N_raw, one
            # output's samples in float32 and float64 12 N_raw / n_out (the corrected
            # cube, float64 8 N, is made before the fitter's arrays, which the fit's
            # part counts, and is gone when they are made)
            fit.append(("the IRS2 correction ([output] refpix = 'irs2')",
                        2 * NR + 4 * Nraw + 12 * Nraw / det.n_out_active))
    path = out.path
    prod_outputs, prod_memory = _product_outputs(scene, path, products, P, N, det, ro)
    prods = []
    if products:
        # written after the run, which keeps its engine (maps and noise generator)
        prods = kept + [(f"writing the pipeline products ({', '.join(products)})",
                         prod_memory)]
    sim = sim + kept[1:]
    phases = [sim, fit, prods]
    totals = [math.fsum(b for _, b in ph) for ph in phases]
    memory = max(totals)
    peak = totals.index(memory)
    parts = phases[peak]
    peak = ("simulating", f"fitting ({out.fit})",
            f"writing the pipeline products ({', '.join(products)})")[peak]

    outputs = []
    if out.ramp:
        # SCI 2 N; RAWREF 2 N_R and its temporary raw copy beside it, 2 N_R
        outputs.append((f"the exposure {path!r}", 2 * N + 4 * NR + _HEADERS))
    if out.truth:
        saved = out.save_charge + out.save_noise
        outputs.append((f"the truth file {derived_path(path, '_truth')!r}",
                        8 * P + 2 * _index_bytes(ro.nreads) * nints * P
                        + _CRS_ROW * _CR_DEPOSITS * events
                        + 8 * N * saved + _HEADERS))
    if out.fit:
        outputs.append((f"the fit file {derived_path(path, '_' + out.fit)!r}",
                        32 * P + 8 * nints * P + _HEADERS))
    outputs += prod_outputs
    output = math.fsum(b for _, b in outputs)
    return Budget(memory=memory, output=output,
                  memory_parts=tuple((k, float(v)) for k, v in parts if v),
                  output_parts=tuple(outputs), cosmic_ray_events=events,
                  available_memory=available_memory(), free_disk=free_disk(path),
                  output_dir=os.path.dirname(os.path.abspath(path)), peak=peak)


def check_budget(scene, *, force=False, options=None, products=()):
    """Estimate what running ``scene`` needs and refuse it if the machine cannot.

    Parameters
    ----------
    scene : scenesim.scene.Scene
        Validated, with its ``[output]`` as the run will use it.
    force : bool, keyword-only
        Do not refuse (the command's ``--force``); the returned budget's
        :meth:`~Budget.warning` then says which limit is exceeded.
    options : scenesim.engine.EngineOptions, optional
    products : sequence of {'uncal', 'l1', 'reffiles'}
        As in :func:`estimate_budget`.

    Returns
    -------
    Budget
        Its :meth:`~Budget.warning` is a one-line warning to print (or None).

    Raises
    ------
    noise.errors.ParameterError
        Without ``force``, when the memory exceeds :data:`MEMORY_FRACTION` of the
        available memory or the output exceeds the free disk space: one line with
        the estimate, the largest part and the scene keys that drive it, the limit,
        and ``--force``.
    """
    force = check_bool("force", force)
    budget = estimate_budget(scene, options=options, products=products)
    if not force:
        budget.check()
    return budget


def check_noise_budget(detector, params, nframes, *, nints=1, unit="e", path,
                       force=False):
    """:func:`check_budget` for a noise-only ramp (``scenesim noise``,
    :func:`noise.write_noise_fits`).

    Memory: the noise generator (module notes) and the writer's two frames in
    flight plus a float64 scratch (``16 P``); output: ``nints * nframes * P`` values of
    4 bytes (``unit='e'``, float32) or 2 (``'DN'``, uint16), plus 64 kB.

    Parameters
    ----------
    detector : noise.Detector
    params : noise.NoiseParams
    nframes : int
        Read frames per integration (>= 1).
    nints : int, keyword-only
    unit : {'e', 'DN'}, keyword-only
    path : str or os.PathLike, keyword-only
        The output file (its directory's free space is checked).
    force : bool, keyword-only

    Returns
    -------
    Budget

    Raises
    ------
    noise.errors.ParameterError
        As :func:`check_budget`.
    """
    check_instance("detector", detector, Detector, "a noise.Detector")
    check_instance("params", params, NoiseParams, "a noise.NoiseParams")
    nframes = check_int("nframes", nframes, minimum=1)
    nints = check_int("nints", nints, minimum=1)
    unit = check_choice("unit", unit, ("e", "DN"))
    path = check_path("path", path)
    force = check_bool("force", force)
    P = float(detector.ny) * detector.nx
    size = f"{detector.ny} x {detector.nx} pixels"
    parts = [(f"the frames being written ({size}, --naxis)", 16 * P)]
    parts += [(k, v) for k, v in _noise_parts(detector, params) if v]
    values = nints * nframes * P
    outputs = [(f"the ramp {path!r} ({values:.3g} values, --frames x --nints x the "
                f"array)", values * (4 if unit == "e" else 2) + _HEADERS)]
    budget = Budget(memory=math.fsum(v for _, v in parts),
                    output=math.fsum(v for _, v in outputs),
                    memory_parts=tuple((k, float(v)) for k, v in parts),
                    output_parts=tuple(outputs), cosmic_ray_events=0.0,
                    available_memory=available_memory(), free_disk=free_disk(path),
                    output_dir=os.path.dirname(os.path.abspath(path)))
    if not force:
        budget.check()
    return budget


def check_batch_budget(scenes, *, workers=None, fitters=(), force=False):
    """Estimate what a batch's remaining tasks need and refuse it if the machine
    cannot (``scenesim batch``; :func:`check_budget` for one run).

    Parameters
    ----------
    scenes : sequence of (Scene, int)
        Each grid point's validated scene, with the ``[output]`` of its tasks (the
        output directory), and the number of its tasks left to run.
    workers : int or None
        Worker processes of the local cluster, which share this machine's memory:
        each may run the largest task at once.  None (an existing dask cluster, whose
        machines are not known here): the memory is not checked.
    fitters : sequence of str
        The batch's fitters: each task writes one slope file per fitter (the memory
        of one fit, as they run one after the other).
    force : bool
        Do not refuse; the returned budget's :meth:`~Budget.warning` says which limit
        is exceeded.

    Returns
    -------
    Budget
        Memory: ``workers`` times the largest task's; output: the sum over the tasks
        left (their exposures, truth files and slope files, uncompressed).
    """
    fitters = tuple(fitters)
    memory, output, largest, parts, out_dir = 0.0, 0.0, None, [], None
    for scene, count in scenes:
        cfg = scene.output
        one = estimate_budget(scene.replace(output=dataclasses.replace(
            cfg, fit=fitters[0] if fitters else "")))
        fit_file = sum(b for label, b in one.output_parts if label.startswith(
            "the fit file"))
        per_task = one.output + max(len(fitters) - 1, 0) * fit_file
        output += count * per_task
        parts.append((f"{count} tasks of {_size(per_task)} each", count * per_task))
        if largest is None or one.memory > largest.memory:
            largest = one
        out_dir = one.output_dir
    if largest is None:
        return None
    if workers is not None:
        memory = workers * largest.memory
        mem_parts = tuple((f"{workers} local workers x {label}", workers * b)
                          for label, b in largest.memory_parts)
        avail = available_memory()
    else:
        mem_parts, avail = (), None
    budget = Budget(memory=memory, output=output, memory_parts=mem_parts,
                    output_parts=tuple(parts),
                    cosmic_ray_events=largest.cosmic_ray_events,
                    available_memory=avail, free_disk=free_disk(os.path.join(
                        out_dir, "x")), output_dir=out_dir)
    if not check_bool("force", force):
        budget.check()
    return budget
