"""Figures of the optical simulation stages (thesis Figs. 3.7-3.8)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from .frame import OpticalFrame, auto_exposure, to_srgb8
from .._atomic import ensure_dir, savefig

__all__ = ["save_stage_figures", "save_ground_truth_figure"]


def _plt():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def save_stage_figures(frame: OpticalFrame, out_dir, *, prefix: str = "optical", title: str | None = None,
                       individual: bool = True) -> list[tuple[Path, str]]:
    """The four stages of Figs. 3.7-3.8 as one panel, the two scattered components alone,
    and (``individual``) each stage as a full-resolution PNG.

    All four stages share one exposure (the larger of the clear and the final image's auto
    exposures), so that attenuation is seen taking light away and the veil adding it; an
    exposure per panel would brighten the attenuated seabed back up.
    Returns ``[(path, caption), ...]``.
    """
    plt = _plt()
    out = Path(out_dir)
    ensure_dir(out)
    e = max(frame.exposure("clear"), frame.exposure("image"))  # one exposure: panels compare
    panels = [
        ("clear", e, "a) clear (no water), Fig. 3.7a"),
        ("attenuated", e, "b) attenuation, Fig. 3.7b"),
        ("forward_scatter", e, "c) + forward scatter, Fig. 3.8a"),
        ("image", e, "d) + backscatter, Fig. 3.8b"),
    ]
    figs = []
    fig, axes = plt.subplots(2, 2, figsize=(12, 8.4))
    for ax, (stage, e, label) in zip(axes.ravel(), panels):
        ax.imshow(frame.to_srgb8(stage, e))
        ax.set_title(label)
        ax.axis("off")
    w = frame.water
    fig.suptitle(title or f"{w.name} water, c = ({', '.join(f'{x:.3g}' for x in w.c)}) /m (R, G, B)")
    fig.tight_layout()
    p = out / f"{prefix}_stages.png"
    savefig(fig, p, dpi=80)
    plt.close(fig)
    figs.append((p, f"Underwater image formation step by step in {w.name} water (thesis Figs. 3.7-3.8): "
                    "clear scene, attenuation (red fades first), forward scatter, and the veiling backscatter; "
                    "one exposure for all four panels."))
    for stage, e, label in panels if individual else ():
        p = out / f"{prefix}_{stage}.png"
        frame.save_png(p, stage, e)
        figs.append((p, label.split(") ", 1)[1] + f" ({w.name} water), full resolution."))
    # the veil alone (own exposure) and the forward-scattered light alone (magnified)
    fig, axes = plt.subplots(1, 2, figsize=(12, 4.2))
    axes[0].imshow(frame.to_srgb8("backscatter"))
    axes[0].set_title("backscatter (veiling light) alone, own exposure")
    fs = np.asarray(frame.forward_scatter) - np.asarray(frame.attenuated)
    axes[1].imshow(to_srgb8(fs, auto_exposure(fs) if np.any(fs > 0) else 1.0))
    axes[1].set_title("forward-scattered light alone, own exposure")
    for a in axes:
        a.axis("off")
    fig.tight_layout()
    p = out / f"{prefix}_components.png"
    savefig(fig, p, dpi=80)
    plt.close(fig)
    share = float(np.sum(frame.backscatter) / max(np.sum(frame.image), 1e-30))
    figs.append((p, f"The two scattered components on their own: the veil ({100 * share:.0f} % of the image's light) "
                    "is smooth and brightest towards the lamp; the forward-scattered light is a range-dependent blur "
                    "of the scene."))
    return figs


def save_ground_truth_figure(frame: OpticalFrame, path) -> Path:
    """Depth and body-id maps of a frame."""
    plt = _plt()
    fig, axes = plt.subplots(1, 2, figsize=(12, 4.2))
    d = np.where(np.isfinite(frame.depth), frame.depth, np.nan)
    im = axes[0].imshow(d, cmap="viridis")
    fig.colorbar(im, ax=axes[0], label="range along the ray (m)")
    axes[0].set_title("depth (range) ground truth")
    b = np.where(frame.body >= 0, frame.body, np.nan)
    im = axes[1].imshow(b, cmap="tab10", interpolation="nearest")
    fig.colorbar(im, ax=axes[1], label="body id")
    axes[1].set_title("body ids (open water blank)")
    for a in axes:
        a.set_xlabel("u (px)")
        a.set_ylabel("v (px)")
    fig.tight_layout()
    savefig(fig, path, dpi=80)
    plt.close(fig)
    return Path(path)
