"""Pictures of matches: both images side by side, matches colour-coded by score."""

from __future__ import annotations

from pathlib import Path

import numpy as np

__all__ = ["draw_matches"]


def _camera_display(image) -> np.ndarray:
    img = np.asarray(image, float)
    if img.dtype == np.uint8 or img.max() > 2.0:
        return np.clip(img / 255.0, 0, 1)
    ref = np.percentile(img, 99.5) if np.any(img > 0) else 1.0
    return np.clip(img / max(ref, 1e-12), 0, 1) ** (1 / 2.2)


def draw_matches(path, sonar_image, ranges, azimuths, camera_image, matches, *, title: str = "",
                 correct=None) -> Path:
    """Write a PNG of the sonar image (polar: azimuth across, range up) and the camera image with the matches.

    Parameters
    ----------
    path : path-like
    sonar_image : array_like, shape (n_bins, n_beams)
        Linear intensity (shown in dB, 40 dB range).
    ranges, azimuths : array_like
        Bin centres (m) and beam centres (rad).
    camera_image : array_like, shape (H, W, 3)
    matches : Matches
    title : str
    correct : array_like of bool, shape (N,), optional
        Ground truth (evaluation only): wrong matches are drawn with a cross.
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from .._atomic import savefig

    S = np.asarray(sonar_image, float)
    ref = np.percentile(S[S > 0], 99.5) if np.any(S > 0) else 1.0
    db = 10 * np.log10(np.maximum(S / ref, 1e-4))
    r = np.asarray(ranges, float)
    th = np.rad2deg(np.asarray(azimuths, float))
    fig, ax = plt.subplots(1, 2, figsize=(13, 5.2), gridspec_kw=dict(width_ratios=[1, 1.35]))
    ax[0].imshow(db, origin="lower", aspect="auto", cmap="copper", vmin=-40, vmax=0,
                 extent=(th[0], th[-1], r[0], r[-1]))
    ax[0].set_xlabel("azimuth (deg)")
    ax[0].set_ylabel("range (m)")
    ax[0].set_title("sonar (polar)")
    ax[1].imshow(_camera_display(camera_image))
    ax[1].set_title("camera")
    ax[1].set_axis_off()
    cmap = plt.get_cmap("plasma")
    n = len(matches)
    if n:
        col = cmap(np.clip(matches.score, 0, 1))
        ok = np.ones(n, bool) if correct is None else np.asarray(correct, bool)
        for good, marker in ((True, "o"), (False, "x")):
            k = ok == good
            if not k.any():
                continue
            ax[0].scatter(np.rad2deg(matches.azimuths[k]), matches.ranges[k], s=28, c=col[k], marker=marker,
                          edgecolors="white" if marker == "o" else None, linewidths=0.6 if marker == "o" else 1.5)
            ax[1].scatter(matches.pixels[k, 0], matches.pixels[k, 1], s=28, c=col[k], marker=marker,
                          edgecolors="white" if marker == "o" else None, linewidths=0.6 if marker == "o" else 1.5)
        for i in range(min(n, 40)):
            ax[0].annotate(str(i), (np.rad2deg(matches.azimuths[i]), matches.ranges[i]), color="white", fontsize=6,
                           xytext=(3, 3), textcoords="offset points")
            ax[1].annotate(str(i), tuple(matches.pixels[i]), color="white", fontsize=6, xytext=(3, 3),
                           textcoords="offset points")
    sm = plt.cm.ScalarMappable(cmap=cmap, norm=plt.Normalize(0, 1))
    fig.colorbar(sm, ax=ax[1], fraction=0.03, label="match score")
    note = "" if correct is None else " (x: wrong by ground truth)"
    fig.suptitle((title + ": " if title else "") + f"{n} matches{note}")
    fig.tight_layout()
    out = savefig(fig, Path(path), dpi=110)
    plt.close(fig)
    return out
