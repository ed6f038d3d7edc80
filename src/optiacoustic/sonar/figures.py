"""Figures of the sonar simulation stages (thesis Figs. 2.4-2.17)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from .display import to_display
from .frame import SonarFrame
from .._atomic import ensure_dir, savefig

__all__ = ["save_stage_figures", "plot_scene_overview"]


def _plt():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def plot_scene_overview(scene, sonar_pose, spec, path, *, camera_pose=None, title=None) -> Path:
    """3D view of the scene's bodies with the sonar's fan footprint (thesis Fig. 2.15)."""
    plt = _plt()
    from mpl_toolkits.mplot3d.art3d import Poly3DCollection

    from ..scene import Cylinder, Ellipsoid, KleinBottle, Sphere

    fig = plt.figure(figsize=(8, 6))
    ax = fig.add_subplot(111, projection="3d")
    light = np.array([0.3, -0.5, 0.8])
    light /= np.linalg.norm(light)
    from ..scene import Plane, Surface

    def draw_shape(shape):
        # coarser tessellation for drawing only
        if isinstance(shape, (Sphere, Ellipsoid)):
            return type(shape)(**{**shape.__dict__, "subdivisions": 3})
        if isinstance(shape, Cylinder):
            return Cylinder(radius=shape.radius, height=shape.height, sections=32)
        if isinstance(shape, KleinBottle):
            return KleinBottle(height=shape.height, resolution=48)
        return shape

    solids = [(b, draw_shape(b.shape).tessellate().transformed(b.pose)) for b in scene.bodies if not isinstance(b.shape, Plane)]
    if solids:
        v = np.concatenate([s.vertices for _, s in solids])
        lo, hi = v.min(0) - 1.0, v.max(0) + 1.0
    else:
        lo, hi = sonar_pose.t - 3.0, sonar_pose.t + 3.0
    parts = []
    for b in scene.bodies:
        if isinstance(b.shape, Plane):
            # draw large planes only over the window around the objects and the sensor
            w_lo = np.minimum(lo, sonar_pose.t - 0.5)
            w_hi = np.maximum(hi, sonar_pose.t + 0.5)
            surf = b.shape.tessellate().transformed(b.pose)
            gv = surf.vertices.copy()
            gv[:, :2] = np.clip(gv[:, :2], w_lo[:2], w_hi[:2])
            parts.append((b, Surface(gv, surf.faces, surf.normals)))
    # planes first, then solids from far to near: matplotlib draws collections in order
    eye_dir = np.array([np.cos(np.deg2rad(-110)), np.sin(np.deg2rad(-110)), 0.5])
    solids.sort(key=lambda bs: -float(bs[1].vertices.mean(0) @ eye_dir))
    parts += solids
    ax.computed_zorder = False
    for body, surf in parts:
        tris = surf.vertices[surf.faces]
        n = np.cross(tris[:, 1] - tris[:, 0], tris[:, 2] - tris[:, 0])
        n /= np.linalg.norm(n, axis=1, keepdims=True) + 1e-12
        shade = 0.35 + 0.65 * np.abs(n @ light)
        col = np.clip(np.asarray(body.material.color)[None, :] * shade[:, None], 0, 1)
        ax.add_collection3d(Poly3DCollection(tris, facecolors=col, edgecolors="none", alpha=1.0))
    # sonar fan outline on the ground: rays at the aperture's corners
    o = sonar_pose.t
    for th in (-spec.fov_azimuth / 2, 0.0, spec.fov_azimuth / 2):
        for ph in (-spec.fov_elevation / 2, spec.fov_elevation / 2):
            d = sonar_pose.R @ np.array([np.cos(ph) * np.sin(th), np.cos(ph) * np.cos(th), np.sin(ph)])
            L = spec.range_max if d[2] >= 0 else min(spec.range_max, -o[2] / d[2]) if o[2] > 0 else spec.range_max
            ax.plot(*np.stack([o, o + d * L]).T, color="tab:orange", lw=0.8, alpha=0.7)
    ax.scatter(*o, color="tab:red", s=40, label="sonar")
    if camera_pose is not None:
        ax.scatter(*camera_pose.t, color="tab:blue", s=40, label="camera")
    pts = np.vstack([lo, hi, o])
    c = (pts.min(0) + pts.max(0)) / 2
    r = (pts.max(0) - pts.min(0)).max() / 2 + 0.5
    ax.set_xlim(c[0] - r, c[0] + r)
    ax.set_ylim(c[1] - r, c[1] + r)
    ax.set_zlim(max(c[2] - r, -0.5), c[2] + r)
    ax.set_box_aspect((1, 1, 0.6))
    ax.set_xlabel("x (m)")
    ax.set_ylabel("y (m)")
    ax.set_zlabel("z (m)")
    ax.view_init(elev=28, azim=-110)
    ax.legend(loc="upper left")
    ax.set_title(title or f"{scene.name}: scene and sonar fan")
    fig.tight_layout()
    savefig(fig, path, dpi=110)
    plt.close(fig)
    return Path(path)


def save_stage_figures(frame: SonarFrame, out_dir, *, prefix: str = "sonar", fan_width: int = 900) -> list[tuple[Path, str]]:
    """Write the stage figures of one frame; returns ``[(path, caption), ...]``.

    Raw per-ray matrices (Figs. 2.4-2.7), decimated polar image (Fig. 2.16), fan image
    (Fig. 2.17a), fan image with noise and reverberation (Fig. 2.17b), ground truth.
    """
    plt = _plt()
    out = Path(out_dir)
    ensure_dir(out)
    spec = frame.spec
    figs = []
    deg = np.rad2deg
    az = deg(spec.fov_azimuth) / 2
    el = deg(spec.fov_elevation) / 2

    # --- raw per-ray matrices
    rays = frame.rays
    fig, axes = plt.subplots(1, 3, figsize=(15, 4.2))
    ext = (-az, az, -el, el)
    rng_map = np.where(np.isfinite(rays.range), rays.range, np.nan)
    im = axes[0].imshow(rng_map, origin="lower", aspect="auto", extent=ext, cmap="viridis")
    fig.colorbar(im, ax=axes[0], label="range (m)")
    axes[0].set_title("range of each ray")
    # per unit of elevation: each ray's energy over its own cell's width (edge cells differ)
    cell = np.where(np.isfinite(rays.range), rays.elevation_hi - rays.elevation_lo, np.nan)
    with np.errstate(invalid="ignore", divide="ignore"):
        lambert = rays.energy / cell
    im = axes[1].imshow(lambert, origin="lower", aspect="auto", extent=ext, cmap="copper")
    fig.colorbar(im, ax=axes[1], label="reflectivity x cos(incidence)")
    axes[1].set_title("intensity of each ray (eq. 2.10)")
    body = np.where(rays.body >= 0, rays.body, np.nan)
    im = axes[2].imshow(body, origin="lower", aspect="auto", extent=ext, cmap="tab10", interpolation="nearest")
    fig.colorbar(im, ax=axes[2], label="body id")
    axes[2].set_title("surface (body) hit by each ray")
    for a in axes:
        a.set_xlabel("azimuth (deg)")
        a.set_ylabel("elevation (deg)")
    fig.suptitle(f"Scan: {spec.n_beams} beams x {spec.elevation_samples} elevation samples")
    fig.tight_layout()
    p = out / f"{prefix}_rays.png"
    savefig(fig, p, dpi=90)
    plt.close(fig)
    figs.append((p, "Per-ray matrices of the scan: range, Lambert intensity and body hit (Figs. 2.4-2.7)."))

    # --- one beam's raw returns vs range and the summed echo
    j = int(np.argmax(frame.intensity.sum(0)))
    fig, ax = plt.subplots(1, 2, figsize=(12, 3.8))
    r = rays.range[:, j]
    ok = np.isfinite(r)
    ax[0].scatter(r[ok], lambert[ok, j], s=4, c=rays.body[ok, j], cmap="tab10")
    ax[0].set_xlabel("range (m)")
    ax[0].set_ylabel("ray intensity")
    ax[0].set_title(f"beam {j}: raw returns (Fig. 2.7/2.11a)")
    ax[1].plot(frame.ranges, frame.intensity[:, j], lw=1)
    ax[1].set_xlabel("range (m)")
    ax[1].set_ylabel("echo per metre")
    ax[1].set_title("summed, integrated and decimated echo (Fig. 2.11b/2.13)")
    for a in ax:
        a.set_xlim(spec.range_min, spec.range_max)
    fig.tight_layout()
    p = out / f"{prefix}_beam_profile.png"
    savefig(fig, p, dpi=90)
    plt.close(fig)
    figs.append((p, f"Beam {j}: raw returns of its rays against range, and the echo after summing returns of equal range, integration into bins and decimation."))

    # --- decimated polar image
    ref = np.percentile(frame.intensity[frame.intensity > 0], 99.5) if np.any(frame.intensity > 0) else 1.0
    fig, ax = plt.subplots(figsize=(7, 6))
    ax.imshow(to_display(frame.intensity, reference=ref), origin="lower", aspect="auto", cmap="copper",
              extent=(-az, az, spec.range_min, spec.range_max))
    ax.set_xlabel("azimuth (deg)")
    ax.set_ylabel("range (m)")
    ax.set_title(f"Image after decimation ({spec.n_bins} bins x {spec.n_beams} beams)")
    fig.tight_layout()
    p = out / f"{prefix}_polar.png"
    savefig(fig, p, dpi=90)
    plt.close(fig)
    figs.append((p, "Image directly formed after decimation, range vs azimuth (Fig. 2.16)."))

    # --- fan images, clean and noisy
    for which, name, cap in (
        ("intensity", "fan", "Fan (polar) image: acoustic shadows are exactly dark (Fig. 2.17a)."),
        ("image", "fan_noisy", "With bottom reverberation (Rayleigh mixture) and the ambient noise floor (Fig. 2.17b)."),
    ):
        fan = frame.fan(which, width=fan_width)
        fig, ax = plt.subplots(figsize=(8, 6))
        ax.imshow(to_display(fan.data, reference=ref), extent=fan.extent, cmap="copper")
        ax.set_facecolor("black")
        ax.set_xlabel("x_s (m)")
        ax.set_ylabel("y_s (m)")
        ax.set_title(("noise-free echo" if which == "intensity" else "with noise and reverberation") + " (40 dB display)")
        fig.tight_layout()
        p = out / f"{prefix}_{name}.png"
        savefig(fig, p, dpi=90)
        plt.close(fig)
        figs.append((p, cap))

    # --- ground truth
    gt = frame.ground_truth
    fig, axes = plt.subplots(1, 3, figsize=(15, 4.2))
    extent = (-az, az, spec.range_min, spec.range_max)
    body = np.where(gt.body >= 0, gt.body, np.nan)
    im = axes[0].imshow(body, origin="lower", aspect="auto", extent=extent, cmap="tab10", interpolation="nearest")
    fig.colorbar(im, ax=axes[0], label="body id")
    axes[0].set_title("strongest body per cell")
    span = np.rad2deg(gt.elevation_max - gt.elevation_min)
    im = axes[1].imshow(span, origin="lower", aspect="auto", extent=extent, cmap="magma")
    fig.colorbar(im, ax=axes[1], label="deg")
    axes[1].set_title("elevation span echoing into each cell")
    axes[2].imshow(gt.shadow, origin="lower", aspect="auto", extent=extent, cmap="gray", interpolation="nearest")
    axes[2].set_title("acoustic shadow")
    for a in axes:
        a.set_xlabel("azimuth (deg)")
        a.set_ylabel("range (m)")
    fig.tight_layout()
    p = out / f"{prefix}_ground_truth.png"
    savefig(fig, p, dpi=90)
    plt.close(fig)
    figs.append((p, "Ground truth per cell: strongest body, the elevation span the sonar cannot resolve, acoustic shadow."))
    return figs
