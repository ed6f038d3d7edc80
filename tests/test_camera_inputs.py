"""PinholeCamera: pixels a strong distortion cannot produce are NaN (and the renderer refuses such a camera);
bad arguments are named."""

import numpy as np
import pytest

from optiacoustic import PinholeCamera, Pose, Scene, simulate_optical
from optiacoustic.scene import Body, Plane

W, H, F = 160, 120, 150.0


def _cam(k1):
    return PinholeCamera(fx=F, fy=F, cx=79.5, cy=59.5, width=W, height=H, dist=(k1, 0, 0, 0, 0))


@pytest.mark.parametrize("k1", [-0.6, -2.0])
def test_pixels_beyond_the_distortion_fold_are_nan_the_rest_round_trip(k1):
    """Radial distortion r_d = r (1 + k1 r^2) with k1 < 0 rises to its maximum at r* = sqrt(-1 / (3 k1)),
    r_d* = 2 r* / 3, and turns back: a pixel farther than r_d* from the centre has no ray."""
    cam = _cam(k1)
    r_star = np.sqrt(-1.0 / (3.0 * k1))
    rd_max = 2.0 * r_star / 3.0
    u, v = np.meshgrid(np.arange(W, dtype=float), np.arange(H, dtype=float))
    rd = np.hypot((u - cam.cx) / F, (v - cam.cy) / F)
    rays = cam.pixel_rays()
    ok = np.isfinite(rays[..., 0])
    assert not np.any(ok[rd > rd_max * (1 + 1e-6)])            # no ray where the model produces no pixel
    assert np.all(ok[rd < rd_max * (1 - 1e-3)])                # a ray for every pixel it does produce
    # the rays that exist point where the pixel is: within 0.01 px, and on the near branch (r < r*)
    uv = cam.project(rays[ok])
    np.testing.assert_allclose(uv, np.stack([u[ok], v[ok]], -1), atol=0.01)
    r = np.hypot(rays[ok][:, 0], rays[ok][:, 1]) / rays[ok][:, 2]
    assert np.all(r <= r_star * (1 + 1e-6))
    # normalized() gives the same mask
    xn = cam.normalized(np.stack([u, v], -1))
    np.testing.assert_array_equal(np.isfinite(xn[..., 0]), ok)


def test_mild_distortion_keeps_every_pixel():
    cam = PinholeCamera(fx=F, fy=F, cx=79.5, cy=59.5, width=W, height=H, dist=(-0.2, 0.05, 0.001, -0.002, 0.0))
    rays = cam.pixel_rays()
    assert np.isfinite(rays).all()
    u, v = np.meshgrid(np.arange(W, dtype=float), np.arange(H, dtype=float))
    np.testing.assert_allclose(cam.project(rays), np.stack([u, v], -1), atol=1e-6)


def test_renderer_refuses_a_camera_with_pixels_without_rays():
    wall = Body("wall", Plane(size=(40, 40)), Pose.from_euler_deg([0, 4, 0], [90, 0, 0]))
    pose = Pose.look_at([0, 0, 0], [0, 1, 0], body="camera")
    with pytest.raises(ValueError, match=r"PinholeCamera.dist: .* cannot produce \d+ of the image's 19200 pixels"):
        simulate_optical(Scene([wall]), _cam(-0.6), pose, water="clear")


@pytest.mark.parametrize("kw, field", [({"fx": True}, "fx"), ({"fy": "1"}, "fy"), ({"cx": True}, "cx"),
                                       ({"dist": "abc"}, "dist"), ({"dist": (0, 0, 0, 0)}, "dist"),
                                       ({"dist": (0, 0, 0, 0, np.nan)}, "dist")])
def test_bad_camera_arguments_are_named(kw, field):
    args = {"fx": 100.0, "fy": 100.0, "cx": 5.0, "cy": 5.0, "width": 10, "height": 10, **kw}
    with pytest.raises(ValueError, match=rf"^PinholeCamera.{field}:"):
        PinholeCamera(**args)


@pytest.mark.parametrize("factor", [np.nan, 0, -1, "2", np.inf])
def test_scaled_names_its_factor(factor):
    with pytest.raises(ValueError, match="scaled: factor"):
        PinholeCamera(100.0, 100.0, 4.5, 4.5, 10, 10).scaled(factor)
