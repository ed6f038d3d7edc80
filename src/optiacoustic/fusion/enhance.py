"""Drawing sonar information into a degraded optical image (thesis sec. 7.4, Figs. 7.8-7.10).

Any mapping of this package (a callable from fan coordinates ``(..., 2)`` in metres to
optical pixels ``(..., 2)``) carries sonar features into the camera:

* :func:`map_fan` resamples a whole sonar fan image into the optical image's geometry:
  the centres of the fan pixels are mapped forward and the optical pixels are interpolated
  linearly between them (:func:`scipy.interpolate.griddata`), because the mappings have no
  inverse;
* :func:`overlay` draws points (markers) or a fan image (a coloured, echo-weighted layer)
  over the optical image.

Images are display-referred here: ``(H, W, 3)`` floats in [0, 1] (apply the camera's tone
mapping first); the fan's data should be a display mapping of the echo in [0, 1] too.
A fan image is any object with ``data`` ``(h, w)``, ``mask`` ``(h, w)`` and
``from_pixel(u, v) -> (x_s, y_s)``, such as ``SonarFrame.fan()``.
"""

from __future__ import annotations

import numpy as np
from scipy.interpolate import griddata
from scipy.spatial import QhullError, cKDTree

from .._validate import as_array, as_positive

__all__ = ["map_fan", "overlay"]


def _check_mapping(mapping):
    if not callable(mapping):
        raise ValueError(f"mapping: expected a callable from fan coordinates to pixels, got {type(mapping).__name__}")
    return mapping


def _is_fan(obj) -> bool:
    return all(hasattr(obj, a) for a in ("data", "mask", "from_pixel"))


def _check_image(image) -> np.ndarray:
    img = as_array(image, "optical_image", (None, None, 3))
    return np.clip(img, 0.0, 1.0).astype(np.float32)


def map_fan(fan, mapping, shape, *, max_distance: float | None = None, centres=None) -> np.ndarray:
    """A sonar fan image resampled into optical pixels through ``mapping``.

    Parameters
    ----------
    fan : fan image
        ``data`` ``(h, w)``, ``mask`` ``(h, w)`` (True inside the fan), ``from_pixel``.
    mapping : callable
        Fan coordinates ``(M, 2)`` (m) -> optical pixels ``(M, 2)``.
    shape : tuple of int
        ``(H, W)`` of the optical image.
    max_distance : float, optional
        Use only fan pixels within this distance (m) of a point of ``centres`` (where a
        learned mapping is supported by data).
    centres : array_like, shape (N, 2), optional
        Fan coordinates of those points; default ``mapping.sonar_xy`` when the mapping
        has it.

    Returns
    -------
    ndarray, shape (H, W), float32
        The fan's data seen from the camera; NaN where no fan pixel maps.
    """
    if not _is_fan(fan):
        raise ValueError("fan: expected a fan image with data, mask and from_pixel (e.g. SonarFrame.fan())")
    _check_mapping(mapping)
    if len(shape) < 2 or int(shape[0]) < 1 or int(shape[1]) < 1:
        raise ValueError(f"shape: expected (H, W) of the optical image, got {shape!r}")
    H, W = int(shape[0]), int(shape[1])
    data = np.asarray(fan.data, float)
    vv, uu = np.nonzero(np.asarray(fan.mask, bool))
    xs, ys = fan.from_pixel(uu, vv)
    xy = np.stack([xs, ys], -1)
    if max_distance is not None:
        max_distance = as_positive(max_distance, "max_distance")
        c = getattr(mapping, "sonar_xy", None) if centres is None else centres
        if c is None:
            raise ValueError("centres: needed with max_distance when the mapping has no sonar_xy")
        c = as_array(c, "centres", (None, 2))
        near = cKDTree(c).query(xy, distance_upper_bound=max_distance)[0] <= max_distance
        xy, vv, uu = xy[near], vv[near], uu[near]
    out = np.full((H, W), np.nan, np.float32)
    if len(xy) < 3:
        return out
    px = np.asarray(mapping(xy), float)
    # keep what lands near the image (a margin keeps the interpolation right at the border)
    keep = np.all(np.isfinite(px), axis=-1)
    keep &= (px[:, 0] > -0.1 * W) & (px[:, 0] < 1.1 * W) & (px[:, 1] > -0.1 * H) & (px[:, 1] < 1.1 * H)
    if keep.sum() < 3:
        return out
    gu, gv = np.meshgrid(np.arange(W, dtype=float), np.arange(H, dtype=float))
    try:
        res = griddata(px[keep], data[vv[keep], uu[keep]], (gu, gv), method="linear")
    except QhullError:  # qhull cannot triangulate (all mapped points on a line): nothing to draw
        return out
    return res.astype(np.float32)


def _draw_points(img: np.ndarray, px: np.ndarray, color, radius: int, marker: str) -> np.ndarray:
    import cv2

    out = np.ascontiguousarray(img)
    col = tuple(float(c) for c in color)
    for u, v in px[np.all(np.isfinite(px), axis=-1)]:
        p = (int(round(u)), int(round(v)))
        if marker == "circle":
            cv2.circle(out, p, radius, col, 2, cv2.LINE_AA)
        elif marker == "dot":
            cv2.circle(out, p, radius, col, -1, cv2.LINE_AA)
        else:
            mk = cv2.MARKER_CROSS if marker == "cross" else cv2.MARKER_TILTED_CROSS
            cv2.drawMarker(out, p, col, mk, 2 * radius + 1, 2, cv2.LINE_AA)
    return out


def overlay(optical_image, sonar, mapping, *, color=(1.0, 0.25, 0.1), alpha: float = 0.7, radius: int = 5,
            marker: str = "circle", max_distance: float | None = None, centres=None) -> np.ndarray:
    """Draw sonar features, mapped into the camera, over an optical image.

    Parameters
    ----------
    optical_image : array_like, shape (H, W, 3)
        Display-referred image, values in [0, 1] (clipped).
    sonar : array_like (N, 2) or fan image
        Sonar points in fan coordinates (m), drawn as markers; or a fan image (data in
        [0, 1]) blended as a coloured layer whose opacity is ``alpha`` times the echo.
    mapping : callable
        Fan coordinates ``(..., 2)`` (m) -> optical pixels ``(..., 2)``.
    color : 3 floats in [0, 1]
        RGB of the markers or of the echo layer.
    alpha : float
        Opacity of the echo layer where the echo is 1.
    radius : int
        Marker radius (px).
    marker : {"circle", "dot", "cross", "x"}
    max_distance : float, optional
        Fan images only: draw only the echo within this distance (m) of ``centres``
        (:func:`map_fan`).
    centres : array_like, shape (N, 2), optional
        Fan coordinates (m) of the sonar features the echo is drawn around; default the
        mapping's training features (``mapping.sonar_xy``).

    Returns
    -------
    ndarray, shape (H, W, 3), float32
        A new image in [0, 1]; the input is not modified. Points that map to NaN are skipped.
    """
    img = _check_image(optical_image).copy()
    _check_mapping(mapping)
    col = as_array(color, "color", (3,))
    if np.any((col < 0) | (col > 1)):
        raise ValueError(f"color: expected RGB values in [0, 1], got {col.tolist()}")
    if marker not in ("circle", "dot", "cross", "x"):
        raise ValueError(f"marker: expected 'circle', 'dot', 'cross' or 'x', got {marker!r}")
    a = as_positive(alpha, "alpha", allow_zero=True)
    if a > 1:
        raise ValueError(f"alpha: expected a value in [0, 1], got {a}")
    if _is_fan(sonar):
        echo = map_fan(sonar, mapping, img.shape[:2], max_distance=max_distance, centres=centres)
        w = a * np.clip(np.nan_to_num(echo, nan=0.0), 0.0, 1.0)[..., None]
        return (img * (1 - w) + col[None, None, :] * w).astype(np.float32)
    pts = as_array(sonar, "sonar", (None, 2), finite=False)
    if isinstance(radius, bool) or not isinstance(radius, (int, np.integer)) or radius < 1:
        raise ValueError(f"radius: expected a positive integer (px), got {radius!r}")
    px = np.asarray(mapping(pts), float).reshape(-1, 2)
    return _draw_points(img, px, col, int(radius), marker).astype(np.float32)
