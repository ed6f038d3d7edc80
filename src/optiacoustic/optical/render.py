"""The underwater camera: Jaffe-McGlamery image formation (thesis sec. 3.2.3-3.3).

``E_T = E_D + E_fs + E_bs`` (eq. 3.7), each term derived in docs/derivations.md (ch. 3):

* direct (eq. 3.8): a Lambertian surface of albedo ``rho`` lit by point lights of radiant
  intensity ``I`` (W/sr) has radiance ``rho / pi * sum_l I s cos(gamma) e^{-c R_s} / R_s^2``
  (shadowed lights removed by shadow rays); it reaches the camera times ``e^{-c R_c}``;
* forward scatter (eqs. 3.9, 3.12): light scattered by small angles keeps travelling
  nearly along its path, so over a path ``L`` a share ``e^{-G L}`` (``G <= c``) of it
  survives of which ``e^{-c L}`` is unscattered. On the lamp leg the surplus lights the
  surface (smooth, left unblurred); on the camera leg ``e^{-G R_c} - e^{-c R_c}`` of the
  surface's light arrives blurred by a Gaussian whose angular width grows with range,
  ``sigma = B R_c / (pi sqrt(2 ln 2))`` (Jaffe 1990's ``e^{-B R f}`` MTF matched where it
  is 1/2). The blur runs with ``cv2.GaussianBlur`` over a few range layers and preserves
  the sum of what it blurs (energy) up to the image border;
* backscatter (eqs. 3.10-3.13): the single-scattering integral along each pixel's ray
  ``L_bs = int_0^R beta(psi) I s e^{-G R_bs} / R_bs^2 e^{-c r} dr``, evaluated on N planes
  parallel to the image plane (the thesis's slices). A ray crosses a slab of thickness
  ``dz`` over a length ``dz / cos(theta)``, hence the thesis's ``1 / cos(theta)``; the
  attenuation to the camera is over the *range* ``r = z / cos(theta)``, not the slice
  depth ``z`` the thesis writes. The volume integral is computed for every slice on a
  coarse grid of ray directions (it is smooth across the image) and interpolated with
  ``cv2.remap``; each pixel then stops at its own surface depth, so object edges stay
  sharp.
"""

from __future__ import annotations

import functools
import time
from dataclasses import dataclass

import numpy as np

from .._scratch import Workspace
from .._validate import as_array, as_rng, check_memory, is_integer, is_number
from ._sanity import warn_if_blind
from ..camera import PinholeCamera
from ..frames import Pose
from ..scene import Scene
from .frame import OpticalFrame
from .lights import MIN_LAMP_DISTANCE, resolve_lights
from .texture import apply_textures, body_colors, surface_albedo
from .water import Water, as_water

__all__ = ["OpticalOptions", "SensorNoise", "simulate_optical", "forward_scatter", "backscatter",
           "forward_scatter_G", "slice_depths"]

#: Gaussian sigma per unit of Jaffe's B R: matches exp(-B R f) at half power.
_SIGMA_PER_BR = 1.0 / (np.pi * np.sqrt(2 * np.log(2)))


@dataclass(frozen=True)
class SensorNoise:
    """Photon shot noise and read noise of the camera sensor.

    The noise-free image's :func:`~optiacoustic.optical.frame.auto_exposure` is taken as
    the full well: a pixel of radiance ``L`` collects ``n = full_well * L / exposure``
    electrons, with variance ``n + read_noise^2`` (a Gaussian approximation of Poisson
    plus read noise), and the result is converted back to radiance.
    """

    full_well: float = 10000.0
    read_noise: float = 5.0

    def __post_init__(self):
        for name in ("full_well", "read_noise"):
            v = getattr(self, name)
            if not (isinstance(v, (int, float, np.floating)) and np.isfinite(v) and v >= 0):
                raise ValueError(f"SensorNoise.{name}: must be finite and >= 0, got {v!r}")
        if self.full_well <= 0:
            raise ValueError("SensorNoise.full_well: must be > 0")

    def apply(self, image: np.ndarray, rng: np.random.Generator) -> np.ndarray:
        from .frame import auto_exposure

        e = auto_exposure(image)
        k = np.float32(self.full_well / e)
        n = image * k
        sd = np.sqrt(np.maximum(n, 0) + np.float32(self.read_noise ** 2))
        noisy = n + sd * rng.standard_normal(image.shape, dtype=np.float32)
        return np.maximum(noisy, 0) / k


@dataclass(frozen=True)
class OpticalOptions:
    """How the underwater image is formed. Defaults: the thesis's model.

    Attributes
    ----------
    slices : int
        Backscatter slices N (planes parallel to the image plane), default 32.
    backscatter_step : int
        Spacing (px) of the coarse grid of ray directions on which the volume integral is
        evaluated, default 16 (thesis scene: 1e-4 from the per-pixel result); 1 evaluates
        it for every pixel (slow, for validation). Use a finer grid for narrow spot lights
        whose beams cross the view.
    slice_scale : float, optional
        Scale ``s`` (m) of the slice spacing ``z = s u / (1 - u)`` (u uniform in [0, 1),
        so the slices reach to infinity). Default: the median distance of the lights from
        the camera, clipped to [0.2, 5] m: the backscatter integrand varies on that scale.
    forward_scatter : bool
        Add the forward-scattered light (eq. 3.9, 3.12). ``False`` sets ``G = c``.
    G : float or (3,), optional
        Jaffe's G (m^-1): light that travels ``L`` keeps ``e^{-G L}`` within the blur
        kernel. Default ``G = c - b F(fs_cone_deg)``, with ``F`` the water's share of
        scattering at angles below ``fs_cone_deg`` (light deflected by less stays near
        its line of sight). Must satisfy ``0 <= G <= c``.
    B : float
        Jaffe's B (rad/m): angular blur ``sigma = B R / (pi sqrt(2 ln 2))``. Default 0.03,
        our choice (Jaffe and the thesis leave B empirical): sigma = 1.4 deg (20 px of the
        thesis camera) at 3 m, 2.8 deg at 6 m, the order of the small-angle deflections of
        the Kopelevich particle phase functions.
    fs_cone_deg : float
        Forward-scatter cone for the default G (deg), default 10.
    fs_layers : int
        Range layers of the forward-scatter blur (a pixel's light is shared linearly in
        log-range between its two nearest layers), default 6.
    shadows : bool
        Cast shadow rays to the lights (default True).
    noise : SensorNoise, False or None
        Sensor noise on ``.image``: ``None`` applies ``SensorNoise()`` when a ``seed`` is
        given and nothing otherwise; ``False`` never.
    """

    slices: int = 32
    backscatter_step: int = 16
    slice_scale: float | None = None
    forward_scatter: bool = True
    G: float | tuple | None = None
    B: float = 0.03
    fs_cone_deg: float = 10.0
    fs_layers: int = 6
    shadows: bool = True
    noise: SensorNoise | bool | None = None

    def __post_init__(self):
        def bad(name, msg):
            raise ValueError(f"OpticalOptions.{name}: {msg}, got {getattr(self, name)!r}")

        integer = is_integer  # bools are not counts (slices=True was 1 slice)

        def number(v):
            return is_number(v) and bool(np.isfinite(v))

        if not integer(self.slices) or not 1 <= self.slices <= 4096:
            bad("slices", "expected an integer in [1, 4096]")
        if not integer(self.backscatter_step) or not 1 <= self.backscatter_step <= 64:
            bad("backscatter_step", "expected an integer in [1, 64]")
        if self.slice_scale is not None and not (number(self.slice_scale) and self.slice_scale > 0):
            bad("slice_scale", "expected a finite scale > 0 (m) or None")
        if not (number(self.B) and self.B >= 0):
            bad("B", "expected a finite value >= 0 (rad/m)")
        if not (number(self.fs_cone_deg) and 0 <= self.fs_cone_deg <= 180):
            bad("fs_cone_deg", "expected an angle in [0, 180] deg")
        if not integer(self.fs_layers) or not 1 <= self.fs_layers <= 64:
            bad("fs_layers", "expected an integer in [1, 64]")
        for name in ("forward_scatter", "shadows"):  # "no" was a true value
            if not isinstance(getattr(self, name), (bool, np.bool_)):
                bad(name, "expected True or False")
        if self.G is not None:
            g = np.asarray(self.G, object).reshape(-1)
            if (g.size not in (1, 3) or not all(number(x) for x in g)
                    or np.any(np.asarray(g, float) < 0)):
                bad("G", "expected a number or 3 numbers >= 0 (m^-1)")
        if self.noise not in (None, False) and not isinstance(self.noise, SensorNoise):
            bad("noise", "expected a SensorNoise, False or None")


# --------------------------------------------------------------------------- helpers
@functools.lru_cache(maxsize=8)
def _pixel_rays(camera: PinholeCamera) -> np.ndarray:
    d = camera.pixel_rays().astype(np.float64)
    bad = ~np.isfinite(d[..., 0])
    if np.any(bad):  # NaN: pixels the lens model cannot produce (PinholeCamera.normalized)
        v, u = (int(i) for i in np.argwhere(bad)[0])
        raise ValueError(f"PinholeCamera.dist: the distortion {list(camera.dist)} cannot produce {int(bad.sum())} of "
                         f"the image's {bad.size} pixels (e.g. pixel ({u}, {v})): it turns back inside the image, so "
                         "those pixels have no viewing ray; the renderer needs one for every pixel")
    d.setflags(write=False)
    return d


#: per-thread scratch of this simulator's frames (see :mod:`optiacoustic._scratch`)
_workspace = Workspace()


@functools.lru_cache(maxsize=8)
def _pixel_rays32(camera: PinholeCamera) -> np.ndarray:
    """The unit pixel rays (camera frame) as float32 ``(H*W, 3)``."""
    d = np.ascontiguousarray(_pixel_rays(camera).reshape(-1, 3), np.float32)
    d.setflags(write=False)
    return d


@functools.lru_cache(maxsize=8)
def _coarse_rays(camera: PinholeCamera, step: int) -> np.ndarray:
    """Unit rays (camera frame) through a grid of about ``step``-px spacing spanning the image
    corner to corner, so that interpolating between its nodes never extrapolates."""
    wc = int(np.ceil((camera.width - 1) / step)) + 1
    hc = int(np.ceil((camera.height - 1) / step)) + 1
    grid = np.stack(np.meshgrid(np.linspace(0, camera.width - 1, wc), np.linspace(0, camera.height - 1, hc)), -1)
    d = camera.pixel_rays(grid)
    d.setflags(write=False)
    return d


@functools.lru_cache(maxsize=64)
def _fs_fraction(phase, cone_deg: float) -> np.ndarray:
    return phase.fraction_within(np.deg2rad(cone_deg))


def forward_scatter_G(water: Water, options: OpticalOptions) -> np.ndarray:
    """Jaffe's G per channel ``(3,)`` (m^-1) for ``water`` under ``options``."""
    c = water.c
    if not options.forward_scatter:
        return c.copy()
    if options.G is not None:
        g = np.broadcast_to(np.asarray(options.G, float).reshape(-1), (3,)).copy()
        if np.any(g > c + 1e-12):
            raise ValueError(f"OpticalOptions.G: must not exceed the attenuation c = {np.round(c, 6).tolist()} "
                             f"(forward scatter cannot return more light than attenuation removed), got {g.tolist()}")
        return g
    return c - np.asarray(water.b) * _fs_fraction(water.phase, float(options.fs_cone_deg))


def slice_depths(n: int, scale: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Slice planes for the backscatter sum.

    ``z(u) = s u / (1 - u)`` maps ``u`` in [0, 1) onto all depths; the slices are N equal
    steps in ``u`` sampled at their midpoints (the midpoint rule in ``u``).

    Returns
    -------
    z : (N,) depth of each slice's plane along the optical axis (m).
    dz : (N,) its effective thickness ``z'(u) / N`` (m).
    u_edges : (N + 1,) the slice boundaries in ``u``.
    """
    u = (np.arange(n) + 0.5) / n
    z = scale * u / (1 - u)
    dz = scale / (1 - u) ** 2 / n
    return z, dz, np.arange(n + 1) / n


def _cumulative_backscatter(dirs_cam: np.ndarray, water: Water, lights_cam, G: np.ndarray, n: int, scale: float) -> np.ndarray:
    """Backscatter accumulated from the camera to each slice boundary.

    Parameters
    ----------
    dirs_cam : (h, w, 3) unit ray directions, camera frame.
    lights_cam : list of (position (3,), intensity (3,), axis (3,) or None, exponent) in the camera frame.

    Returns
    -------
    (N + 1, h, w, 3) float32: entry k is the radiance scattered towards the camera by the
    water between the camera and slice boundary k (W m^-2 sr^-1).
    """
    z, dz, _ = slice_depths(n, scale)
    cz = np.maximum(dirs_cam[..., 2], 1e-6)  # cos(theta) of each ray
    r = z[:, None, None] / cz[None]          # (N, h, w) range to each slice along the ray
    pts = r[..., None] * dirs_cam[None]      # (N, h, w, 3) sample points, camera frame
    c = water.c
    acc = np.zeros(r.shape + (3,))
    for pos, inten, axis, expo in lights_cam:
        v = pts - pos
        R = np.maximum(np.sqrt(np.einsum("...i,...i->...", v, v)), 1e-6)
        # cos(psi): light travels along v / R, the camera receives it along -d
        cos_psi = -np.einsum("...i,...i->...", v, dirs_cam[None]) / R
        irr = np.exp(-R[..., None] * G) * (inten / (R * R)[..., None])
        if axis is not None:
            ca = np.einsum("...i,i->...", v, axis) / R
            irr *= np.where(ca > 0, np.maximum(ca, 0) ** expo, 0.0)[..., None]
        acc += water.vsf(cos_psi) * irr
    # transmit to the camera over the range, and the path length through each slab
    acc *= np.exp(-r[..., None] * c) * (dz[:, None, None] / cz[None])[..., None]
    out = np.empty((n + 1,) + acc.shape[1:], np.float32)
    out[0] = 0.0
    np.cumsum(acc, axis=0, out=acc)
    out[1:] = acc
    return out


def _lights_key(lights_cam) -> tuple:
    """A hashable, exact copy of the camera-frame lights."""
    return tuple((tuple(np.asarray(p, float)), tuple(np.asarray(i, float)),
                  None if a is None else tuple(np.asarray(a, float)), float(e)) for p, i, a, e in lights_cam)


@functools.lru_cache(maxsize=16)
def _coarse_table(camera: PinholeCamera, step: int, water: Water, lights_key: tuple, G: tuple, n: int,
                  s: float) -> np.ndarray:
    """:func:`_cumulative_backscatter` on the coarse grid, kept for the next frame.

    It depends on the lights only through their camera-frame positions, so lamps carried by
    the camera (the default) give every frame of a trajectory the same table.
    """
    lights_cam = [(np.array(p), np.array(i), None if a is None else np.array(a), e) for p, i, a, e in lights_key]
    table = _cumulative_backscatter(_coarse_rays(camera, step), water, lights_cam, np.array(G), n, s)
    table.setflags(write=False)
    return table


@functools.lru_cache(maxsize=8)
def _pixel_cz(camera: PinholeCamera) -> np.ndarray:
    """Cosine of each pixel ray to the optical axis, ``(H*W,)`` float64."""
    cz = np.ascontiguousarray(_pixel_rays(camera)[..., 2].reshape(-1))
    cz.setflags(write=False)
    return cz


def _check_lamp_distances(lights, pose: Pose) -> None:
    """Refuse a lamp nearer the camera centre than :data:`~optiacoustic.optical.lights.MIN_LAMP_DISTANCE`
    (for scattering water: the single-scattering veil grows as 1 / distance and is infinite at 0; a lamp at
    the camera centre gave a veil that grew with the number of slices without converging)."""
    for i, lt in enumerate(lights):
        dist = float(np.linalg.norm(np.asarray(lt.position) - pose.t))
        if dist < MIN_LAMP_DISTANCE:
            raise ValueError(f"lights[{i}]: the lamp is {dist:.3g} m from the camera centre; in scattering water "
                             f"it must be at least MIN_LAMP_DISTANCE = {MIN_LAMP_DISTANCE} m away (the veil grows "
                             "as 1 / distance and is infinite at 0; a real lamp sits outside the camera housing)")


def backscatter(camera: PinholeCamera, pose: Pose, depth: np.ndarray, water: Water, lights, *,
                options: OpticalOptions | None = None, G=None) -> np.ndarray:
    """The veiling light (eqs. 3.10-3.13, corrected) of every pixel.

    Parameters
    ----------
    camera : PinholeCamera
    pose : Pose
        Camera pose in the world (camera axes).
    depth : (H, W)
        Range along each pixel's ray to its surface (m); ``inf`` for open water.
    water : Water
    lights : sequence of Light (world frame, see :func:`resolve_lights`)
    options : OpticalOptions
    G : (3,), optional
        Forward-scatter coefficient of the lamp-to-volume leg; default from ``options``.

    Returns
    -------
    (H, W, 3) float32 radiance (W m^-2 sr^-1).
    """
    import cv2

    options = options or OpticalOptions()
    H, W = camera.height, camera.width
    kernels = _use_kernels() and options.backscatter_step > 1
    if kernels and isinstance(depth, np.ndarray) and depth.shape == (H, W) and depth.dtype in (np.float32, np.float64):
        depth = np.ascontiguousarray(depth)  # validated by the kernel below
    else:
        kernels = False
        depth = as_array(depth, "depth", (H, W), finite=False)
        if np.any(np.isnan(depth)) or np.any(depth < 0):
            raise ValueError("depth: must be >= 0 or inf")
    if G is None:
        G = forward_scatter_G(water, options)
    if not np.any(np.asarray(water.b) > 0) or not lights:
        if kernels and not np.all(depth >= 0):
            raise ValueError("depth: must be >= 0 or inf")
        return np.zeros((H, W, 3), np.float32)
    _check_lamp_distances(lights, pose)
    lights_cam = []
    for lt in lights:
        p = pose.to_body(lt.position)
        ax = None if (lt.direction is None or lt.cone_deg is None) else np.asarray(lt.direction) @ pose.R
        lights_cam.append((p, np.asarray(lt.intensity), ax, lt.spot_exponent))
    s = options.slice_scale
    if s is None:
        dist = np.array([np.linalg.norm(p) for p, *_ in lights_cam])
        s = float(np.clip(np.median(dist), 0.2, 5.0))
    n = options.slices
    step = options.backscatter_step
    full_dirs = _pixel_rays(camera)
    if step == 1:
        table = _cumulative_backscatter(full_dirs, water, lights_cam, G, n, s)
    else:
        table = _coarse_table(camera, step, water, _lights_key(lights_cam), tuple(np.asarray(G, float)), n, s)
    if kernels:
        from ._kernels import veil

        out = np.empty((H * W, 3), np.float32)
        if veil(table, depth.reshape(-1), _pixel_cz(camera), float(s), W, out):
            raise ValueError("depth: must be >= 0 or inf")
        return out.reshape(H, W, 3)
    # each pixel stops at its own surface: fractional slice index of its depth in u
    cz = full_dirs[..., 2]
    zD = depth * cz
    with np.errstate(invalid="ignore", over="ignore"):
        u = np.where(np.isfinite(zD), zD / (s + zD), 1.0)
    q = u * n
    k0 = np.minimum(np.floor(q), n - 1)
    frac = (q - k0).astype(np.float32)[..., None]
    if step == 1:
        k0i = k0.astype(np.int64)
        rows, cols = np.indices((H, W))
        lo = table[k0i, rows, cols]
        hi = table[k0i + 1, rows, cols]
        return lo + frac * (hi - lo)
    # tile the N + 1 coarse tables side by side (one replicated column each side, so the
    # bilinear interpolation never mixes two slices) and sample with cv2.remap
    hc, wc = table.shape[1:3]
    padded = np.concatenate([table[:, :, :1], table, table[:, :, -1:]], axis=2)  # (N+1, hc, wc+2, 3)
    tiled = np.ascontiguousarray(padded.transpose(1, 0, 2, 3).reshape(hc, (n + 1) * (wc + 2), 3))
    xs = (np.arange(W, dtype=np.float64) * (wc - 1) / max(W - 1, 1))[None, :]
    ys = np.arange(H, dtype=np.float64) * (hc - 1) / max(H - 1, 1)
    map_y = np.ascontiguousarray(np.broadcast_to(ys[:, None], (H, W)), np.float32)
    map_x = (k0 * (wc + 2) + 1 + xs).astype(np.float32)
    lo = cv2.remap(tiled, map_x, map_y, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
    hi = cv2.remap(tiled, map_x + np.float32(wc + 2), map_y, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
    return lo + frac * (hi - lo)


def forward_scatter(source: np.ndarray, depth: np.ndarray, camera: PinholeCamera, *, B: float = 0.03,
                    layers: int = 6, threads: int = 1) -> np.ndarray:
    """Blur ``source`` with a Gaussian whose angular width grows with range (eq. 3.9).

    Parameters
    ----------
    source : (H, W, 3)
        Light to redistribute (already weighted by ``e^{-G R} - e^{-c R}``); zero where
        there is no surface.
    depth : (H, W)
        Range of each pixel's surface (m); ``inf`` where there is none.
    camera : PinholeCamera
        Gives the pixels per radian ``sqrt(fx fy)``.
    B : float
        Jaffe's B (rad/m): ``sigma = B R / (pi sqrt(2 ln 2))`` rad.
    layers : int
        Number of range layers, geometrically spaced between the nearest and the farthest
        surface; a pixel's light is shared between its two nearest layers, linearly in
        log-range, so the weights sum to 1 and no light is lost or created.
    threads : int
        Threads for the compiled binning (1 or 2).

    Returns
    -------
    (H, W, 3) float32, with the same sum as ``source`` up to what the kernels push over
    the image border.
    """
    import cv2

    src = np.asarray(source, np.float32)
    if src.ndim != 3 or src.shape[2] != 3:
        raise ValueError(f"source: expected shape (H, W, 3), got {src.shape}")
    H, W = src.shape[:2]
    if np.shape(depth) != (H, W):
        raise ValueError(f"depth: expected shape {(H, W)} (the source's), got {np.shape(depth)}")
    kernels = _use_kernels()
    if kernels:
        from . import _kernels as K

        flat = np.ascontiguousarray(src.reshape(-1, 3))
        d = np.ascontiguousarray(depth, np.float64).reshape(-1)
        r_lo, r_hi, n_hit = K.range_span(flat, d)
        if n_hit == 0 or B <= 0:
            return src.copy()
    else:
        d = np.asarray(depth, float)
        hit = np.isfinite(d) & np.any(src > 0, axis=-1)
        if not np.any(hit) or B <= 0:
            return src.copy()
        r_lo, r_hi = float(d[hit].min()), float(d[hit].max())
    px_per_rad = float(np.sqrt(camera.fx * camera.fy))
    if r_hi <= r_lo * 1.0001 or layers == 1:
        ranges = np.array([np.sqrt(r_lo * r_hi)])
    else:
        ranges = np.geomspace(r_lo, r_hi, layers)
    n_layers = len(ranges)
    sigmas = B * ranges * _SIGMA_PER_BR * px_per_rad
    # one reduced grid for all layers, as coarse as the narrowest kernel allows
    # (a reduction beyond the image's side is one cell either way: capped, or a long lens's
    # kernels of millions of px made cv2.resize allocate q^2 px, 1e16 bytes at 1e9 mm)
    q = min(max(1, int(np.floor(sigmas.min() / 2.0))), max(H, W))
    h, w = -(-H // q), -(-W // q)
    # box sums of each layer's share of the light, all layers at once: a pixel gives
    # (1 - f) of its light to layer k and f to layer k + 1
    per_layer = (layers - 1) / np.log(r_hi / r_lo) if n_layers > 1 else 0.0
    if kernels:
        # two halves of the image on two threads, each into its own accumulator
        accs = _halves(threads, H * W, lambda a, b: _bin_rows(K, flat, d, W, q, w, r_lo, per_layer, n_layers, a, b))
        small = (accs[0] if len(accs) == 1 else accs[0] + accs[1]).astype(np.float32)
    else:
        if n_layers == 1:
            k = np.zeros(H * W, np.int64)
            f = np.zeros(H * W, np.float32)
        else:
            with np.errstate(divide="ignore", invalid="ignore"):
                t = np.log(np.where(hit, d, r_lo) / r_lo).ravel() * per_layer
            k = np.clip(np.floor(t), 0, layers - 2).astype(np.int64)
            f = (t - k).astype(np.float32)
        cell = ((np.arange(H) // q)[:, None] * w + (np.arange(W) // q)[None, :]).ravel()
        flat = src.reshape(-1, 3)
        key_lo = k * (h * w) + cell
        key_hi = key_lo + h * w
        size = n_layers * h * w
        small = np.empty((n_layers, h, w, 3), np.float32)
        for ch in range(3):
            v = flat[:, ch]
            acc = np.bincount(key_lo, v * (1 - f), size)
            if n_layers > 1:
                acc += np.bincount(key_hi, v * f, size)
            small[..., ch] = acc.reshape(n_layers, h, w)
    # the q x q box sum adds (q^2 - 1)/12 px^2 of variance per axis and the bilinear
    # upsampling about q^2/6: both are taken out of each layer's Gaussian
    extra = (q * q - 1) / 12.0 + (q * q / 6.0 if q > 1 else 0.0)
    out = np.zeros((h, w, 3), np.float32)
    for j in range(n_layers):
        if np.any(small[j] > 0):
            out += _gaussian(small[j], np.sqrt(max(sigmas[j] ** 2 - extra, 0.0)) / q)
    if q == 1:
        return out
    big = cv2.resize(out, (w * q, h * q), interpolation=cv2.INTER_LINEAR) * np.float32(1.0 / (q * q))
    return np.ascontiguousarray(big[:H, :W])


def _bin_rows(K, flat, d, W, q, w, r_lo, per_layer, n_layers, a, b):
    """:func:`._kernels.bin_layers` over pixels ``[a, b)`` (cut on a row of reduced cells) into a new accumulator."""
    H = len(d) // W
    acc = np.zeros((n_layers, -(-H // q), w, 3))
    # whole rows of cells per half: the kernel indexes rows from the start of what it is given
    r0 = (a // W) // q * q
    r1 = H if b == len(d) else (b // W) // q * q
    K.bin_layers(flat[r0 * W:r1 * W], d[r0 * W:r1 * W], W, q, w, r_lo, per_layer, n_layers, acc[:, r0 // q:])
    return acc


def _gaussian(img: np.ndarray, sigma: float) -> np.ndarray:
    """Sum-preserving Gaussian blur of ``sigma`` pixels (zero outside the image).

    Up to 4 px with ``cv2.GaussianBlur`` directly; wider on a grid reduced by box sums,
    whose added variance is taken out of the Gaussian, then upsampled bilinearly.
    """
    import cv2

    if sigma < 0.3:
        return img.copy()
    if sigma <= 4.0:
        return cv2.GaussianBlur(img, (0, 0), sigma, borderType=cv2.BORDER_CONSTANT)
    H, W = img.shape[:2]
    q = min(int(np.floor(sigma / 2.0)), max(H, W))  # beyond the image's side: one cell either way
    h, w = -(-H // q), -(-W // q)
    pad = np.zeros((h * q, w * q, 3), np.float32)
    pad[:H, :W] = img
    small = cv2.resize(pad, (w, h), interpolation=cv2.INTER_AREA) * np.float32(q * q)
    s_small = np.sqrt(max(sigma * sigma - (q * q - 1) / 12.0 - q * q / 6.0, 0.0)) / q
    small = cv2.GaussianBlur(small, (0, 0), max(s_small, 0.3), borderType=cv2.BORDER_CONSTANT)
    big = cv2.resize(small, (w * q, h * q), interpolation=cv2.INTER_LINEAR) * np.float32(1.0 / (q * q))
    return big[:H, :W]


# --------------------------------------------------------------------------- geometry checks
@functools.lru_cache(maxsize=1)
def _side_pool():
    """One worker thread for the backscatter veil, computed while the main thread shades."""
    from concurrent.futures import ThreadPoolExecutor

    return ThreadPoolExecutor(max_workers=1, thread_name_prefix="oas-veil")


class _inline:
    """A finished 'future': runs the call now (single-threaded casters)."""

    def __init__(self, fn, *args, **kw):
        self._value = fn(*args, **kw)

    def result(self):
        return self._value


def _direct_light(caster, p, nrm, rho_pi, lights, c, G, shadows: bool):
    """Radiance leaving lit Lambertian surface points (eq. 3.8), per pixel ``(n, 3)``.

    Parameters: surface points ``p`` and camera-facing unit normals ``nrm`` ``(n, 3)``
    (world, m), ``rho_pi = albedo / pi`` ``(n, 3)``, world-frame lights, ``c`` and ``G``
    ``(3,)`` (m^-1). Returns ``(clear, surf, surf_fwd)``: without water, through water
    with the narrow-beam ``e^{-c R_s}`` on the lamp leg, and with the forward-scattered
    lamp light ``e^{-G R_s}`` (McGlamery's ``E_I,fs``; the same array as ``surf`` when
    ``G = c``).
    """
    n = len(p)
    irr_clear = np.zeros((n, 3), np.float32)
    irr_water = np.zeros((n, 3), np.float32)
    irr_fwd = np.zeros((n, 3), np.float32)
    c32 = c.astype(np.float32)
    G32 = G.astype(np.float32)
    lamp_fs = bool(np.any(G32 < c32))
    eps = np.float32(1e-3)  # shadow rays start 1 mm off the surface
    for lt in lights:
        v = np.asarray(lt.position, np.float32) - p
        Rs = np.sqrt(np.einsum("ij,ij->i", v, v))
        ldir = v / np.maximum(Rs, np.float32(1e-12))[:, None]
        cosg = np.einsum("ij,ij->i", nrm, ldir)
        lit = cosg > 0
        if shadows and np.any(lit):
            # every point is cast, lit or not (a gather costs more than the rays it saves);
            # the points facing away get a zero-length ray that Embree rejects at once
            o = p + eps * nrm
            lim = np.where(lit, np.maximum(Rs - 2 * eps, np.float32(1e-6)), np.float32(0))
            lit &= ~caster.occluded_raw(o, np.ascontiguousarray(ldir, np.float32), lim)
        e = np.where(lit, cosg / np.maximum(Rs * Rs, np.float32(1e-12)), np.float32(0))
        if lt.direction is not None and lt.cone_deg is not None:
            ca = -np.einsum("ij,j->i", ldir, np.asarray(lt.direction, np.float32))  # cos from the spot axis
            m = lt.spot_exponent
            e *= np.maximum(ca, 0) if abs(m - 1.0) < 1e-9 else np.where(ca > 0, np.maximum(ca, 0) ** np.float32(m), 0)
        e = e[:, None] * np.asarray(lt.intensity, np.float32)
        irr_clear += e
        irr_water += e * np.exp(-Rs[:, None] * c32)
        if lamp_fs:
            irr_fwd += e * np.exp(-Rs[:, None] * G32)
    surf = rho_pi * irr_water
    return rho_pi * irr_clear, surf, (rho_pi * irr_fwd if lamp_fs else surf)


def _check_not_inside(caster, names, pose: Pose, lights) -> None:
    """ValueError naming the body when the camera or a light sits inside a closed body."""
    inside = caster.enclosing_body(pose.t)
    if inside >= 0:
        raise ValueError(f"pose: the camera at {np.round(pose.t, 3).tolist()} is inside body '{names[inside]}'")
    for i, lt in enumerate(lights):
        inside = caster.enclosing_body(lt.position)
        if inside >= 0:
            raise ValueError(f"lights[{i}]: the light at {np.round(lt.position, 3).tolist()} (world) is inside "
                             f"body '{names[inside]}'")


# --------------------------------------------------------------------------- shading
def _use_kernels() -> bool:
    """Compiled kernels (numba) unless ``OAS_KERNELS=numpy`` asks for the numpy reference path."""
    from .._kernel_switch import use_numba

    return use_numba()


def _shade_numpy(caster, scene, pose, o32, d32, lights, c, G, shadows, H, W, start_veil):
    """The reference shading path (numpy): primary hits, direct light, the unblurred stages.

    Returns ``(depth (H, W) float64 range or inf, body (H*W,) int32, normal (H*W, 3) NaN
    on a miss, clear (H, W, 3), attenuated (H, W, 3), forward-scatter source (H, W, 3) or
    None, forward image before the blur (H, W, 3), veil future)``.
    """
    dist_all, body_all, _, nrm_all = caster.cast_raw(o32, d32)
    hit = body_all >= 0
    warn_if_blind(hit, pose, scene, stacklevel=4)
    full = bool(hit.all())
    sel = slice(None) if full else np.flatnonzero(hit)   # scenes with a seabed hit everywhere
    depth = np.where(hit, dist_all.astype(np.float64), np.inf)
    dist = dist_all[sel]
    dv = d32[sel]
    p = o32[sel] + dv * dist[:, None]
    nrm = nrm_all[sel]
    # shade the side facing the camera (planes are two-sided)
    nrm *= np.where(np.einsum("ij,ij->i", nrm, dv) > 0, np.float32(-1), np.float32(1))[:, None]
    body_all = np.where(hit, body_all, -1).astype(np.int32)
    rho_pi = surface_albedo(scene, body_all[sel], p, nrm) * np.float32(1 / np.pi)
    depth2 = depth.reshape(H, W)
    bs_job = start_veil(depth2)
    clear_v, surf, surf_fwd = _direct_light(caster, p, nrm, rho_pi, lights, c, G, shadows)
    lamp_fs = surf_fwd is not surf
    Rc = dist[:, None]
    t_cam = np.exp(-Rc * c.astype(np.float32))      # narrow-beam transmittance to the camera
    att = surf * t_cam

    def scatter(values):
        if full:
            return values.reshape(H, W, 3)
        img = np.zeros((H * W, 3), np.float32)
        img[sel] = values
        return img.reshape(H, W, 3)

    clear = scatter(clear_v)
    attenuated = scatter(att)
    if lamp_fs:
        w_fs = np.exp(-Rc * G.astype(np.float32)) - t_cam
        src = scatter(surf_fwd * np.maximum(w_fs, 0))
        fwd = scatter((surf_fwd - surf) * t_cam) + attenuated
    else:
        src = None
        fwd = attenuated.copy()
    normal = scatter(nrm) if full else np.full((H * W, 3), np.nan, np.float32)
    if not full:
        normal[sel] = nrm
    return depth2, body_all, normal, clear, attenuated, src, fwd, bs_job


@functools.lru_cache(maxsize=1)
def _kernel_pool():
    """One worker thread that runs the first half of a compiled kernel while the caller runs the second."""
    from concurrent.futures import ThreadPoolExecutor

    return ThreadPoolExecutor(max_workers=1, thread_name_prefix="oas-shade")


def _halves(threads: int, n: int, job) -> list:
    """``job(a, b)`` over ``[0, n)``: in two halves on two threads when ``threads > 1`` (the kernels
    release the GIL), else at once. Returns the results."""
    if threads <= 1 or n < 20000:
        return [job(0, n)]
    m = n // 2
    first = _kernel_pool().submit(job, 0, m)
    second = job(m, n)
    return [first.result(), second]


def _shade_compiled(caster, scene, pose, o32, d32, lights, c, G, shadows, H, W, start_veil):
    """:func:`_shade_numpy` with the per-pixel work in compiled kernels (:mod:`._kernels`)."""
    from . import _kernels as K

    f32 = np.float32
    n = len(d32)
    tfar, geom, prim, u, v, _ = caster.intersect_raw(o32, d32, normals=False)
    p = np.empty((n, 3), f32)
    nrm = np.empty((n, 3), f32)
    depth = np.empty(n, f32)
    body = np.empty(n, np.int32)
    rho_pi = np.empty((n, 3), f32)
    inv_pi = f32(1 / np.pi)
    colors_pi = body_colors(scene) * inv_pi
    tri_offsets, corner_normals = caster.triangle_offset, caster.corner_normals
    threads = caster.threads
    hits = sum(_halves(threads, n, lambda a, b: K.surface(
        o32[a:b], d32[a:b], tfar[a:b], geom[a:b], prim[a:b], u[a:b], v[a:b], tri_offsets, corner_normals, colors_pi,
        p[a:b], nrm[a:b], depth[a:b], body[a:b], rho_pi[a:b])))
    if hits == 0:
        warn_if_blind(body >= 0, pose, scene, stacklevel=4)
    depth2 = depth.reshape(H, W)
    bs_job = start_veil(depth2)
    apply_textures(scene, body, p, nrm, rho_pi, inv_pi)
    c32, G32 = c.astype(f32), G.astype(f32)
    lamp_fs = bool(np.any(G32 < c32))
    irr_clear = np.zeros((n, 3), f32)
    irr_water = np.zeros((n, 3), f32)
    irr_fwd = np.zeros((n, 3), f32) if lamp_fs else irr_water
    o_sh, ldir = np.empty((n, 3), f32), np.empty((n, 3), f32)
    lim, cosg, rs = np.empty(n, f32), np.empty(n, f32), np.empty(n, f32)
    no_block = np.zeros(n, bool)
    eps = f32(1e-3)
    for lt in lights:
        pos = np.asarray(lt.position, f32)
        _halves(threads, n, lambda a, b: K.shadow_rays(p[a:b], nrm[a:b], body[a:b], pos, eps, o_sh[a:b], ldir[a:b],
                                                       lim[a:b], cosg[a:b], rs[a:b]))
        blocked = caster.occluded_raw(o_sh, ldir, lim) if shadows and hits else no_block
        spot = 0 if lt.direction is None or lt.cone_deg is None else (1 if abs(lt.spot_exponent - 1.0) < 1e-9 else 2)
        axis = np.zeros(3, f32) if spot == 0 else np.asarray(lt.direction, f32)
        inten, expo = np.asarray(lt.intensity, f32), f32(lt.spot_exponent)
        _halves(threads, n, lambda a, b: K.add_lamp(cosg[a:b], rs[a:b], ldir[a:b], blocked[a:b], inten, axis, expo,
                                                    spot, c32, G32, lamp_fs, irr_clear[a:b], irr_water[a:b],
                                                    irr_fwd[a:b]))
    clear, att = np.empty((n, 3), f32), np.empty((n, 3), f32)
    src, fwd = np.empty((n, 3), f32), np.empty((n, 3), f32)
    _halves(threads, n, lambda a, b: K.compose(rho_pi[a:b], irr_clear[a:b], irr_water[a:b], irr_fwd[a:b], depth[a:b],
                                               c32, G32, lamp_fs, clear[a:b], att[a:b], src[a:b], fwd[a:b]))
    if hits < n:
        nrm[body < 0] = np.nan
    img = lambda a: a.reshape(H, W, 3)  # noqa: E731
    return depth2, body, nrm, img(clear), img(att), (img(src) if lamp_fs else None), img(fwd), bs_job


# --------------------------------------------------------------------------- simulate
def simulate_optical(scene: Scene, camera: PinholeCamera, pose: Pose, *, water=None, lights=None, seed=None,
                     options: OpticalOptions | None = None) -> OpticalFrame:
    """Simulate one underwater camera frame (thesis ch. 3, Jaffe-McGlamery model).

    Parameters
    ----------
    scene : Scene
    camera : PinholeCamera
    pose : Pose
        The camera's pose in the world with camera axes (X right, Y down, Z forward):
        ``Pose.look_at(eye, target, body="camera")`` or ``rig.camera_pose(sonar_pose)``.
    water : Water, str or None
        The water (:meth:`Water.preset` name accepted). ``None``: the thesis's water,
        c = (0.41, 0.066, 0.018) m^-1.
    lights : Light, sequence of Light, or None
        ``None``: one lamp 0.4 m right of and 0.2 m above the camera, aimed forward
        (:func:`~optiacoustic.optical.lights.default_lights`).
    seed : int or numpy.random.Generator, optional
        Seed of the sensor noise; without it (and without ``options.noise``) the image is
        noise-free.
    options : OpticalOptions, optional

    Returns
    -------
    OpticalFrame
        Stages ``.clear``, ``.attenuated``, ``.forward_scatter``, ``.backscatter``,
        ``.image`` (H, W, 3) float32 linear radiance; ``.depth`` (range, inf for open
        water), ``.body`` (-1 for open water), ``.normal``.

    Raises
    ------
    ValueError
        Unknown water type, bad coefficients or options, the camera or a light inside a
        closed body (found by 14 probe rays; the message names the body), a lamp closer to
        the camera centre than ``MIN_LAMP_DISTANCE`` (2 cm) in scattering water, a camera
        whose distortion cannot produce every pixel of its image (``PinholeCamera.dist``).

    Notes
    -----
    An open surface (a plane such as the seabed) encloses nothing: a camera or a lamp
    below the seabed is allowed and sees or lights its underside. The veil ignores the
    shadows that bodies cast into the lit water, and a lamp closer to a pixel's ray than
    the slice spacing (a lamp in view) is undersampled by the slices.
    """
    t_start = time.perf_counter()
    from ..raycast import caster_for

    if not isinstance(scene, Scene):
        raise ValueError(f"scene: expected a Scene, got {type(scene).__name__}")
    if not isinstance(camera, PinholeCamera):
        raise ValueError(f"camera: expected a PinholeCamera, got {type(camera).__name__}")
    if not isinstance(pose, Pose):
        raise ValueError(f"pose: expected a Pose (e.g. Pose.look_at(eye, target, body='camera')), got {type(pose).__name__}")
    water = as_water(water)
    options = options or OpticalOptions()
    if not isinstance(options, OpticalOptions):
        raise ValueError(f"options: expected OpticalOptions, got {type(options).__name__}")
    lights = resolve_lights(lights, pose)
    if np.any(np.asarray(water.b) > 0):
        _check_lamp_distances(lights, pose)
    # a lower estimate of the bytes a render takes (rays, stages, depth, normals): refuse before allocating
    check_memory(160.0 * camera.width * camera.height,
                 f"a {camera.width} x {camera.height} camera image (PinholeCamera.width x height)")
    caster = caster_for(scene)
    names = scene.body_names()
    _check_not_inside(caster, names, pose, lights)
    G = forward_scatter_G(water, options)
    c = water.c
    H, W = camera.height, camera.width

    # ---- primary rays
    kernels = _use_kernels()
    # straight into float32 for Embree: the pixel rays are unit vectors by construction
    d_cam32 = _pixel_rays32(camera)
    # the world rays are scratch of this frame (per-thread, reused: nothing the frame returns
    # is one of them or a view of them)
    d32 = _workspace("d32", d_cam32.shape, np.float32)
    o32 = _workspace("o32", d_cam32.shape, np.float32)
    if kernels:
        from ._kernels import rotate_rays

        rotate_rays(d_cam32, pose.R.astype(np.float32), pose.t.astype(np.float32), o32, d32)
    else:
        # einsum, not @: a BLAS call on (n, 3) x (3, 3) can stall on busy cores
        np.einsum("ij,kj->ik", d_cam32, pose.R.astype(np.float32), out=d32)
        o32[...] = pose.t

    # the backscatter veil needs only the depth map: it runs beside the shading (numpy and
    # OpenCV release the GIL), so the second core works while this one shades
    def start_veil(depth2):
        return (_side_pool().submit if caster.threads > 1 else _inline)(backscatter, camera, pose, depth2, water,
                                                                        lights, options=options, G=G)

    shade = _shade_compiled if kernels else _shade_numpy
    depth2, body_all, normal, clear, attenuated, fs_src, fwd, bs_job = shade(
        caster, scene, pose, o32, d32, lights, c, G, options.shadows, H, W, start_veil)

    # ---- forward scatter (eq. 3.9): the lamp's forward-scattered light lights the surface
    # (smooth, not blurred), and of what leaves the surface e^{-G R_c} - e^{-c R_c} arrives
    # blurred by the range-dependent kernel
    if fs_src is not None:
        fwd += forward_scatter(fs_src, depth2, camera, B=options.B, layers=options.fs_layers, threads=caster.threads)

    # ---- backscatter (eqs. 3.10-3.13)
    bs = bs_job.result()
    image = fwd + bs
    noise = options.noise
    if noise is None and seed is not None:
        noise = SensorNoise()
    if isinstance(noise, SensorNoise):
        rng = as_rng(seed)
        image = noise.apply(image, rng)

    body = body_all.reshape(H, W)
    arrays = dict(clear=clear, attenuated=attenuated, forward_scatter=fwd, backscatter=bs, image=image,
                  depth=depth2.astype(np.float32, copy=False), body=body, normal=normal.reshape(H, W, 3))
    for a in arrays.values():
        a.setflags(write=False)
    return OpticalFrame(**arrays, camera=camera, pose=pose, water=water, lights=lights,
                        body_names=tuple(names), elapsed=time.perf_counter() - t_start)
