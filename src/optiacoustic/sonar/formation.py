"""Image formation of a forward-looking imaging sonar (thesis sec. 2.6).

The echo of beam ``j`` in range bin ``b`` is the integral over the beam's elevation
aperture of the returns whose range falls in the bin:

    E_j(b) = integral w(phi) G(r(phi)) rho(phi) cos(alpha(phi)) 1[r(phi) in bin b] dphi

(eq. 2.10 for the Lambert term). It is computed by *tangent-plane footprint
integration* (docs/physics.md): each ray stands for an elevation cell of width
``dphi``; on the tangent plane at its hit the cell covers the range interval
``r +- (dphi / 2) |dr/dphi|`` with ``dr/dphi = -r (n . d') / (n . d)``, and the cell's
energy is spread uniformly over that interval and integrated exactly into range bins.
So returns at equal range add up, shadows receive nothing, a steep surface leaves no
empty bins between lit ones, and the image converges as ``elevation_samples`` grows.
The fine range profile is then low-pass filtered and decimated to ``n_bins``.

The inner loops run as compiled kernels (``_numba_kernels``: the scan's per-ray work, the
echo with the seabed/target split and the decimation in one pass, the shadow; ``_truth_kernels``:
the truth maps); with
``OAS_KERNELS=numpy`` the numpy reference implementation in this module runs
instead, and the tests compare the two (``_kernels``).
"""

from __future__ import annotations

import dataclasses
import functools
import itertools
import weakref
from dataclasses import dataclass
from typing import Literal

import numpy as np

from .._embree_upload import SELF_GAP
from .._validate import as_rng, check_memory, is_integer
from ..frames import Pose
from ..raycast import RayCaster, caster_for, widen_hits
from ..scene import Scene
from ._kernels import chunked_run, kernels, split_run, truth_kernels, use_numba
from ._kernels import workspace as _workspace
from .frame import SonarFrame, SonarGroundTruth, SonarRays
from .propagation import Seawater, two_way_gain
from .spec import SonarSpec

__all__ = ["SonarOptions", "simulate_sonar", "caster_for", "echo_profile"]

#: Incidence cosines below this are clamped when sizing a ray's range footprint (about
#: 88.9 deg): a grazing ray's tangent plane would otherwise stretch to infinity.
_MIN_COS_FOOTPRINT = 0.02


@dataclass(frozen=True)
class SonarOptions:
    """How the echo is formed. The defaults are the thesis's model.

    Attributes
    ----------
    propagation : {"tvg", "spreading"}
        ``"tvg"``: ideal time-varying gain, no range dependence (thesis). ``"spreading"``:
        two-way spreading and absorption of the raw echo (``two_way_gain``).
    water : Seawater
        For the absorption when ``propagation="spreading"``.
    elevation_pattern : {"uniform", "gaussian"}
        Two-way elevation beam pattern inside the aperture: flat (thesis) or a Gaussian
        taper that is -3 dB at the aperture's edges.
    azimuth_pattern : bool
        Spread each beam's echo over its neighbours with a Gaussian azimuth beam pattern
        of one-way -3 dB width ``spec.beamwidth_azimuth`` (cross-beam leakage). Off in
        the thesis's model.
    range_oversample : int
        Fine range samples per output bin before the anti-aliasing filter.
    beam_model : {"thesis", "aperture"}
        ``"thesis"``: the beam is a hard cut at ``fov_elevation`` in elevation and one
        beam cell in azimuth (with the two options above). ``"aperture"``: the spec's
        two-way beam patterns (``spec.elevation_pattern()``, ``spec.azimuth_pattern()``,
        sidelobes included): rays span the elevation pattern to its second null and are
        weighted by ``F^4``; each beam sums its neighbours' cells weighted by ``F^4``
        (docs/physics.md, "Beam patterns from the aperture").
    """

    propagation: Literal["tvg", "spreading"] = "tvg"
    water: Seawater = Seawater()
    elevation_pattern: Literal["uniform", "gaussian"] = "uniform"
    azimuth_pattern: bool = False
    range_oversample: int = 2
    beam_model: Literal["thesis", "aperture"] = "thesis"

    def __post_init__(self):
        if not isinstance(self.propagation, str) or self.propagation not in ("tvg", "spreading"):
            raise ValueError(f"SonarOptions.propagation: expected 'tvg' or 'spreading', got {self.propagation!r}")
        if not isinstance(self.elevation_pattern, str) or self.elevation_pattern not in ("uniform", "gaussian"):
            raise ValueError(
                f"SonarOptions.elevation_pattern: expected 'uniform' or 'gaussian', got {self.elevation_pattern!r}"
            )
        if not isinstance(self.azimuth_pattern, (bool, np.bool_)):  # "no" is truthy: a switch must be a bool
            raise ValueError(f"SonarOptions.azimuth_pattern: expected True or False, got {self.azimuth_pattern!r} "
                             f"({type(self.azimuth_pattern).__name__})")
        if not is_integer(self.range_oversample) or not 1 <= self.range_oversample <= 16:
            raise ValueError(f"SonarOptions.range_oversample: expected an integer in [1, 16], got {self.range_oversample!r}")
        if not isinstance(self.water, Seawater):
            raise ValueError("SonarOptions.water: expected a Seawater")
        if not isinstance(self.beam_model, str) or self.beam_model not in ("thesis", "aperture"):
            raise ValueError(f"SonarOptions.beam_model: expected 'thesis' or 'aperture', got {self.beam_model!r}")


#: The aperture model's rays reach at most this elevation (rad) off the boresight.
_MAX_SCAN_ELEVATION = float(np.deg2rad(75.0))


@functools.lru_cache(maxsize=16)
def scan_spec(spec: SonarSpec, beam_model: str) -> SonarSpec:
    """The spec the rays are cast with: ``spec`` itself for the thesis model; for the
    aperture model the elevation span widened to the pattern's second null."""
    if beam_model == "thesis":
        return spec
    half = min(spec.elevation_pattern().null_angle(2), _MAX_SCAN_ELEVATION)
    return dataclasses.replace(spec, fov_elevation=2.0 * half)


#: The fewest elevation samples (rays) per main lobe the image model takes: one ray stands for an
#: elevation cell, so coarser cells misplace the echo in range and weight it wrongly (a wall in the
#: aperture model: +45 % energy at about 1 sample per -3 dB width, +19 % at 1.4, +1 % at 4; a seabed
#: in the thesis model at 1-3 samples over its aperture: the onset 1-4 m short).
MIN_SAMPLES_PER_LOBE = 4


def elevation_samples_for(spec: SonarSpec, beam_model: str, per_lobe: float) -> int:
    """Elevation samples that put ``per_lobe`` rays in the elevation main lobe of ``spec``: for the
    thesis model the lobe is the hard-cut aperture ``fov_elevation`` that the rays span; for the
    aperture model its -3 dB width ``elevation_pattern().beamwidth()`` within the scan's span (to the
    pattern's second null, :func:`scan_spec`). ``SensorProfile.simulation_spec`` asks 24."""
    if beam_model == "thesis":
        return int(np.ceil(per_lobe))
    el = spec.elevation_pattern()
    span = 2.0 * min(el.null_angle(2), _MAX_SCAN_ELEVATION)
    return int(np.ceil(per_lobe * span / el.beamwidth() - 1e-9))


@functools.lru_cache(maxsize=16)
def check_elevation_samples(spec: SonarSpec, beam_model: str) -> None:
    """Refuse a spec whose elevation sampling is too coarse for the image model (fewer than
    :data:`MIN_SAMPLES_PER_LOBE` rays in the elevation main lobe), naming the field and the least
    count (cached per spec and model: once, not per frame)."""
    need = elevation_samples_for(spec, beam_model, MIN_SAMPLES_PER_LOBE)
    if spec.elevation_samples < need:
        lobe = ("over the aperture fov_elevation" if beam_model == "thesis" else
                f"per -3 dB elevation width ({np.rad2deg(spec.elevation_pattern().beamwidth()):.3g} deg; the scan spans "
                f"{np.rad2deg(scan_spec(spec, beam_model).fov_elevation):.3g} deg)")
        raise ValueError(f"SonarSpec.elevation_samples: {spec.elevation_samples} is too coarse for beam_model="
                         f"{beam_model!r}: it needs at least {need} ({MIN_SAMPLES_PER_LOBE} rays {lobe}); "
                         f"each ray stands for an elevation cell, and coarser cells misplace and misweight the echo")


@functools.lru_cache(maxsize=16)
def _aperture_elevation_weights(spec: SonarSpec) -> np.ndarray:
    """Two-way elevation power ``F^4`` at the scan's elevation samples (cell averages)."""
    sc = scan_spec(spec, "aperture")
    w = spec.elevation_pattern().cell_average_two_way(sc.elevations, sc.elevation_step)
    w.setflags(write=False)
    return w


@functools.lru_cache(maxsize=16)
def azimuth_mixing(spec: SonarSpec) -> np.ndarray:
    """Beam-mixing matrix ``M[j, i]``: two-way azimuth power ``F^4`` of beam ``j`` averaged over
    beam ``i``'s cell (for a beam table, where beams are unevenly spaced). ``(n_beams, n_beams)``."""
    pat = spec.azimuth_pattern()
    th = spec.azimuths
    e = spec.beam_edges
    n_sub = 8
    frac = (np.arange(n_sub) + 0.5) / n_sub
    sub = e[:-1, None] + (e[1:] - e[:-1])[:, None] * frac  # (i, n_sub)
    M = pat.two_way(sub[None, :, :] - th[:, None, None]).mean(-1) * ((e[1:] - e[:-1]) / spec.beam_spacing)[None, :]
    M = M.astype(np.float32)
    M.setflags(write=False)
    return M


def _mix_beams(spec: SonarSpec, echo: np.ndarray, out=None) -> np.ndarray:
    """Apply the two-way azimuth pattern across beams to ``echo`` ``(n_beams, n_bins)`` (into ``out``,
    a C-contiguous float32 array of that shape, when given)."""
    if spec.beam_azimuths is not None:
        return np.matmul(azimuth_mixing(spec), echo, out=out)
    import cv2

    k = np.ascontiguousarray(azimuth_kernel(spec)[::-1], np.float32).reshape(-1, 1)  # correlation kernel
    # (rows of contiguous float32, a piece of an image's columns included, go to cv2 as they are)
    src = echo if echo.dtype == np.float32 and echo.strides[-1] == 4 else np.ascontiguousarray(echo, np.float32)
    if out is None:
        return cv2.filter2D(src, cv2.CV_32F, k, borderType=cv2.BORDER_CONSTANT)
    got = cv2.filter2D(src, cv2.CV_32F, k, dst=out, borderType=cv2.BORDER_CONSTANT)
    if not np.shares_memory(got, out):  # cv2 allocated anew (it should not for a matching buffer)
        out[...] = got
    return out


def _live_span(live: np.ndarray, spec: SonarSpec):
    """The beams ``(j0, j1)`` whose mixed rows can be nonzero: the rows with echo (``live``, bool
    ``(n_beams,)``) widened by the azimuth kernel's half-length; ``None`` for all beams (a beam
    table mixes every beam with every other); ``(0, 0)`` when no row has echo."""
    if spec.beam_azimuths is not None:
        return None
    idx = np.flatnonzero(live)
    if idx.size == 0:
        return (0, 0)
    m = (azimuth_kernel(spec).size - 1) // 2
    return (max(int(idx[0]) - m, 0), min(int(idx[-1]) + m + 1, spec.n_beams))


#: Bins (columns) of one piece of the beam mixing on several threads (:func:`_form_aperture_numba`): a
#: multiple of 128, so that every piece starts where cv2's vector loop over a row starts a block.
_MIX_COLUMNS = 256


def _mix_rows(spec: SonarSpec, rows: np.ndarray, out: np.ndarray, span, zero_outside: bool = True) -> None:
    """:func:`_mix_beams` of ``rows`` ``(n_beams, n_bins)`` into ``out``, computed over the beams of
    ``span`` only (:func:`_live_span`; ``None``: all): the rows outside it are zero and take none
    from the rows with echo. The same numbers as the whole array (the rows left out are zeros,
    which add nothing, with the same zero border). ``zero_outside=False`` leaves ``out``'s rows
    outside the span unwritten (for a reader that reads the span only)."""
    if span is None:
        _mix_beams(spec, rows, out=out)
        return
    j0, j1 = span
    if zero_outside:
        out[:j0] = 0.0
        out[j1:] = 0.0
    if j1 > j0:
        _mix_beams(spec, rows[j0:j1], out=out[j0:j1])


@functools.lru_cache(maxsize=16)
def azimuth_kernel(spec: SonarSpec) -> np.ndarray:
    """Two-way azimuth power ``F^4`` averaged over beam cells at offsets ``-m..m`` beams.

    A beam's echo is ``sum_m kernel[m] cell[j + m]`` where ``cell`` is the echo of the
    azimuth cell of one beam spacing (what the thesis model gives).
    """
    pat = spec.azimuth_pattern()
    m = int(min(spec.n_beams, max(1, np.ceil(pat.null_angle(2) / spec.beam_spacing))))
    k = pat.cell_average_two_way(np.arange(-m, m + 1) * spec.beam_spacing, spec.beam_spacing)
    k.setflags(write=False)
    return k


@functools.lru_cache(maxsize=16)
def _ray_grid(spec: SonarSpec):
    """Sonar-frame unit directions d and their elevation derivatives d' (K, J, 3), float32."""
    th = spec.azimuths[None, :]
    ph = spec.elevations[:, None]
    st, ct, sp, cp = np.sin(th), np.cos(th), np.sin(ph), np.cos(ph)
    d = np.stack(np.broadcast_arrays(cp * st, cp * ct, sp), -1)
    dd = np.stack(np.broadcast_arrays(-sp * st, -sp * ct, cp), -1)
    return d.reshape(-1, 3), dd.reshape(-1, 3)


@functools.lru_cache(maxsize=16)
def _index_grids(spec: SonarSpec):
    """Beam index and elevation-sample index of every ray, flattened (read-only, cached)."""
    K, J = spec.elevation_samples, spec.n_beams
    beam = np.tile(np.arange(J), K)
    elev = np.repeat(np.arange(K), J)
    beam.setflags(write=False)
    elev.setflags(write=False)
    return beam, elev


@functools.lru_cache(maxsize=16)
def _elevation_grid(spec: SonarSpec) -> np.ndarray:
    """Elevation (rad) of every ray, flattened ``(K * J,)`` like :func:`_index_grids` (read-only, cached)."""
    elev = spec.elevations[_index_grids(spec)[1]]
    elev.setflags(write=False)
    return elev


def _world_ray_grid(spec: SonarSpec, R: np.ndarray):
    """World-frame ray directions ``d`` and their elevation derivatives ``d'``, ``(K * J, 3)``.

    The grid is separable: ``R d(theta, phi) = cos(phi) a(theta) + sin(phi) R_z`` with
    ``a(theta) = sin(theta) R_x + cos(theta) R_y`` (``R_x, R_y, R_z`` the columns of ``R``),
    so one broadcast does what a per-ray rotation would (and no BLAS call is involved).
    """
    th, ph = spec.azimuths, spec.elevations
    a = np.sin(th)[:, None] * R[:, 0] + np.cos(th)[:, None] * R[:, 1]  # (J, 3)
    cp, sp = np.cos(ph)[:, None, None], np.sin(ph)[:, None, None]
    d = cp * a[None] + sp * R[:, 2]
    dd = -sp * a[None] + cp * R[:, 2]
    return d.reshape(-1, 3), dd.reshape(-1, 3)


def _elevation_weights(spec: SonarSpec, pattern: str) -> np.ndarray:
    ph = spec.elevations
    if pattern == "uniform":
        return np.ones_like(ph)
    # Gaussian two-way power pattern, -3 dB (one half) at the aperture edges
    return np.exp(-np.log(2.0) * (2.0 * ph / spec.fov_elevation) ** 2)


@functools.lru_cache(maxsize=16)
def _decimation_weights(n_bins: int, q: int, sigma_bins: float) -> np.ndarray:
    """Anti-aliasing weights ``W[phase, delta]`` from fine sample ``q b' + phase`` to bin ``b' + delta``.

    A Gaussian of ``sigma_bins`` (in output bins) evaluated between the fine sample's
    centre and the output bin centres, normalised per fine sample so that energy is
    conserved exactly.
    """
    D = int(np.ceil(3.5 * sigma_bins)) + 1
    deltas = np.arange(-D, D + 1)
    phase_pos = (np.arange(q) + 0.5) / q  # fine-sample centre within its bin, in bins
    x = deltas[None, :] + 0.5 - phase_pos[:, None]
    w = np.exp(-0.5 * (x / sigma_bins) ** 2)
    return (w / w.sum(1, keepdims=True)).astype(np.float32), D


def _decimate(fine: np.ndarray, n_bins: int, q: int, sigma_bins: float) -> np.ndarray:
    """Low-pass filter then downsample ``fine`` (J, n_bins * q) to a new (J, n_bins) float32.

    The energy of fine sample ``q b' + p`` goes to bin ``b' + delta`` with weight
    ``W[p, delta]``: for each phase ``p`` a 1D convolution along range of the phase's
    samples, done by ``cv2.filter2D`` (correlation with the reversed kernel, zero borders).
    """
    import cv2

    W, D = _decimation_weights(n_bins, q, sigma_bins)
    J = fine.shape[0]
    blocks = fine.reshape(J, n_bins, q)
    out = np.zeros((J, n_bins), np.float32)
    for phase in range(q):
        src = np.ascontiguousarray(blocks[:, :, phase], dtype=np.float32)
        kernel = np.ascontiguousarray(W[phase, ::-1][None, :])
        out += cv2.filter2D(src, cv2.CV_32F, kernel, anchor=(D, 0), borderType=cv2.BORDER_CONSTANT)
    return out


def _box_integrate(beam, lo, hi, energy, n_beams: int, n_cells: int, out=None) -> np.ndarray:
    """Integrate boxes of ``energy`` spread uniformly over ``[lo, hi]`` (cell units) into cells.

    Exact: a box is a step up at ``lo`` and a step down at ``hi``; the integral of a step
    over cells is a linear two-cell deposit followed by a cumulative sum. Returns
    ``(n_beams, n_cells)`` float64 (a view into ``out``, shape ``(n_beams, n_cells + 2)``,
    when given).
    """
    n = len(lo)
    stride = n_cells + 2
    xs = np.empty(2 * n)
    np.clip(lo, 0, n_cells, out=xs[:n])
    np.clip(hi, 0, n_cells, out=xs[n:])
    p = xs.astype(np.int64)  # floor: xs >= 0
    f = xs - p
    dens = np.empty(2 * n)
    np.divide(energy, hi - lo, out=dens[:n])
    np.negative(dens[:n], out=dens[n:])
    base = np.empty(2 * n, np.int64)
    base[:n] = beam
    base[n:] = beam
    base *= stride
    base += p
    if out is None:
        out = np.zeros((n_beams, stride))
    else:
        out.fill(0.0)
    flat = out.reshape(-1)
    # np.add.at into the reused workspace: np.bincount would allocate and zero a fresh
    # array of every fine cell (measured slower: ~130 k deposits into ~1.5 M cells)
    np.add.at(flat, base, dens - dens * f)
    base += 1
    np.add.at(flat, base, dens * f)
    np.cumsum(out, axis=1, out=out)
    res = out[:, :n_cells]
    np.maximum(res, 0.0, out=res)  # rounding residue of exact cancellations
    return res


def echo_profile(spec: SonarSpec, rays: SonarRays, *, cells_per_bin: int = 1, select=None, out=None,
                 beams=None) -> np.ndarray:
    """Box-integrate the rays' energy footprints into ``(n_beams, n_bins * cells_per_bin)``.

    ``select`` (bool, rays' shape) restricts the sum to some rays; ``beams`` (sorted
    indices) to some beams, giving ``(len(beams), ...)``.
    """
    hit = rays.energy > 0
    if select is not None:
        hit = hit & select
    n = spec.n_bins * cells_per_bin
    scale = cells_per_bin / spec.bin_width
    lo = (rays.footprint_lo[hit] - spec.range_min) * scale
    hi = (rays.footprint_hi[hit] - spec.range_min) * scale
    beam = rays.beam_index[hit]
    n_cols = spec.n_beams
    if beams is not None:
        col = np.full(spec.n_beams, -1, np.int64)
        col[beams] = np.arange(len(beams))
        beam = col[beam]
        keep = beam >= 0
        beam, lo, hi = beam[keep], lo[keep], hi[keep]
        energy = rays.energy[hit][keep]
        n_cols = len(beams)
    else:
        energy = rays.energy[hit]
    return _box_integrate(beam, lo, hi, energy, n_cols, n, out=out)


# --------------------------------------------------------------------------- main entry
def simulate_sonar(
    scene: Scene,
    spec: SonarSpec,
    pose: Pose,
    *,
    noise=None,
    seed=None,
    options: SonarOptions | None = None,
    profile=None,
) -> SonarFrame:
    """Simulate one frame of a forward-looking imaging sonar.

    Parameters
    ----------
    scene : Scene
    spec : SonarSpec
        The sensor (``SonarSpec.preset(...)`` or your own).
    pose : Pose
        The sonar's pose in the world (body axes: X right, Y forward, Z up); build it
        with ``Pose.look_at(eye, target)``.
    noise : NoiseModel, False or None
        Noise and reverberation applied to ``.image``. ``None`` is the default model
        (thesis: Rayleigh-mixture bottom reverberation plus an ambient noise floor);
        ``False`` makes ``.image`` equal ``.intensity``.
    seed : int or numpy.random.Generator, optional
        Seed of the noise.
    options : SonarOptions, optional
        Propagation, beam patterns, decimation.
    profile : SensorProfile, optional
        A device profile (``sonar.fit_profile``, ``SensorProfile.load``): it sets the
        beam patterns, range resolution, gain chain, speckle and noise of a real device
        (``options`` and ``noise`` given here override its choices of those).

    Returns
    -------
    SonarFrame
        ``.intensity`` (noise-free echo) and ``.image`` (with noise), both
        ``(n_bins, n_beams)`` float32 in echo per metre of range; bin centres
        ``.ranges`` (m), beam centres ``.azimuths`` (rad); ``.ground_truth`` (computed
        on first access) and the per-ray data ``.rays``.
    """
    if not isinstance(spec, SonarSpec):
        raise TypeError(f"spec: expected a SonarSpec, got {type(spec).__name__}")
    if spec.bin_ranges is not None:  # beam tables are fine (rays follow spec.azimuths); bins must be equal
        raise ValueError("simulate_sonar: spec has a range table (bin_ranges); the simulator needs equal bins")
    if not isinstance(pose, Pose):
        raise TypeError(f"pose: expected a Pose (e.g. Pose.look_at(eye, target)), got {type(pose).__name__}")
    if profile is not None:
        if not callable(getattr(profile, "apply_to", None)):  # a SensorProfile (sonar.profile imports us)
            raise TypeError(f"profile: expected a SensorProfile, got {type(profile).__name__}")
        spec, options, noise = profile.apply_to(spec, options, noise)
    options = options or SonarOptions()
    if not isinstance(options, SonarOptions):
        raise TypeError(f"options: expected SonarOptions, got {type(options).__name__}")
    from .noise import NoiseModel, ScattererNoise, release_draws, release_noise_draws

    if noise is not False:
        if noise is None:
            noise = NoiseModel()
        elif not isinstance(noise, (NoiseModel, ScattererNoise)):
            raise TypeError(f"noise: expected a NoiseModel, ScattererNoise, False or None, got {type(noise).__name__}")

    # a lower estimate of the bytes a frame takes (rays, bins x beams images): refuse before allocating
    check_memory(96.0 * spec.n_beams * spec.elevation_samples + 64.0 * spec.n_bins * spec.n_beams,
                 f"a {spec.n_bins} x {spec.n_beams} sonar frame with {spec.elevation_samples} elevation samples "
                 "(SonarSpec.n_bins x n_beams x elevation_samples)")
    check_elevation_samples(spec, options.beam_model)
    caster = caster_for(scene)
    inside = caster.enclosing_body(pose.t)
    if inside >= 0:  # it would image the body's inner walls, or nothing (as the camera, refused)
        raise ValueError(f"pose: the sonar at {np.round(pose.t, 3).tolist()} is inside body "
                         f"'{scene.body_names()[inside]}'")
    for i, z0, up in _floor_sides(scene):
        # the back of a floor plane would image like its front, while the shadow passes back faces
        # (docs/physics.md 1.6.1): the image and the shadow truth would disagree; refused
        if (float(pose.t[2]) - z0) * up < -1e-9 * max(1.0, abs(z0)):
            side = "below" if up > 0 else "above"
            raise ValueError(f"pose: the sonar at {np.round(pose.t, 3).tolist()} is {side} floor plane body "
                             f"'{scene.body_names()[i]}' (z = {z0:.6g} m), on its back side; a floor is seen from its "
                             f"front ({'above' if up > 0 else 'below'} it: its normal points {'up' if up > 0 else 'down'})")
    bottom_types = _bottom_types(scene)
    draws = None
    draw_args = (noise.draw, (spec.n_bins, spec.n_beams), list(bottom_types), as_rng(seed)) if noise is not False else None
    # (not for a subclass with its own draw, which may not take ``_reuse``, or its own apply, which might
    # return a draw: the buffers go back to the pool after it)
    pooled = noise is not False and any(type(noise).draw is m.draw and type(noise).apply is m.apply
                                        for m in (ScattererNoise, NoiseModel))
    if pooled:  # its variates in pooled buffers, handed back once the noise has read them (fresh ones fault)
        draw_args = (functools.partial(noise.draw, _reuse=True),) + draw_args[1:]

    def start_draws():
        # the noise variates do not depend on the echo: with a second thread, draw them on the other
        # core once the primary cast (which takes every thread) is done, beside the one-thread stages
        # (the scatterer noise: the echo-free part of its field too; the thesis model: its variates from
        # the counter stream, which apply would otherwise form in its own pass)
        nonlocal draws
        if draw_args is not None and caster.threads > 1:
            beside = {"_field": True} if pooled else {}
            draws = _background().submit(*draw_args, **beside)
            return True  # a thread of the caller's is taken meanwhile
        return False

    sspec = scan_spec(spec, options.beam_model)
    if options.beam_model == "aperture":
        rays, img_rays = _scan(scene, caster, sspec, pose, options, _aperture_elevation_weights(spec),
                               spec.elevation_pattern(), after_cast=start_draws, materialise=False)
    else:
        # the footprints (0.3 ms) on this thread alone while the draws take the other core: split, the
        # part handed to the pool waited for a core the draws hold (1-1.5 ms at two threads)
        rays = img_rays = _scan(scene, caster, sspec, pose, options, after_cast=start_draws,
                                footprint_threads=1 if draw_args is not None else None)
    if draws is None and draw_args is not None:  # one thread: drawn here, in line
        draws = _done(draw_args[0](*draw_args[1:]))
    area = None
    if isinstance(img_rays, _ApertureCells):
        # the aperture model: one pass forms the sub-cells, their echo, the split and the cell areas
        intensity, shares, cell_areas = _form_aperture_numba(spec, img_rays, options, bottom_types, caster.threads,
                                                             getattr(noise, "needs_cell_area", False))
        area = None if cell_areas is None else _done(cell_areas)
    elif use_numba():
        # one pass forms the echo and the seabed/target split together
        if getattr(noise, "needs_cell_area", False):
            area = (_background().submit(cell_area, spec, img_rays, bottom_types) if caster.threads > 1
                    else _done(cell_area(spec, img_rays, bottom_types)))
        intensity, shares = _form_with_shares_numba(spec, img_rays, options, bottom_types, caster.threads)
    else:
        # the seabed/target split needs only the rays: integrate it on the other core meanwhile
        parts = _background().submit(_class_parts, bottom_types, spec, img_rays, options)
        if getattr(noise, "needs_cell_area", False):
            area = _background().submit(cell_area, spec, img_rays, bottom_types)
        intensity = _form_image(spec, img_rays, options)
        shares = _seabed_shares(bottom_types, *parts.result(), intensity)
    if noise is False:
        image = intensity.copy()
    elif area is not None:
        image = noise.apply(intensity, spec=spec, seabed_share=shares, options=options, draws=draws.result(),
                            cell_area=area.result(), threads=caster.threads)
    else:
        image = noise.apply(intensity, spec=spec, seabed_share=shares, options=options, draws=draws.result(),
                            threads=caster.threads)
    if pooled:  # the image is a fresh array: nothing the frame keeps refers to the draws
        (release_noise_draws if isinstance(noise, NoiseModel) else release_draws)(draws.result())
    intensity.setflags(write=False)
    image.setflags(write=False)
    gt = SonarGroundTruth(
        rays.range.astype(np.float32),
        functools.partial(_truth_maps, spec, rays, caster.threads),
        functools.partial(_shadow_mask, scene, caster, sspec, pose, rays),
    )
    return SonarFrame(spec=spec, pose=pose, intensity=intensity, image=image, ground_truth=gt, rays=rays,
                      body_names=tuple(scene.body_names()), seabed_share=shares, beam_model=options.beam_model)


def _form_image(spec: SonarSpec, rays: SonarRays, options: SonarOptions, select=None, beams=None) -> np.ndarray:
    """Rays -> (n_bins, n_beams) echo per metre: exact box integration, anti-aliasing, decimation.

    ``select`` (bool, rays' shape) keeps some rays; ``beams`` (sorted beam indices)
    computes only those columns, ``(n_bins, len(beams))``.
    """
    q = options.range_oversample
    n_cols = spec.n_beams if beams is None else len(beams)
    ws = _workspace("fine" if beams is None else "fine_part", (n_cols, spec.n_bins * q + 2), np.float64)
    fine = echo_profile(spec, rays, cells_per_bin=q, select=select, out=ws, beams=beams)
    sigma_bins = max(spec.pulse_width / spec.bin_width / 2.3548, 0.5)
    echo = _decimate(fine, spec.n_bins, q, sigma_bins)
    if options.beam_model == "aperture":
        if beams is not None:  # the pattern mixes neighbouring beams: work on all columns
            full = np.zeros((spec.n_beams, spec.n_bins), np.float32)
            full[beams] = echo
            echo = full
        echo = _mix_beams(spec, echo)
        if beams is not None:
            echo = echo[beams]
    elif options.azimuth_pattern and spec.beamwidth_azimuth > 0:
        from scipy.ndimage import gaussian_filter1d

        if beams is not None:  # the pattern mixes neighbouring beams: work on all columns
            full = np.zeros((spec.n_beams, spec.n_bins), np.float32)
            full[beams] = echo
            echo = full
        sigma_beams = spec.beamwidth_azimuth / spec.beam_spacing / 2.3548
        echo = gaussian_filter1d(echo, sigma_beams, axis=0, mode="constant", truncate=3.5)
        if beams is not None:
            echo = echo[beams]
    # energy per bin -> density per metre of range: independent of the bin width
    echo *= np.float32(1.0 / spec.bin_width)
    # flush the cumulative sums' rounding residue (~1e-16) so that shadows are exactly dark
    peak = float(echo.max()) if echo.size else 0.0
    echo[echo < np.float32(1e-9 * peak)] = 0.0
    return np.ascontiguousarray(echo.T)


def _mix_and_scale(spec: SonarSpec, echo: np.ndarray, options: SonarOptions) -> np.ndarray:
    """Beam patterns across beams (aperture model or the azimuth option), then echo per metre.

    ``echo`` ``(n_bins, n_beams)`` float32 (the image layout; ``_form_image`` works on its
    transpose) -> the same, scaled by ``1 / bin_width``."""
    if options.beam_model == "aperture":
        if spec.beam_azimuths is not None:
            echo = echo @ azimuth_mixing(spec).T
        else:
            import cv2

            k = np.ascontiguousarray(azimuth_kernel(spec)[::-1], np.float32).reshape(1, -1)
            echo = cv2.filter2D(echo, cv2.CV_32F, k, borderType=cv2.BORDER_CONSTANT)
    elif options.azimuth_pattern and spec.beamwidth_azimuth > 0:
        from scipy.ndimage import gaussian_filter1d

        sigma_beams = spec.beamwidth_azimuth / spec.beam_spacing / 2.3548
        echo = gaussian_filter1d(echo, sigma_beams, axis=1, mode="constant", truncate=3.5)
    echo *= np.float32(1.0 / spec.bin_width)
    return echo


def _finish_numba(spec: SonarSpec, rows: np.ndarray, bottom_types: dict, slot_of: dict, threads: int,
                  targets_span=None):
    """Intensity and seabed shares from :func:`_echo_rows_numba`'s ``(n_slots, n_beams, n_bins)`` rows in
    one pass (``_numba_kernels.finish_echo``): the thesis model's ``_mix_and_scale`` (a scale),
    threshold and ``shares`` together, with no transposed copy of the class images.
    ``targets_span``: ``(j0, j1)``, the only beams whose rows of slot 1 are read (zeros elsewhere, left
    unwritten by the caller); ``None``: all."""
    scale = np.float32(1.0 / spec.bin_width)
    peak = float(rows[0].max() * scale) if rows.size else 0.0  # rounding is monotonic: max of the scaled
    thr = np.float32(1e-9 * peak)
    names = list(slot_of) if bottom_types else []
    table = np.array([slot_of[n] for n in names], np.int64)
    intensity = np.empty((spec.n_bins, spec.n_beams), np.float32)
    kn = kernels()
    if len(names) == 2 and names[1] is None and rows.shape[0] == 2 and list(table) == [0, 1]:
        share = np.empty((spec.n_bins, spec.n_beams), np.float32)  # one bottom type, most rays: its share only
        j0, j1 = targets_span if targets_span is not None else (0, spec.n_beams)
        chunked_run(lambda r0, r1: kn.finish_two(rows, scale, thr, j0, j1, r0, r1, intensity, share), spec.n_bins,
                    threads)
        share.setflags(write=False)
        return intensity, {names[0]: share}
    if targets_span is not None and rows.shape[0] > 1:  # (the general pass reads every slot whole)
        j0, j1 = targets_span
        rows[1, :j0] = 0.0
        rows[1, j1:] = 0.0
    out = np.empty((len(names), spec.n_bins, spec.n_beams), np.float32)
    chunked_run(lambda r0, r1: kn.finish_echo(rows, scale, thr, table, r0, r1, intensity, out), spec.n_bins, threads)
    return intensity, _read_only_shares(out, names)


def _echo_rows_numba(spec: SonarSpec, rays: SonarRays, slot: np.ndarray, n_slots: int, threads: int,
                     cells_per_bin: int, sigma_bins: float | None) -> np.ndarray:
    """:func:`_echo_numba` before its transposition: ``(n_slots, n_beams, n_bins)`` float32, a per-thread
    workspace that the next frame overwrites."""
    kn = kernels()
    q = cells_per_bin
    H, V, full = _deposit_tables(spec.n_bins, q, sigma_bins)
    J, n_cells = spec.n_beams, spec.n_bins * q
    flat = lambda a: np.ascontiguousarray(a).reshape(-1)  # noqa: E731
    rec, starts = _bucket(flat(rays.beam_index), flat(rays.footprint_lo), flat(rays.footprint_hi), flat(rays.energy),
                          slot, float(spec.range_min), q / spec.bin_width, n_cells, J)
    out = _workspace(f"echo{n_slots}", (n_slots, J, spec.n_bins), np.float32)  # fresh pages fault: reuse
    # in chunks the threads take as they finish (fixed halves waited for the second core while the noise
    # draws held it, or the host slowed it); beams are independent: the same numbers
    chunked_run(lambda j0, j1: kn.echo_rows(rec, starts, n_cells, H, V, full, q, spec.n_bins, j0, j1, out), J, threads)
    return out


def _echo_numba(spec: SonarSpec, rays: SonarRays, slot: np.ndarray, n_slots: int, threads: int,
                cells_per_bin: int, sigma_bins: float | None) -> np.ndarray:
    """The numba twin of :func:`echo_profile` + :func:`_decimate`, for ``n_slots`` classes at once.

    Returns ``(n_slots, n_bins, n_beams)`` float32 (energy per bin): slot 0 every ray, slot
    ``s > 0`` the rays with ``slot == s``. ``sigma_bins=None``: no anti-aliasing
    (``cells_per_bin`` must be 1).
    """
    out = _echo_rows_numba(spec, rays, slot, n_slots, threads, cells_per_bin, sigma_bins)
    return np.ascontiguousarray(out.transpose(0, 2, 1))


def _bucket(beam, lo_m, hi_m, energy, slot, range_min, scale, n_cells, n_beams):
    """``_numba_kernels.bucket_by_beam``: ``(records, starts)``, the records a per-thread scratch (2 MB
    a frame: fresh pages fault) that the next call on this thread overwrites."""
    rec = _workspace("bucket_records", (beam.size, 4), np.float64)
    starts = np.empty(n_beams + 1, np.int64)
    kernels().bucket_by_beam(beam, lo_m, hi_m, energy, slot, range_min, scale, n_cells, n_beams, rec, starts)
    return rec, starts


@functools.lru_cache(maxsize=16)
def _deposit_tables(n_bins: int, q: int, sigma_bins: float | None):
    """What a unit deposit at a fine cell adds to the decimated image (``_numba_kernels.echo_rows``).

    ``H[p, m + D]``: to bin ``b + m`` from the cells at and after fine cell ``q b + p`` (the
    cumulative sum carries the deposit to all of them); ``full``: to every bin from
    ``b + D + 1`` on (all weights); ``V[t]``: what cells past the end of the row would give
    bin ``n_bins - D + t``. ``sigma_bins=None``: no anti-aliasing (``q = 1``).
    """
    if sigma_bins is None:
        W, D = np.ones((1, 1), np.float32), 0
    else:
        W, D = _decimation_weights(n_bins, q, sigma_bins)
    W = W.astype(np.float64)
    H = np.zeros((q, 2 * D + 1))
    for p0 in range(q):
        for m in range(-D, D + 1):
            for r in range(max(0, m - D), m + D + 1):  # bins after the deposit's, relative
                k = m - r + D
                H[p0, m + D] += W[(p0 if r == 0 else 0):, k].sum()
    V = np.array([W[:, : t + 1].sum() for t in range(D)])
    for a in (H, V):
        a.setflags(write=False)
    return H, V, float(W.sum())


def _box_image_numba(spec: SonarSpec, beam, lo_m, hi_m, energy) -> np.ndarray:
    """Boxes of ``energy`` over ``[lo_m, hi_m]`` (m) integrated into range bins, ``(n_bins, n_beams)``
    float32, no anti-aliasing (:func:`echo_profile` with one cell per bin, transposed)."""
    kn = kernels()
    H, V, full = _deposit_tables(spec.n_bins, 1, None)
    slot = np.zeros(len(beam), np.int8)
    rec, starts = _bucket(np.ascontiguousarray(beam), np.ascontiguousarray(lo_m, float), np.ascontiguousarray(hi_m, float),
                          np.ascontiguousarray(energy, float), slot, float(spec.range_min), 1.0 / spec.bin_width,
                          spec.n_bins, spec.n_beams)
    out = np.empty((1, spec.n_beams, spec.n_bins), np.float32)
    kn.echo_rows(rec, starts, spec.n_bins, H, V, full, 1, spec.n_bins, 0, spec.n_beams, out)
    return np.ascontiguousarray(out[0].T)


def _class_slots(bottom_types: dict, rays: SonarRays):
    """Output slot of every ray's class for :func:`_echo_numba`: the class with most lit rays
    (a bottom type or ``None``, the targets) has slot 0, the whole echo; the others 1, 2, ...

    Returns ``(slot per ray (N,) int8, n_slots, {class: slot})``.
    """
    if use_numba():
        return _class_slots_numba(bottom_types, rays)
    body = rays.body.reshape(-1)
    names, cls = _class_table(bottom_types, body)
    lit = rays.energy.reshape(-1) > 0
    ray_cls = cls[body]  # body -1 reads the last entry: unlit anyway
    counts = np.bincount(ray_cls[lit], minlength=len(names))
    table, k, slot_of = _slot_table(names, counts)
    return table[ray_cls], k, slot_of


def _class_table(bottom_types: dict, body: np.ndarray):
    """``(names, cls)``: the classes (the bottom types, then ``None`` for the targets) and every
    body id's class index (``cls[-1]``, read by body -1, is the targets')."""
    n_bodies = int(body.max()) + 1 if body.size else 0
    names = list(bottom_types) + [None]
    cls = np.full(max(n_bodies, max((i for v in bottom_types.values() for i in v), default=-1) + 1) + 1,
                  len(names) - 1, np.int64)
    for c, name in enumerate(bottom_types):
        cls[bottom_types[name]] = c
    return names, cls


def _slot_table(names: list, counts: np.ndarray):
    """``(slot per class int8, n_slots, {class: slot})``: the first class with the largest count
    takes slot 0, the others 1, 2, ... in order."""
    largest = int(np.argmax(counts))
    slot_of = {}
    k = 1
    for c, name in enumerate(names):
        if c == largest:
            slot_of[name] = 0
        else:
            slot_of[name] = k
            k += 1
    return np.array([slot_of[n] for n in names], np.int8), k, slot_of


def _class_slots_numba(bottom_types: dict, rays: SonarRays):
    """:func:`_class_slots` by two kernel passes (the same slots: integer counts, the first largest
    class takes slot 0), every ray counted once, into per-thread scratch (the fancy indexing and
    bincount of the numpy path cost 0.5-0.8 ms and three fresh grid-sized temporaries a frame). The
    aperture model counts its classes' sub-cells in its own pass (``_aperture_kernels.aperture_words``)."""
    from . import _aperture_kernels as ak

    body = np.ascontiguousarray(rays.body).reshape(-1)
    names, cls = _class_table(bottom_types, body)
    counts = np.zeros(len(names), np.int64)
    ones = _workspace("class_weight", (body.size,), np.int64)
    ones.fill(1)  # (class_counts takes a weight per ray: one here)
    ray_cls = _workspace("class_of_ray", (body.size,), np.int64)
    ak.class_counts(body, np.ascontiguousarray(rays.energy).reshape(-1), ones, cls, counts, ray_cls)
    table, k, slot_of = _slot_table(names, counts)
    slot = np.empty(body.size, np.int8)
    ak.class_slots(ray_cls, table, slot)
    return slot, k, slot_of


def _form_with_shares_numba(spec: SonarSpec, rays: SonarRays, options: SonarOptions, bottom_types: dict,
                            threads: int):
    """Echo image and seabed shares in one pass of the kernels (``_form_image`` + ``_class_parts``
    + ``_seabed_shares``)."""
    sigma_bins = max(spec.pulse_width / spec.bin_width / 2.3548, 0.5)
    if not bottom_types:
        slot, n_slots, slot_of = np.zeros(rays.body.size, np.int8), 1, {}
    else:
        slot, n_slots, slot_of = _class_slots(bottom_types, rays)
    if not (options.beam_model == "aperture" or options.azimuth_pattern):
        return _finish_numba(spec, _echo_rows_numba(spec, rays, slot, n_slots, threads, options.range_oversample,
                                                    sigma_bins), bottom_types, slot_of, threads)
    # beam patterns across beams: each class image is mixed on its own (in the image layout)
    parts = _echo_numba(spec, rays, slot, n_slots, threads, options.range_oversample, sigma_bins)
    for s in range(n_slots):  # into the fresh array: no second allocation (np.stack)
        parts[s] = _mix_and_scale(spec, parts[s], options)
    intensity = parts[0]  # parts is fresh; thresholding it in place only zeroes cells whose shares are 0
    peak = float(intensity.max()) if intensity.size else 0.0
    intensity[intensity < np.float32(1e-9 * peak)] = 0.0  # the cumulative sums' rounding residue
    if not bottom_types:
        return intensity, {}
    names = list(slot_of)
    out = np.empty((len(names), spec.n_bins, spec.n_beams), np.float32)
    kn, table = kernels(), np.array([slot_of[n] for n in names], np.int64)
    split_run(lambda r0, r1: kn.shares(parts, intensity, table, r0, r1, out), spec.n_bins, threads)
    return intensity, _read_only_shares(out, names)


def cell_area(spec: SonarSpec, rays: SonarRays, bottom_types: dict) -> np.ndarray:
    """Seabed area (m^2) that falls in each ``(bin, beam)`` cell, ``(n_bins, n_beams)``.

    A ray's elevation cell of ``a + b`` rad and one beam spacing covers
    ``r^2 cos(phi) dtheta (a + b) / cos(alpha)`` of surface; it is box-integrated over its
    range footprint like the echo (no pulse blur, no beam pattern: the scatterers' grid).
    Only bodies with a ``bottom_type`` count; without any, every body does.
    """
    ids = [i for v in bottom_types.values() for i in v]
    if use_numba():
        n_bodies = max([int(np.max(rays.body, initial=-1))] + ids) + 1
        is_seabed = np.zeros(n_bodies + 1, np.bool_)
        is_seabed[ids if ids else slice(0, n_bodies)] = True
        flat = lambda a: np.ascontiguousarray(a).reshape(-1)  # noqa: E731
        area = np.empty(rays.body.size)
        kernels().subcell_area(flat(rays.body), is_seabed, flat(rays.range), flat(rays.cos_incidence),
                               flat(rays.elevation_lo), flat(rays.elevation_hi), flat(rays.elevation),
                               flat(rays.beam_index), np.ascontiguousarray(np.diff(spec.beam_edges), float), area)
        fake = dataclasses.replace(rays, energy=area.reshape(rays.body.shape))
        return _echo_numba(spec, fake, np.zeros(rays.body.size, np.int8), 1, 1, 1, None)[0]
    sel = np.isin(rays.body, ids) if ids else rays.body >= 0
    r = np.where(sel, rays.range, 0.0)
    cos_a = np.maximum(rays.cos_incidence, 0.05)
    width = rays.elevation_hi - rays.elevation_lo
    dtheta = np.diff(spec.beam_edges)[rays.beam_index]
    area = np.where(sel, r * r * np.cos(rays.elevation) * dtheta * width / cos_a, 0.0)
    fake = dataclasses.replace(rays, energy=area)
    if use_numba():
        one = np.zeros(rays.body.size, np.int8)
        return _echo_numba(spec, fake, one, 1, 1, 1, None)[0]
    return np.ascontiguousarray(echo_profile(spec, fake).T, dtype=np.float32)


def _bottom_types(scene: Scene) -> dict:
    """Bottom type -> ids of the seabed bodies of that type, in scene order."""
    types: dict[str, list[int]] = {}
    for i, b in enumerate(scene.bodies):
        if b.material.bottom_type is not None:
            types.setdefault(b.material.bottom_type, []).append(i)
    return types


def _class_parts(bottom_types: dict, spec: SonarSpec, rays: SonarRays, options: SonarOptions):
    """The echo of each class (each bottom type, and the targets) but the one with most rays.

    Returns ``(parts, largest)``: ``parts[name] = (beams, image)`` with the class's echo
    on the beams its rays reach, and the name of the class left out (``None`` = targets).
    Usually only the targets are integrated: a few rays, on a few beams.
    """
    if not bottom_types:
        return {}, None
    lit = rays.energy > 0
    classes = {name: lit & np.isin(rays.body, ids) for name, ids in bottom_types.items()}
    classes[None] = lit & ~np.any(np.stack(list(classes.values())), axis=0)
    largest = max(classes, key=lambda k: int(classes[k].sum()))
    parts = {}
    for name, sel in classes.items():
        if name == largest or not sel.any():
            continue
        beams = np.flatnonzero(np.bincount(rays.beam_index[sel], minlength=spec.n_beams))
        if options.azimuth_pattern or options.beam_model == "aperture":
            beams = np.arange(spec.n_beams)
        parts[name] = (beams, _form_image(spec, rays, options, select=sel, beams=beams))
    return parts, largest


def _seabed_shares(bottom_types: dict, parts, largest, intensity) -> dict:
    """Share of each cell's echo that comes from seabed bodies, per bottom type.

    The largest class's share is the remainder of the others'.
    """
    if not bottom_types:
        return {}
    shares: dict = {}
    rest = np.ones_like(intensity)
    with np.errstate(invalid="ignore", divide="ignore"):
        for name in list(bottom_types) + [None]:
            if name == largest:
                continue
            share = np.zeros_like(intensity)
            if name in parts:
                beams, part = parts[name]
                sub = intensity[:, beams]
                share[:, beams] = np.where(sub > 0, np.clip(part / sub, 0.0, 1.0), 0.0)
            rest -= share
            shares[name] = share
    shares[largest] = np.clip(rest, 0.0, 1.0)
    out = {}
    for name in bottom_types:
        sh = shares[name].astype(np.float32)
        sh[intensity <= 0] = 0.0
        sh.setflags(write=False)
        out[name] = sh
    return out


class _done:
    """A finished result with the ``Future.result()`` interface."""

    def __init__(self, value):
        self._value = value

    def result(self):
        return self._value


_BACKGROUND = None


def _background():
    """One worker thread for work that overlaps the scan (noise draws)."""
    global _BACKGROUND
    if _BACKGROUND is None:
        from concurrent.futures import ThreadPoolExecutor

        _BACKGROUND = ThreadPoolExecutor(max_workers=1, thread_name_prefix="oas-background")
    return _BACKGROUND


def _scan(scene: Scene, caster: RayCaster, spec: SonarSpec, pose: Pose, options: SonarOptions,
          weights=None, pattern=None, after_cast=None, materialise: bool = True, footprint_threads=None):
    """Cast the beams' rays and compute each ray's echo energy and range footprint (sec. 2.6.1).

    ``weights`` (``(elevation_samples,)``) overrides the elevation pattern's weights.
    ``after_cast`` (no arguments) is called once the primary rays are cast; when it returns True it has
    started work on one of the caster's threads (the noise's draws), and with two threads the edge
    refinement's cast then stays on the calling thread (:func:`_refine_edges_numba`).
    With ``pattern`` (the aperture model's elevation pattern) returns ``(rays, image_rays)``:
    ``image_rays`` splits every ray whose footprint is long in range into sub-cells
    (:func:`_subdivide`), so that the echo's density follows the surface within it.
    ``materialise=False`` (compiled kernels only): ``image_rays`` is an :class:`_ApertureCells`,
    what the fused kernel of :func:`_form_aperture_numba` needs to form the sub-cells itself.
    ``footprint_threads``: threads of the footprints' pass (default the caster's).
    """
    fast = use_numba()
    K, J = spec.elevation_samples, spec.n_beams
    # angular extent of each ray's elevation cell below (a) and above (b) the ray
    step = spec.elevation_step
    if fast:
        # scratch of this frame (the rays keep elevation - a and elevation + b): per-thread, reused; filled
        # with the half step chunk by chunk as the grid is read
        a, b = _workspace("scan_a", (K * J,), np.float64), _workspace("scan_b", (K * J,), np.float64)
        body, r, nd, ndd, cos_inc, slope = _scan_hits_numba(caster, spec, pose, ab=(a, b, 0.5 * step))
    else:
        body, r, nd, ndd, cos_inc, slope = _scan_hits_numpy(caster, spec, pose)
    beside = bool(after_cast()) if after_cast is not None else False
    if not fast:
        hit = body >= 0
        a = np.full(K * J, 0.5 * step)
        b = np.full(K * J, 0.5 * step)
    _refine_edges(caster, spec, pose, body, r, slope, a, b, split=not (beside and caster.threads <= 2))

    refl = np.array([bd.material.reflectivity for bd in scene.bodies] + [0.0])
    beam_grid, elev_grid = _index_grids(spec)
    if weights is None and options.elevation_pattern != "uniform":
        weights = _elevation_weights(spec, options.elevation_pattern)
    gain = None
    if options.propagation == "spreading":
        if fast:  # one kernel pass (no float64 power and where-copies over the grid)
            from .propagation import absorption_scalar

            gain = _workspace("scan_gain", (K * J,), np.float64)  # read by footprints only
            k_abs = -0.2 * np.log(10.0) * absorption_scalar(spec.frequency, options.water)
        else:
            gain = np.where(hit, two_way_gain(np.where(hit, r, 1.0), spec.frequency, options.water), 0.0)
    elev = _elevation_grid(spec)  # read-only and shared by the frames of a spec, as beam_index
    if fast:
        energy, lo, hi = np.empty(K * J), np.empty(K * J), np.empty(K * J)
        elev_lo, elev_hi = np.empty(K * J), np.empty(K * J)
        w_k = np.zeros(0) if weights is None else np.asarray(weights, float)
        kn = kernels()

        def rows(k0, k1):  # elevation rows k0..k1 (every ray on its own: the threads take rows)
            s = slice(k0 * J, k1 * J)
            if gain is not None:
                kn.spreading_gain(body[s], r[s], k_abs, gain[s])
            kn.footprints(body[s], r[s], cos_inc[s], slope[s], a[s], b[s], refl, w_k[k0:k1],
                          np.zeros(0) if gain is None else gain[s], J, 1e-4 * spec.bin_width, energy[s], lo[s], hi[s])
            # the cells' elevation spans, rows by rows on the same threads (the same sums as elev - a, elev + b)
            np.subtract(elev[s], a[s], out=elev_lo[s])
            np.add(elev[s], b[s], out=elev_hi[s])

        chunked_run(rows, K, caster.threads if footprint_threads is None else footprint_threads)
    else:
        elev_lo, elev_hi = elev - a, elev + b
        energy = refl[body] * cos_inc * (a + b)
        if weights is not None:
            energy *= weights[elev_grid]
        if gain is not None:
            energy = energy * gain
        # range footprint of the cell on the tangent plane; a floor on its width (1e-4 of a
        # bin) keeps the box integral well conditioned
        lo = r - slope * a
        hi = r + slope * b
        lo, hi = np.minimum(lo, hi), np.maximum(lo, hi)
        with np.errstate(invalid="ignore"):
            pad = np.maximum(0.0, 1e-4 * spec.bin_width - (hi - lo)) * 0.5
        lo, hi = np.where(hit, lo - pad, np.nan), np.where(hit, hi + pad, np.nan)
        energy = np.where(hit, energy, 0.0)
    shape = (K, J)
    rays = SonarRays(
        range=r.reshape(shape),
        energy=energy.reshape(shape),
        body=body.reshape(shape),
        cos_incidence=cos_inc.reshape(shape),
        footprint_lo=lo.reshape(shape),
        footprint_hi=hi.reshape(shape),
        beam_index=beam_grid.reshape(shape),
        elevation=elev.reshape(shape),
        elevation_lo=elev_lo.reshape(shape),
        elevation_hi=elev_hi.reshape(shape),
        elevation_step=step,
    )
    if pattern is None:
        return rays
    if fast and not materialise:
        # the reflectivity per body id (the kernel reads it by the ray's body: no per-ray gather)
        return rays, _aperture_cells(spec, rays, nd, ndd, a, b, refl, pattern, options)
    if fast:
        return rays, _subdivide_numba(spec, rays, nd, ndd, a, b, refl[body], pattern, options, caster.threads)
    return rays, _subdivide(spec, rays, nd, ndd, a, b, refl[body], pattern, options)


def _scan_hits_numpy(caster: RayCaster, spec: SonarSpec, pose: Pose):
    """Cast the grid; per ray ``(body, r, n.d, n.d', |n.d|, dr/dphi)`` (numpy reference path)."""
    d_w, dd_w = _world_ray_grid(spec, pose.R)
    # the unvalidated float32 path: the grid's directions are unit vectors by construction
    body, r, normal = _cast_fast(caster, pose.t, d_w, spec.range_max * 1.5, smooth=True)
    hit = body >= 0
    with np.errstate(invalid="ignore"):
        nd = np.einsum("ij,ij->i", normal, d_w)
        ndd = np.einsum("ij,ij->i", normal, dd_w)
    cos_inc = np.where(hit, np.abs(nd), 0.0)
    # signed dr/dphi on the tangent plane; clamped near grazing incidence
    with np.errstate(invalid="ignore", divide="ignore"):
        slope = np.where(hit, -r * ndd / (np.where(nd < 0, -1.0, 1.0) * np.maximum(cos_inc, _MIN_COS_FOOTPRINT)), 0.0)
    return body, r, nd, ndd, cos_inc, slope


def _fill_rows(out: np.ndarray, row) -> np.ndarray:
    """Every row of ``out`` ``(N, 3)`` set to ``row`` (cast to ``out``'s dtype), column by column: the
    broadcast ``out[...] = row`` runs an inner loop of length 3 per row, 6x slower (0.45 ms for 65 536 rows);
    with the compiled kernels, one flat pass (``_numba_kernels.fill_rows3``)."""
    row = np.asarray(row, out.dtype)
    if use_numba() and out.ndim == 2 and out.shape[1] == 3 and out.flags.c_contiguous:
        kernels().fill_rows3(out, row)
        return out
    for c in range(out.shape[1]):
        out[:, c] = row[c]
    return out


def _scan_hits_numba(caster: RayCaster, spec: SonarSpec, pose: Pose, ab=None):
    """:func:`_scan_hits_numpy` with the grid built and Embree's float32 output read by kernels.
    ``ab`` ``(a, b, value)``: two ``(K * J,)`` arrays filled with ``value`` chunk by chunk as the grid is
    read (on the casting threads, instead of two fills on the calling thread after the cast)."""
    kn = kernels()
    R = pose.R
    th, ph = spec.azimuths, spec.elevations
    a_dir = np.sin(th)[:, None] * R[:, 0] + np.cos(th)[:, None] * R[:, 1]  # (J, 3), see _world_ray_grid
    cp, sp, rz = np.cos(ph), np.sin(ph), np.ascontiguousarray(R[:, 2])
    n = spec.elevation_samples * spec.n_beams
    # the rays, and n.d, n.d' and the slope, are scratch of this frame (per-thread, reused: fresh
    # multi-MB arrays fault on every frame); body, range and cos(incidence) go into the frame's rays
    d32 = _workspace("scan_d32", (n, 3), np.float32)
    kn.ray_grid32(cp, sp, a_dir, rz, d32)
    o32 = _fill_rows(_workspace("scan_o32", (n, 3), np.float32), pose.t)
    dist32 = _workspace("scan_dist32", (n,), np.float32)
    dist32.fill(min(np.float32(spec.range_max * 1.5), np.float32(1e30)))  # Embree writes its hits' distances here
    body = np.empty(n, np.int32)
    r, cos_inc = np.empty(n), np.empty(n)
    nd, ndd, slope = (_workspace(f"scan_{name}", (n,), np.float64) for name in ("nd", "ndd", "slope"))
    cn, off, ng = caster.corner_normals, caster.triangle_offset, np.zeros((0, 3), np.float32)

    def each(i0, i1, tfar, geom, prim, u, v):  # each chunk read on the thread that cast it, as soon as it is cast
        kn.scan_rays(tfar, geom, prim, u, v, ng, cn, off, True, cp, sp, a_dir, rz, i0, i1,
                     body, r, nd, ndd, cos_inc, slope, i0)
        if ab is not None:
            kn.fill2(ab[0], ab[1], ab[2], i0, i1)

    caster.intersect_each(o32, d32, dist32, each)
    return body, r, nd, ndd, cos_inc, slope


@functools.lru_cache(maxsize=16)
def _two_way_table(pattern, fov: float):
    """``F^4`` at 8193 equally spaced elevations over ``[-fov / 2, fov / 2]`` (read-only)."""
    x = np.linspace(-fov / 2, fov / 2, 8193)
    y = np.asarray(pattern.two_way(x), float)
    x.setflags(write=False)
    y.setflags(write=False)
    return x, y


def _two_way_lookup(pattern, fov: float):
    """``F^4`` by linear interpolation in a table of 8193 samples over ``[-fov / 2, fov / 2]``
    (within 1e-5 of the closed form for the apertures of the presets; np.sinc is slow)."""
    x, y = _two_way_table(pattern, fov)
    return functools.partial(np.interp, xp=x, fp=y)


#: At most this many sub-cells per ray in the aperture model's image rays (below 256: the fused
#: kernel's per-ray word, ``_aperture_kernels.aperture_words``, holds the count in 8 bits).
_MAX_SUBCELLS = 16
#: ... each covering at most about this many range bins.
_SUBCELL_BINS = 3.0


def _subdivide(spec: SonarSpec, rays: SonarRays, nd, ndd, a, b, refl, pattern, options) -> SonarRays:
    """Split each hit ray's elevation cell into sub-cells no longer than about 3 range bins.

    On the ray's tangent plane the direction at elevation offset ``t`` is exactly
    ``d cos t + d' sin t``, so ``n . d(t) = nd cos t + ndd sin t``, the range is
    ``r(t) = r nd / (n . d(t))`` and the Lambert factor ``|n . d(t)|``. Each sub-cell gets
    its own two-way pattern weight, Lambert factor and propagation; its footprint runs
    between the ranges of its two ends. Returns flat (1-D) ``SonarRays`` for image formation.
    """
    hit = rays.body.reshape(-1) >= 0
    lo, hi = rays.footprint_lo.reshape(-1), rays.footprint_hi.reshape(-1)
    length = np.where(hit, (hi - lo) / spec.bin_width, 0.0)
    n_sub = np.where(hit, np.clip(np.ceil(length / _SUBCELL_BINS), 1, _MAX_SUBCELLS), 0).astype(np.int64)
    idx = np.repeat(np.arange(n_sub.size), n_sub)
    first = np.cumsum(n_sub) - n_sub
    k = np.arange(idx.size) - first[idx]
    S = n_sub[idx]
    width = (a + b)[idx]
    delta = width / S
    t = -a[idx] + (k + 0.5) * delta
    ndi, nddi = nd[idx], ndd[idx]
    sgn = np.where(ndi < 0, -1.0, 1.0)
    # n . d(t +- delta / 2) by the angle-addition formulas: four trigonometric calls, not six
    ct, st = np.cos(t), np.sin(t)
    ch, sh = np.cos(0.5 * delta), np.sin(0.5 * delta)
    p_mid = (ndi * ct + nddi * st) * sgn
    p_dif = (nddi * ct - ndi * st) * sgn  # d/dt of p_mid
    c_mid = np.maximum(p_mid, _MIN_COS_FOOTPRINT)
    p_a = np.maximum(p_mid * ch - p_dif * sh, _MIN_COS_FOOTPRINT)
    p_b = np.maximum(p_mid * ch + p_dif * sh, _MIN_COS_FOOTPRINT)
    base = rays.range.reshape(-1)[idx] * np.abs(ndi)
    r_mid = base / c_mid
    r_a, r_b = base / p_a, base / p_b
    flo, fhi = np.minimum(r_a, r_b), np.maximum(r_a, r_b)
    pad = np.maximum(0.0, 1e-4 * spec.bin_width - (fhi - flo)) * 0.5
    elev = rays.elevation.reshape(-1)[idx] + t
    energy = refl[idx] * c_mid * delta * _two_way_lookup(pattern, spec.fov_elevation)(elev)
    if options.propagation == "spreading":
        energy = energy * two_way_gain(r_mid, spec.frequency, options.water)
    return SonarRays(
        range=r_mid, energy=energy, body=rays.body.reshape(-1)[idx], cos_incidence=c_mid,
        footprint_lo=flo - pad, footprint_hi=fhi + pad, beam_index=rays.beam_index.reshape(-1)[idx],
        elevation=elev, elevation_lo=elev - 0.5 * delta, elevation_hi=elev + 0.5 * delta,
        elevation_step=rays.elevation_step,
    )


def _subdivide_numba(spec: SonarSpec, rays: SonarRays, nd, ndd, a, b, refl, pattern, options, threads: int = 1) -> SonarRays:
    """:func:`_subdivide` by one kernel pass (the pattern's table interpolated in the kernel)."""
    from .propagation import absorption_db_per_m

    fov = spec.fov_elevation
    x, y = _two_way_table(pattern, fov)
    flat = lambda arr: np.ascontiguousarray(arr).reshape(-1)  # noqa: E731
    spreading = options.propagation == "spreading"
    alpha = float(absorption_db_per_m(spec.frequency, options.water)) if spreading else 0.0
    kn = kernels()
    body0, lo0, hi0, beam0 = flat(rays.body), flat(rays.footprint_lo), flat(rays.footprint_hi), flat(rays.beam_index)
    n_sub = np.empty(body0.size, np.int64)
    total = kn.subcell_counts(body0, lo0, hi0, spec.bin_width, _MAX_SUBCELLS, _SUBCELL_BINS, n_sub)
    r, energy, c, lo, hi, el, el_lo, el_hi = (np.empty(total) for _ in range(8))
    body, beam = np.empty(total, body0.dtype), np.empty(total, beam0.dtype)
    first = np.cumsum(n_sub) - n_sub  # where each ray's sub-cells start: the rays split over threads
    rng0 = flat(rays.range)
    el0 = flat(rays.elevation)
    x0, dx = float(x[0]), float(x[1] - x[0])
    split_run(lambda i0, i1: kn.subdivide(body0, rng0, lo0, hi0, nd, ndd, a, b, refl, el0, beam0, spec.bin_width,
                                          n_sub, x0, dx, y, alpha, spreading,
                                          r, energy, body, c, lo, hi, beam, el, el_lo, el_hi, i0, i1,
                                          int(first[i0]) if i0 < first.size else 0), body0.size, threads)
    return SonarRays(range=r, energy=energy, body=body, cos_incidence=c, footprint_lo=lo, footprint_hi=hi,
                     beam_index=beam, elevation=el, elevation_lo=el_lo, elevation_hi=el_hi,
                     elevation_step=rays.elevation_step)


@dataclass(frozen=True, eq=False)
class _ApertureCells:
    """What the aperture model's fused kernel needs to form the sub-cells of :func:`_subdivide`
    itself (``_aperture_kernels.aperture_echo_rows``): the primary rays, per ray (flat,
    ``(K * J,)``) ``n . d``, ``n . d'``, the cell's extents below/above the ray ``a``, ``b``, the
    reflectivity per body id ``refl`` (``(n_bodies + 1,)``, the last entry 0 for a miss: indexed by
    the ray's body, not per ray) and the two-way pattern's table over the scan's elevations."""

    rays: SonarRays
    nd: np.ndarray
    ndd: np.ndarray
    a: np.ndarray
    b: np.ndarray
    refl: np.ndarray
    table: tuple  # (x0, dx, y) of _two_way_table over the scan's elevation span
    alpha_db: float
    spreading: bool


def _aperture_cells(spec: SonarSpec, rays: SonarRays, nd, ndd, a, b, refl, pattern, options) -> _ApertureCells:
    """The arguments of :func:`_subdivide_numba`, kept for the fused kernel instead of sub-cells."""
    from .propagation import absorption_scalar

    x, y = _two_way_table(pattern, spec.fov_elevation)
    spreading = options.propagation == "spreading"
    alpha = absorption_scalar(spec.frequency, options.water) if spreading else 0.0
    c = np.ascontiguousarray
    return _ApertureCells(rays, c(nd, float), c(ndd, float), c(a, float), c(b, float), c(refl, float),
                          (float(x[0]), float(x[1] - x[0]), y), alpha, spreading)


def _form_aperture_numba(spec: SonarSpec, cells: _ApertureCells, options: SonarOptions, bottom_types: dict,
                         threads: int, need_area: bool):
    """The aperture model's intensity, seabed shares and (``need_area``) seabed area per cell from
    one kernel pass per beam (``_aperture_kernels``): what :func:`_subdivide_numba`,
    :func:`_form_with_shares_numba` and :func:`cell_area` give on the sub-cells, without storing
    them (the area bit for bit; the echo's float64 sums in another order, the same to their rounding).

    Returns ``(intensity, shares, area or None)``, each ``(n_bins, n_beams)`` float32; ``area`` is
    a per-thread scratch that the next call on this thread overwrites.
    """
    out, area, live, slot_of = _aperture_rows(spec, cells, options, bottom_types, threads, need_area)
    n_slots, J, B = out.shape
    # the azimuth pattern mixes whole rows (beams); scale, threshold, shares and the image layout in one pass
    mixed = _workspace(f"mixed{n_slots}", (n_slots, J, B), np.float32)
    spans = [_live_span(live[s], spec) for s in range(n_slots)]
    if threads > 1 and all(sp is not None for sp in spans):
        # cv2's filter along the beams, in pieces of _MIX_COLUMNS bins (columns) of every slot that the
        # threads take in turn (cv2 releases the GIL): each bin's column is filtered on its own, and pieces
        # starting at multiples of its vector width compute each value as the whole image does (bit for bit)
        pieces = iter([(s, c0, min(c0 + _MIX_COLUMNS, B)) for s in range(n_slots) for c0 in range(0, B, _MIX_COLUMNS)])

        def work():
            for s, c0, c1 in pieces:  # next() on the iterator is atomic under the GIL
                _mix_rows(spec, out[s][:, c0:c1], mixed[s][:, c0:c1], spans[s], s != 1)

        from ._kernels import take_turns

        take_turns(work, threads)
    elif threads > 1 and n_slots > 1:  # the class images on the other threads meanwhile (cv2 releases the GIL)
        from ._kernels import _pool, wait_or_run_here

        jobs = [_pool(threads - 1).submit(_mix_rows, spec, out[s], mixed[s], spans[s], s != 1)
                for s in range(1, n_slots)]
        _mix_rows(spec, out[0], mixed[0], spans[0])
        for s, job in zip(range(1, n_slots), jobs):
            wait_or_run_here(job, _mix_rows, spec, out[s], mixed[s], spans[s], s != 1)
    else:
        for s in range(n_slots):
            _mix_rows(spec, out[s], mixed[s], spans[s], s != 1)
    # the targets' slot is mixed over its live span only (the zeros outside are neither written nor read)
    targets_span = spans[1] if n_slots > 1 else None
    intensity, shares = _finish_numba(spec, mixed, bottom_types, slot_of, threads, targets_span)
    return intensity, shares, area


def _aperture_rows(spec: SonarSpec, cells: _ApertureCells, options: SonarOptions, bottom_types: dict,
                   threads: int, need_area: bool):
    """:func:`_form_aperture_numba`'s kernel pass (``_aperture_kernels.aperture_echo_rows``): the rows
    ``(n_slots, n_beams, n_bins)`` float32 (per-thread scratch, as :func:`_echo_rows_numba`'s), the
    seabed area ``(n_bins, n_beams)`` (``None`` unless ``need_area``), which rows have echo
    (bool ``(n_slots, n_beams)``) and the slot of each class (as :func:`_class_slots`)."""
    from . import _aperture_kernels as ak

    rays = cells.rays
    flat = lambda arr: np.ascontiguousarray(arr).reshape(-1)  # noqa: E731
    body, lo, hi = flat(rays.body), flat(rays.footprint_lo), flat(rays.footprint_hi)
    J, B = spec.n_beams, spec.n_bins
    K = body.size // J
    # one pass over the rays in the grid's order writes each ray's word (sub-cell count, refined-edge
    # flag, body) beam-major, so that the kernel's loop over a beam's rays reads them contiguously, and
    # counts the classes' lit sub-cells (as _class_slots counts lit rays, each weighted by its sub-cells)
    names, cls = _class_table(bottom_types, body)
    counts = np.zeros(len(names), np.int64)
    word = _workspace("aperture_word", (body.size,), np.int64)
    max_s = ak.aperture_words(body, lo, hi, flat(rays.energy), flat(cells.a), flat(cells.b), 0.5 * rays.elevation_step,
                              cls, spec.bin_width, _MAX_SUBCELLS, _SUBCELL_BINS, K, J, word, counts)
    if not bottom_types:
        slot_of_body, n_slots, slot_of = np.zeros(cls.size, np.int8), 1, {}
    else:  # the class with most lit sub-cells takes slot 0, as _class_slots on the sub-cells
        table, n_slots, slot_of = _slot_table(names, counts)
        slot_of_body = table[cls]
    ids = [i for v in bottom_types.values() for i in v]
    n_bodies = max([int(np.max(body, initial=-1))] + ids) + 1
    is_seabed = np.zeros(n_bodies + 1, np.bool_)
    is_seabed[ids if ids else slice(0, n_bodies)] = True
    q = options.range_oversample
    sigma_bins = max(spec.pulse_width / spec.bin_width / 2.3548, 0.5)
    H, V, full = _deposit_tables(spec.n_bins, q, sigma_bins)
    out = _workspace(f"echo{n_slots}", (n_slots, J, B), np.float32)
    # written in the image layout into a reused scratch (fresh pages fault on every frame): the
    # caller reads it before the next frame on this thread (simulate_sonar: the noise's counts)
    area = _workspace("aperture_area", (B, J), np.float32) if need_area else np.empty((0, 0), np.float32)
    x0, dx, y = cells.table
    dtheta = np.ascontiguousarray(np.diff(spec.beam_edges), float)
    elevation_k = np.ascontiguousarray(rays.elevation[:, 0], float)  # the grid's rows: one elevation each
    args = (flat(rays.range), cells.nd, cells.ndd, cells.a, cells.b, 0.5 * rays.elevation_step,
            cells.refl, elevation_k, word, K, J, x0, dx, y, cells.alpha_db, cells.spreading, spec.bin_width,
            slot_of_body, is_seabed, dtheta, float(spec.range_min), B * q, H, V, full, q, B, bool(need_area), max_s)
    live = np.empty((n_slots, J), np.bool_)
    chunked_run(lambda j0, j1: ak.aperture_echo_rows(*args, j0, j1, out, area, live), J, threads)
    return out, (area if need_area else None), live, slot_of


#: Sub-rays cast across each visibility discontinuity between two elevation samples.
_EDGE_SUBRAYS = 8


def _cast_fast(caster: RayCaster, origin, d_world, max_distance: float, smooth: bool):
    """``caster.cast`` from one origin along unit directions ``(N, 3)``, bit for bit, without
    its validation: ``(body (N,) int32, distance (N,) float64 (inf on a miss), unit
    normal (N, 3) float64 (NaN on a miss))``."""
    d32 = np.asarray(d_world, np.float32)
    o32 = np.empty_like(d32)
    o32[...] = np.asarray(origin, np.float32)
    dist32 = np.full(len(d32), min(np.float32(max_distance), np.float32(1e30)), np.float32)
    tfar, body, _, nrm = caster.cast_raw(o32, d32, dist32, smooth=smooth)
    r, n = widen_hits(tfar, nrm, body < 0)
    return body, r, n


def _refine_edges(caster, spec, pose, body, r, slope, a, b, split: bool = True) -> None:
    """Locate visibility edges between consecutive elevation samples and move the cell boundary there.

    Between rays k and k+1 of a beam that see different surfaces (another body, a miss,
    or a range jump their tangent planes cannot explain) the true transition lies
    anywhere in between; midpoint cells would misplace it by up to half a cell, which at
    grazing incidence is several range bins (jagged shadow edges). ``_EDGE_SUBRAYS``
    sub-rays between the two classify which surface continues where, and the shared cell
    boundary moves to the transition. ``a`` (extent below) and ``b`` (above) are updated
    in place; energy follows the cells' widths, so it stays conserved. ``split=False``: the compiled
    path casts the sub-rays on the calling thread only.
    """
    K, J = spec.elevation_samples, spec.n_beams
    step = spec.elevation_step
    if use_numba():
        _refine_edges_numba(caster, spec, pose, body, r, slope, a, b, split)
        return
    B = body.reshape(K, J)
    Rg = r.reshape(K, J)
    S_ = slope.reshape(K, J)
    reach = np.abs(S_) * step  # range a tangent plane covers over one cell
    with np.errstate(invalid="ignore"):
        jump = np.abs(Rg[1:] - Rg[:-1]) > 1.5 * (reach[1:] + reach[:-1]) + 0.5 * spec.bin_width
    disc = (B[1:] != B[:-1]) | (jump & (B[1:] >= 0))
    kk, jj = np.nonzero(disc)
    if kk.size == 0:
        return
    S = _EDGE_SUBRAYS
    frac = (np.arange(S) + 0.5) / S
    phi = spec.elevations[kk][:, None] + step * frac[None, :]
    th = spec.azimuths[jj][:, None]
    cp = np.cos(phi)
    d = pose.directions_to_world(np.stack(np.broadcast_arrays(cp * np.sin(th), cp * np.cos(th), np.sin(phi)), -1))
    h_body, h_dist, _ = _cast_fast(caster, pose.t, d.reshape(-1, 3), spec.range_max * 1.5, smooth=False)
    h_body, h_dist = h_body.reshape(d.shape[:-1]), h_dist.reshape(d.shape[:-1])
    lower = kk * J + jj
    upper = lower + J
    bl, bu = body[lower][:, None], body[upper][:, None]
    with np.errstate(invalid="ignore"):
        pred_l = r[lower][:, None] + slope[lower][:, None] * step * frac[None, :]
        pred_u = r[upper][:, None] - slope[upper][:, None] * step * (1 - frac[None, :])
        err_l = np.where(h_body == bl, np.abs(h_dist - pred_l), np.inf)
        err_u = np.where(h_body == bu, np.abs(h_dist - pred_u), np.inf)
    miss = h_body < 0
    err_l = np.where(miss & (bl < 0), 0.0, err_l)
    err_u = np.where(miss & (bu < 0), 0.0, err_u)
    like_lower = err_l < err_u
    like_lower |= np.isinf(err_u) & np.isinf(err_l) & (frac[None, :] < 0.5)  # a third surface: split evenly
    t = like_lower.sum(1) / S  # transition, as a fraction of the step above ray k
    b[lower] = step * t
    a[upper] = step * (1 - t)


@functools.lru_cache(maxsize=16)
def _edge_trig(spec: SonarSpec):
    """The trigonometry of :func:`_refine_edges`' sub-rays, per spec (read-only, cached):
    ``cos``, ``sin`` of the sub-rays' elevations ``(K - 1, _EDGE_SUBRAYS)`` (sub-ray ``s`` between
    samples ``k`` and ``k + 1`` at ``phi_k + step (s + 1/2) / S``) and ``sin``, ``cos`` of the beams'
    azimuths ``(n_beams,)``: the same numbers as the numpy path's per-frame calls on them."""
    S = _EDGE_SUBRAYS
    frac = (np.arange(S) + 0.5) / S
    phi = spec.elevations[:-1, None] + spec.elevation_step * frac[None, :]
    out = (np.cos(phi), np.sin(phi), np.sin(spec.azimuths), np.cos(spec.azimuths))
    for arr in out:
        arr.setflags(write=False)
    return out


def _refine_edges_numba(caster, spec, pose, body, r, slope, a, b, split: bool = True) -> None:
    """:func:`_refine_edges` with the discontinuities found, the sub-rays' directions formed and the
    sub-rays classified by kernels (the directions from per-spec tables of the numpy path's sines
    and cosines, rotated with its einsum's order of sums: both cast the same float32 rays)."""
    K, J = spec.elevation_samples, spec.n_beams
    step = spec.elevation_step
    kn = kernels()
    kk, jj = _workspace("edge_kk", ((K - 1) * J,), np.int64), _workspace("edge_jj", ((K - 1) * J,), np.int64)
    m = kn.edge_pairs(body, r, slope, K, J, step, 0.5 * spec.bin_width, kk, jj)
    if m == 0:
        return
    kk, jj = kk[:m], jj[:m]
    S = _EDGE_SUBRAYS
    cp, sp, sth, cth = _edge_trig(spec)
    d32 = np.empty((m * S, 3), np.float32)
    kn.edge_directions32(kk, jj, cp, sp, sth, cth, np.ascontiguousarray(pose.R, float), 0, m, d32)
    o32 = _fill_rows(np.empty_like(d32), pose.t)
    dist32 = np.full(len(d32), min(np.float32(spec.range_max * 1.5), np.float32(1e30)), np.float32)
    # split=False (_scan: two threads, one of them drawing the noise): on the calling thread alone. The
    # sub-rays lie along silhouettes, scattered over the fan; on the 2-vCPU machine of the benchmarks two
    # threads cast such rays no faster than one (i14o: 8 120 sub-rays 1.30 ms on one thread, 1.33-1.58
    # split), and a split put a chunk beside the noise's words on the other vCPU (2.8 ms of wall for the
    # realistic frame's edge cast at two threads, 1.3 alone). With more threads the split stays.
    tfar, h_body, _, _, _, _ = caster.intersect_raw(o32, d32, dist32, normals=False, split=split)
    kn.edge_split(kk, jj, h_body, tfar, body, r, slope, step, S, J, a, b)


def _truth_maps(spec: SonarSpec, rays: SonarRays, threads: int = 1):
    """Per cell: the body of the strongest single contribution and the elevation span that echoes."""
    B, J = spec.n_bins, spec.n_beams
    if use_numba():
        body_map = np.empty((B, J), np.int16)
        el_min = np.empty((B, J), np.float32)
        el_max = np.empty((B, J), np.float32)
        flat = lambda a: np.ascontiguousarray(a).reshape(-1)  # noqa: E731
        args = (flat(rays.beam_index), flat(rays.footprint_lo), flat(rays.footprint_hi), flat(rays.energy),
                flat(rays.body), flat(rays.elevation_lo), flat(rays.elevation_hi), float(spec.range_min),
                1.0 / spec.bin_width, B, J, body_map, el_min, el_max)
        # written straight into the maps (no scratch pass); beam ranges: disjoint columns
        tk, odd = truth_kernels(), []
        weight = _workspace("truth_weight", (B, J), np.float32)
        # the grid's beams in chunks that the threads take as they finish, each chunk reading its own rays
        # (fixed halves, each reading every ray, waited for the slower core)
        chunked_run(lambda j0, j1: odd.append(tk.truth_maps_grid(*args, weight, j0, j1)), J, threads)
        if any(o < 0 for o in odd):  # rays not in the grid's order (never from _scan): every ray per part
            odd = []
            split_run(lambda j0, j1: odd.append(tk.truth_maps_direct(*args, weight, j0, j1)), J, threads)
        if any(odd):  # a lit ray with a non-finite elevation span: the ray-order kernel's rules for those
            kn = kernels()
            rec = _workspace("truth_cells", (B, J, 4), np.float32)
            split_run(lambda j0, j1: kn.truth_maps(*args, rec, j0, j1), J, threads)
        return body_map, el_min, el_max
    ok = rays.energy > 0
    inv = np.float32(1.0 / spec.bin_width)
    lo = (rays.footprint_lo[ok].astype(np.float32) - np.float32(spec.range_min)) * inv
    hi = (rays.footprint_hi[ok].astype(np.float32) - np.float32(spec.range_min)) * inv
    inside = (hi > 0) & (lo < B)
    lo, hi = lo[inside], hi[inside]
    dens = (rays.energy[ok][inside] / (hi - lo)).astype(np.float32)
    beam = rays.beam_index[ok][inside].astype(np.int32)
    body = rays.body[ok][inside].astype(np.int64)
    el_lo = rays.elevation_lo[ok][inside].astype(np.float32)
    el_hi = rays.elevation_hi[ok][inside].astype(np.float32)
    # expand each ray to the bins its footprint overlaps
    b0 = np.clip(lo, 0, B - 1).astype(np.int32)
    b1 = np.clip(hi, 0, B - 1).astype(np.int32)
    cnt = b1 - b0 + 1
    ray = np.repeat(np.arange(len(lo), dtype=np.int32), cnt)
    step = np.ones(len(ray), np.int32)
    first = np.cumsum(cnt) - cnt
    step[first[1:]] = 1 - cnt[:-1]
    step[0] = 0
    b = b0[ray] + np.cumsum(step, dtype=np.int32)
    bf = b.astype(np.float32)
    w = dens[ray] * np.clip(np.minimum(hi[ray], bf + 1) - np.maximum(lo[ray], bf), 0, None)
    cell = b * J + beam[ray]
    # strongest single contribution: positive float32 bit patterns order like their values
    packed = (w.view(np.int32).astype(np.int64) << 16) | (body[ray] + 1)
    best = np.zeros(B * J, np.int64)
    np.maximum.at(best, cell, packed)
    body_map = ((best & 0xFFFF) - 1).astype(np.int16).reshape(B, J)
    el_min = np.full(B * J, np.inf, np.float32)
    el_max = np.full(B * J, -np.inf, np.float32)
    np.minimum.at(el_min, cell, el_lo[ray])
    np.maximum.at(el_max, cell, el_hi[ray])
    unlit = ~np.isfinite(el_min)
    el_min[unlit] = np.nan
    el_max[unlit] = np.nan
    return body_map, el_min.reshape(B, J), el_max.reshape(B, J)


_FLOORS: "weakref.WeakKeyDictionary[Scene, tuple]" = weakref.WeakKeyDictionary()


def _floor_planes(scene: Scene) -> tuple:
    """Bodies that are horizontal planes with every vertex of the scene at or above them.

    A ray that crosses one going down meets nothing after it, so the acoustic shadow needs no
    continuation ray for it (exact; in most scenes the seabed, hit by most rays). Cached per scene.
    """
    got = _FLOORS.get(scene)
    if got is None:
        surfaces = scene.surfaces()
        lows = [float(sf.vertices[:, 2].min()) if sf.vertices.size else np.inf for sf in surfaces]
        floors = []
        for i, sf in enumerate(surfaces):
            z = sf.vertices[:, 2] if sf.vertices.size else None
            if z is None or float(z.max() - z.min()) > 1e-9 * max(1.0, abs(float(z.min()))):
                continue
            # 1 um: far below what Embree's float32 resolves (a body resting on the plane may dip 1e-16 m under it)
            if all(lows[k] >= float(z.min()) - 1e-6 for k in range(len(surfaces)) if k != i):
                floors.append(i)
        got = _FLOORS[scene] = tuple(floors)
    return got


_FLOOR_SIDES: "weakref.WeakKeyDictionary[Scene, tuple]" = weakref.WeakKeyDictionary()


def _floor_sides(scene: Scene) -> tuple:
    """``(body, z, up)`` of each floor plane (:func:`_floor_planes`): its height and the sign of its
    faces' geometric normals' z (+1: the front faces up). Cached per scene."""
    got = _FLOOR_SIDES.get(scene)
    if got is None:
        surfaces = scene.surfaces()
        out = []
        for i in _floor_planes(scene):
            sf = surfaces[i]
            v = np.asarray(sf.vertices, float)
            f = np.asarray(sf.faces)
            nz = float(np.sum(np.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]])[:, 2])) if f.size else 0.0
            if nz != 0.0:
                out.append((i, float(v[:, 2].min()), 1.0 if nz > 0 else -1.0))
        got = _FLOOR_SIDES[scene] = tuple(out)
    return got


def _grid_directions(spec: SonarSpec, R: np.ndarray, idx: np.ndarray):
    """World directions ``d`` and elevation derivatives ``d'`` of the grid rays ``idx`` (flat
    indices ``k * n_beams + j``), ``(len(idx), 3)`` each, as :func:`_world_ray_grid` gives them."""
    k, j = np.divmod(idx, spec.n_beams)
    th, ph = spec.azimuths[j], spec.elevations[k]
    a = np.sin(th)[:, None] * R[:, 0] + np.cos(th)[:, None] * R[:, 1]
    cp, sp = np.cos(ph)[:, None], np.sin(ph)[:, None]
    return cp * a + sp * R[:, 2], -sp * a + cp * R[:, 2]


def _shadow_mask(scene, caster, spec, pose, rays: SonarRays, elevation_min: np.ndarray, *,
                 direct: bool = True) -> np.ndarray:
    """Cells that would echo but for an occluder: the hidden surfaces behind each hit, unlit.

    Each hit ray is continued beyond its first hit to the next surface it meets from the front
    (``n . d < 0``, ``n`` the triangle's geometric normal): back faces are passed through, front
    faces of any body, the first one included, end it. Cells that this hidden surface's footprint
    covers and that no direct ray lights are acoustic shadow. Rays going down through a floor plane
    (a horizontal body with every vertex of the scene at or above it) are not continued: nothing
    lies beyond.

    Two ways to find the hidden surface, the same surface on closed bodies: with the numba kernels
    and where :meth:`RayCaster.front_hits` checks out (``direct``), one ``rtcIntersect1`` per ray whose
    filter rejects back-facing hits during the traversal; otherwise (and on the numpy reference
    path) casts in rounds, each from just beyond the previous hit, up to 6 hits per ray. The two
    measure the hidden range from different float32 origins (the first hit, or the last back face),
    so a footprint edge may move by float32 rounding and a cell at its edge flip; and where a body's
    base lies flush on the seabed, a ray leaving through it meets base and seabed at one distance:
    the one-cast path takes the seabed under the body (shadow), the rounds restart under the seabed
    and find nothing (207 of 35 895 shadow cells in the thesis frame). In both, a front face of the
    first body within ``SELF_GAP`` x the start's largest coordinate is the first hit met again through
    float32 rounding and is passed over (docs/physics.md 1.6.1). On an open surface
    (a body that is not closed) the rule is the one above in both ways: a front face of the body
    hit first that the ray meets without having crossed one of its back faces (a second sheet of
    the same open mesh behind the first) is a hidden surface; before issue 14 it was passed over.
    """
    if use_numba():
        return _shadow_mask_numba(scene, caster, spec, pose, rays, elevation_min, direct=direct)
    first_body = rays.body.reshape(-1)
    r0 = rays.range.reshape(-1)
    hit = first_body >= 0
    floors = _floor_planes(scene)
    if floors:  # nothing lies below a floor plane: a ray going down through it hits nothing more
        R = pose.R
        a_z = np.sin(spec.azimuths) * R[2, 0] + np.cos(spec.azimuths) * R[2, 1]
        down = (np.cos(spec.elevations)[:, None] * a_z + np.sin(spec.elevations)[:, None] * R[2, 2]).reshape(-1) < 0
        hit &= ~(np.isin(first_body, floors) & down)
    active = np.flatnonzero(hit)
    # the directions of the rays that continue only (most rays end on a floor)
    d_act, dd_act = _grid_directions(spec, pose.R, active)
    d_w = np.zeros((first_body.size, 3))
    dd_w = np.zeros((first_body.size, 3))
    d_w[active] = d_act
    dd_w[active] = dd_act
    hidden_r = np.full(first_body.shape, np.inf)
    hidden_n = np.zeros((first_body.size, 3))
    t = r0[active].copy()
    idx = active
    eps = 1e-4 * max(spec.bin_width, 1e-3)
    # a front face of the first body up to here is that first hit again (float32 rounding at grazing incidence)
    start32 = (pose.t + d_act * (t + eps)[:, None]).astype(np.float32)
    gap_end = np.zeros(first_body.size)
    gap_end[active] = t + eps + SELF_GAP * np.maximum(np.abs(start32).max(axis=1), 1.0).astype(np.float64)
    d32_all = np.asarray(d_w, np.float32)
    for _ in range(6):  # a few crossings of the occluding body are enough for closed shapes
        if idx.size == 0:
            break
        org = pose.t + d_w[idx] * (t + eps)[:, None]
        # the unvalidated float32 path (``caster.cast`` is this, widened): unit directions by construction
        dist32 = np.full(idx.size, min(np.float32(spec.range_max * 1.5), np.float32(1e30)), np.float32)
        h_dist, h_body, _, h_n = caster.cast_raw(np.asarray(org, np.float32), d32_all[idx], dist32, smooth=False)
        got = h_body >= 0
        tt = t + eps + np.where(got, h_dist.astype(np.float64), np.inf)
        h_normal = h_n.astype(np.float64)
        with np.errstate(invalid="ignore"):
            front = got & (np.einsum("ij,ij->i", h_normal, d_w[idx]) < 0)
        front &= ~((h_body == first_body[idx]) & (tt <= gap_end[idx]))
        hidden_r[idx[front]] = tt[front]
        hidden_n[idx[front]] = h_normal[front]
        keep = got & ~front  # met a back face (or the first hit again): on to the next surface
        idx, t = idx[keep], tt[keep]
    sel = np.isfinite(hidden_r)
    if not sel.any():
        return np.zeros((spec.n_bins, spec.n_beams), bool)
    r = hidden_r[sel]
    nd = np.abs(np.einsum("ij,ij->i", hidden_n[sel], d_w[sel]))
    ndd = np.abs(np.einsum("ij,ij->i", hidden_n[sel], dd_w[sel]))
    half = 0.5 * spec.elevation_step * r * ndd / np.maximum(nd, _MIN_COS_FOOTPRINT)
    half = np.maximum(half, 0.5 * spec.bin_width * 1e-3)
    beam = _index_grids(spec)[0][sel]
    if use_numba():
        ones = np.ones_like(r)
        hidden = _box_image_numba(spec, beam, r - half, r + half, ones)
    else:
        lo = (r - half - spec.range_min) / spec.bin_width
        hi = (r + half - spec.range_min) / spec.bin_width
        hidden = _box_integrate(beam, lo, hi, np.ones_like(r), spec.n_beams, spec.n_bins).T
    return (hidden > 1e-9) & np.isnan(elevation_min)


def _shadow_mask_numba(scene, caster, spec, pose, rays: SonarRays, elevation_min: np.ndarray, *,
                       direct: bool = True) -> np.ndarray:
    """:func:`_shadow_mask` with the continuation rays' bookkeeping in kernels: only the rays that
    continue are touched (no per-grid-ray arrays of directions or normals); one direct cast per ray
    where ``direct`` and the caster's :meth:`~RayCaster.front_hits` allow, else casts in rounds."""
    kn = kernels()
    first_body = np.ascontiguousarray(rays.body).reshape(-1)
    # nothing lies below a floor plane: a ray going down through it hits nothing more
    floors = _floor_planes(scene)
    is_floor = np.zeros(int(first_body.max(initial=-1)) + 1, bool)
    is_floor[[f for f in floors if f < is_floor.size]] = True
    R = pose.R
    a_dir = np.sin(spec.azimuths)[:, None] * R[:, 0] + np.cos(spec.azimuths)[:, None] * R[:, 1]  # (J, 3)
    cp, sp, rz = np.cos(spec.elevations), np.sin(spec.elevations), np.ascontiguousarray(R[:, 2])
    # the continuing rays' bookkeeping is scratch of this call: per-thread arrays as long as the grid,
    # reused (fresh ones fault on every frame); only the mask it returns is fresh
    N = first_body.size
    ws = lambda name, shape=(N,), dtype=np.float64: _workspace(f"shadow_{name}", shape, dtype)  # noqa: E731
    active, t = ws("active", dtype=np.int64), ws("t")
    n = kn.shadow_active(first_body, is_floor, cp, sp, a_dir, rz, np.ascontiguousarray(rays.range, float).reshape(-1),
                         active, t)
    if n == 0:
        return np.zeros((spec.n_bins, spec.n_beams), bool)
    active, t = active[:n], t[:n]
    d_act, dd_act = ws("d", (N, 3))[:n], ws("dd", (N, 3))[:n]
    body_act = first_body[active]
    hid_r = ws("hidden_r")[:n]
    hid_r.fill(np.inf)
    hid_n = ws("hidden_n", (N, 3))[:n]
    hid_n.fill(0.0)
    eps = 1e-4 * max(spec.bin_width, 1e-3)
    origin = np.asarray(pose.t, float)
    far = min(np.float32(spec.range_max * 1.5), np.float32(1e30))
    front = caster.front_hits() if direct else None

    lo, hi = ws("lo")[:n], ws("hi")[:n]
    min_half = 0.5 * spec.bin_width * 1e-3
    # one cell mask per part (split_run makes at most `threads` parts); each part takes the next one
    threads = max(1, caster.threads)  # read once: the parts are sized for it
    parts = ws("parts", (threads, spec.n_bins, spec.n_beams), np.bool_)
    part_no = itertools.count()

    def follow(p0, p1):
        # the rays p0..p1 through every round on this thread (each ray's rounds depend on it alone,
        # so the threads need not meet between rounds), then their hidden surfaces' footprints;
        # they write disjoint rows of d_act, dd_act, hid_r, hid_n, lo, hi
        kn.grid_directions(active[p0:p1], cp, sp, a_dir, rz, d_act[p0:p1], dd_act[p0:p1])
        if front is not None:  # one cast per ray: Embree skips the back faces
            kn.shadow_front(front.fn, front.scene, front.args, t, eps, origin, d_act, far, body_act, p0, p1, hid_r,
                            hid_n)
        else:
            m = p1 - p0
            pos, tt = np.arange(p0, p1, dtype=np.int64), t[p0:p1].copy()
            gap_end = ws("gap_end")[:n]
            kn.shadow_gap_ends(t, eps, origin, d_act, p0, p1, gap_end)
            o32, d32 = np.empty((m, 3), np.float32), np.empty((m, 3), np.float32)
            for _ in range(6):  # each back face met costs a round: a few are enough for closed shapes
                if m == 0:
                    break
                kn.shadow_origins(pos, tt, m, eps, origin, d_act, o32, d32)
                tfar, geom, _, _, _, ng = caster.intersect_raw(o32[:m], d32[:m], np.full(m, far, np.float32),
                                                               normals=True, split=False)
                m = kn.shadow_step(pos, tt, m, eps, geom, tfar, ng, body_act, gap_end, d_act, hid_r, hid_n)
        kn.shadow_boxes(hid_r[p0:p1], hid_n[p0:p1], d_act[p0:p1], dd_act[p0:p1], spec.elevation_step, min_half,
                        lo[p0:p1], hi[p0:p1])
        sel = np.isfinite(hid_r[p0:p1])
        out = parts[next(part_no)]  # a part's shadow cells; the union of the parts' is the mask
        out.fill(False)
        if sel.any():
            kn.shadow_cells(beam_of[active[p0:p1][sel]], lo[p0:p1][sel], hi[p0:p1][sel], float(spec.range_min),
                            1.0 / spec.bin_width, spec.n_bins, elevation_min, out)

    beam_of = _index_grids(spec)[0]
    elevation_min = np.ascontiguousarray(elevation_min)
    if front is not None:
        # one cast per ray: the rays in chunks that the threads take as they finish (fixed halves waited
        # for the slower core), then the shadow cells in one part per thread
        def cast(p0, p1):
            kn.grid_directions(active[p0:p1], cp, sp, a_dir, rz, d_act[p0:p1], dd_act[p0:p1])
            kn.shadow_front(front.fn, front.scene, front.args, t, eps, origin, d_act, far, body_act, p0, p1, hid_r,
                            hid_n)
            kn.shadow_boxes(hid_r[p0:p1], hid_n[p0:p1], d_act[p0:p1], dd_act[p0:p1], spec.elevation_step, min_half,
                            lo[p0:p1], hi[p0:p1])

        def cells(p0, p1):
            sel = np.isfinite(hid_r[p0:p1])
            out = parts[next(part_no)]
            out.fill(False)
            if sel.any():
                kn.shadow_cells(beam_of[active[p0:p1][sel]], lo[p0:p1][sel], hi[p0:p1][sel], float(spec.range_min),
                                1.0 / spec.bin_width, spec.n_bins, elevation_min, out)

        chunked_run(cast, n, threads)
        split_run(cells, n, threads)
    else:
        split_run(follow, n, threads)
    used = next(part_no)
    # the mask is the frame's: a fresh array, never the scratch
    return parts[0].copy() if used == 1 else np.logical_or.reduce(parts[:used], axis=0)


def _read_only_shares(out: np.ndarray, names: list) -> dict:
    """``{name: out[m]}`` for each named slot (``None`` names skipped), each view made read-only."""
    shares = {}
    for m, name in enumerate(names):
        if name is not None:
            sh = out[m]
            sh.setflags(write=False)
            shares[name] = sh
    return shares
