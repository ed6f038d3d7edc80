"""Drawing sonar features into optical images: resampling identities and drawing checks."""

from dataclasses import dataclass

import numpy as np
import pytest

from optiacoustic.fusion import map_fan, overlay


@dataclass
class Fan:
    """A minimal fan image: x_s in [-1, 1], y_s in [3, 5], 5 cm pixels."""

    data: np.ndarray
    mask: np.ndarray
    px: float = 0.05

    def from_pixel(self, u, v):
        return -1.0 + (np.asarray(u) + 0.5) * self.px, 5.0 - (np.asarray(v) + 0.5) * self.px


def _fan(values):
    h, w = 40, 40
    u, v = np.meshgrid(np.arange(w), np.arange(h))
    f = Fan(np.zeros((h, w)), np.ones((h, w), bool))
    x, y = f.from_pixel(u, v)
    f.data = values(x, y)
    return f


def affine(xy):
    xy = np.asarray(xy, float)
    return np.stack([300 + 150 * xy[..., 0] + 10 * (xy[..., 1] - 4), 200 - 90 * (xy[..., 1] - 4)], -1)


def affine_inverse(u, v):
    y = 4 - (v - 200) / 90
    x = (u - 300 - 10 * (y - 4)) / 150
    return x, y


def test_map_fan_reproduces_a_linear_echo_exactly():
    # a fan whose data is linear in (x_s, y_s), mapped by an affine map: linear interpolation is exact
    fan = _fan(lambda x, y: 2.0 * x - 0.5 * y + 3.0)
    out = map_fan(fan, affine, (400, 600))
    assert out.shape == (400, 600) and out.dtype == np.float32
    v, u = np.nonzero(np.isfinite(out))
    assert len(u) > 10000
    x, y = affine_inverse(u.astype(float), v.astype(float))
    np.testing.assert_allclose(out[v, u], 2.0 * x - 0.5 * y + 3.0, atol=1e-4)
    # pixels whose sonar point lies outside the fan stay NaN
    x, y = affine_inverse(599.0, 399.0)
    assert not (-1 <= x <= 1 and 3 <= y <= 5) and np.isnan(out[399, 599])


def test_map_fan_max_distance_keeps_the_neighbourhood_of_centres():
    fan = _fan(lambda x, y: np.ones_like(x))
    centre = np.array([[0.0, 4.0]])
    out = map_fan(fan, affine, (400, 600), max_distance=0.3, centres=centre)
    v, u = np.nonzero(np.isfinite(out))
    x, y = affine_inverse(u.astype(float), v.astype(float))
    assert len(u) > 100
    assert np.hypot(x - 0.0, y - 4.0).max() <= 0.3 + 0.05
    with pytest.raises(ValueError, match="centres"):
        map_fan(fan, affine, (400, 600), max_distance=0.3)


def test_overlay_points_are_drawn_where_the_mapping_sends_them():
    img = np.full((400, 600, 3), 0.2, np.float32)
    before = img.copy()
    pts = np.array([[0.0, 4.0], [0.5, 3.5], [np.nan, 4.0]])
    out = overlay(img, pts, affine, color=(1.0, 0.0, 0.0), radius=4, marker="dot")
    np.testing.assert_array_equal(img, before)  # the input is untouched
    assert out.shape == img.shape and out.dtype == np.float32
    for u, v in affine(pts[:2]):
        np.testing.assert_allclose(out[int(round(v)), int(round(u))], (1.0, 0.0, 0.0), atol=1e-6)
    changed = np.any(out != img, axis=-1)
    assert changed.sum() < 2 * 120  # two dots of radius 4, nothing else
    assert not changed[:100].any()


def test_overlay_fan_blends_the_echo_colour():
    img = np.zeros((400, 600, 3), np.float32)
    fan = _fan(lambda x, y: (np.abs(x) < 0.2).astype(float))  # a bright stripe |x_s| < 0.2
    out = overlay(img, fan, affine, color=(0.0, 1.0, 0.0), alpha=0.5)
    u, v = affine(np.array([[0.0, 4.0], [0.8, 4.0]])).round().astype(int).T
    np.testing.assert_allclose(out[v[0], u[0]], (0.0, 0.5, 0.0), atol=1e-6)  # inside the stripe
    np.testing.assert_allclose(out[v[1], u[1]], (0.0, 0.0, 0.0), atol=1e-6)  # outside it


@pytest.mark.parametrize(
    "kwargs, match",
    [
        ({"optical_image": np.zeros((10, 10))}, "optical_image"),
        ({"mapping": "not callable"}, "mapping"),
        ({"color": (2.0, 0.0, 0.0)}, "color"),
        ({"marker": "star"}, "marker"),
        ({"radius": 0}, "radius"),
        ({"sonar": np.zeros((3, 3))}, "sonar"),
        ({"alpha": 2.0}, "alpha"),  # was accepted for marker overlays
        ({"alpha": -1.0}, "alpha"),
    ],
)
def test_overlay_bad_input(kwargs, match):
    args = {"optical_image": np.zeros((20, 30, 3)), "sonar": np.zeros((2, 2)), "mapping": affine, **kwargs}
    with pytest.raises(ValueError, match=match):
        overlay(args.pop("optical_image"), args.pop("sonar"), args.pop("mapping"), **args)


def test_map_fan_bad_input():
    with pytest.raises(ValueError, match="fan"):
        map_fan(np.zeros((5, 5)), affine, (10, 10))
    with pytest.raises(ValueError, match="shape"):
        map_fan(_fan(lambda x, y: x), affine, (0, 10))
