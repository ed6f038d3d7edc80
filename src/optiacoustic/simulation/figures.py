"""Figure of a synchronised sonar + camera pair."""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from .._atomic import savefig
from ..optical.figures import _plt
from ..sonar.display import to_display

if TYPE_CHECKING:  # annotations only (the optical frame module is not needed to draw the figure)
    from ..optical.frame import OpticalFrame

__all__ = ["save_pair_figure"]


def save_pair_figure(sonar_frame, optical_frame: OpticalFrame, path, *, title: str | None = None) -> Path:
    """A synchronised sonar fan image and camera image side by side."""

    plt = _plt()
    fan = sonar_frame.fan("image", width=700)
    ref = np.percentile(sonar_frame.intensity[sonar_frame.intensity > 0], 99.5) if np.any(sonar_frame.intensity > 0) else 1.0
    fig, axes = plt.subplots(1, 2, figsize=(14, 5.2), gridspec_kw={"width_ratios": [1, 1.25]})
    axes[0].imshow(to_display(fan.data, reference=ref), extent=fan.extent, cmap="copper")
    axes[0].set_facecolor("black")
    axes[0].set_xlabel("x_s (m)")
    axes[0].set_ylabel("y_s (m)")
    axes[0].set_title(f"sonar ({sonar_frame.spec.name}) at {np.round(sonar_frame.pose.t, 2).tolist()}")
    axes[1].imshow(optical_frame.to_srgb8("image"))
    axes[1].set_title(f"camera at {np.round(optical_frame.pose.t, 2).tolist()}, {optical_frame.water.name} water")
    axes[1].axis("off")
    if title:
        fig.suptitle(title)
    fig.tight_layout()
    savefig(fig, path, dpi=80)
    plt.close(fig)
    return Path(path)
