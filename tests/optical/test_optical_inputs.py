"""Lights and options the optical model cannot evaluate: refused with the argument named."""

import numpy as np
import pytest

from optiacoustic import PinholeCamera, Pose, Scene, simulate_optical
from optiacoustic.optical import Light, OpticalOptions
from optiacoustic.optical.lights import MIN_CONE_DEG, MIN_LAMP_DISTANCE
from optiacoustic.scene import Body, Plane

CAM = PinholeCamera.from_sensor(64, 48, focal_mm=20)
WALL = Scene([Body("wall", Plane(size=(40, 40)), Pose.from_euler_deg([0, 4, 0], [90, 0, 0]))])
POSE = Pose.look_at([0, 0, 0], [0, 1, 0], body="camera")


@pytest.mark.parametrize("offset", [(0.0, 0.0, 0.0), (0.0, 0.01, 0.0)])
def test_a_lamp_at_the_camera_centre_is_refused_in_scattering_water(offset):
    # its veil is infinite (the integrand of the single-scattering integral grows as 1 / R^2 at the camera)
    lamps = [Light((0.4, -0.2, 0.0), 100.0), Light(offset, 100.0)]
    with pytest.raises(ValueError, match=rf"lights\[1\]: the lamp is {np.linalg.norm(offset):.3g} m from the camera "
                                         rf"centre.*MIN_LAMP_DISTANCE = {MIN_LAMP_DISTANCE}"):
        simulate_optical(WALL, CAM, POSE, water="jerlov-II", lights=lamps, options=OpticalOptions(noise=False))
    # a lamp in world coordinates that happens to sit at the camera is the same lamp
    with pytest.raises(ValueError, match=r"lights\[0\]"):
        simulate_optical(WALL, CAM, POSE, water="jerlov-II", lights=Light(tuple(POSE.t + offset), 100.0, frame="world"))


def test_a_lamp_at_the_camera_centre_is_fine_in_clear_water():
    """No scattering, no veil: the direct term of a wall 4 m ahead lit from the camera is rho/pi I / d^2."""
    f = simulate_optical(WALL, CAM, POSE, water="clear", lights=Light((0.0, 0.0, 0.0), 100.0),
                         options=OpticalOptions(noise=False))
    # the centre pixel (31.5, 23.5) is between four pixels: take the nearest one's range
    d = f.depth[24, 32]
    assert d == pytest.approx(4.0, rel=1e-3)
    cos_g = 4.0 / d
    np.testing.assert_allclose(f.clear[24, 32], 0.5 / np.pi * 100.0 * cos_g / d ** 2, rtol=1e-3)


def test_lamp_just_beyond_the_minimum_converges_with_slices():
    lt = Light((MIN_LAMP_DISTANCE, 0.0, 0.0), 100.0)
    bs = [simulate_optical(WALL, CAM, POSE, water="jerlov-II", lights=lt,
                           options=OpticalOptions(noise=False, slices=n, backscatter_step=8)).backscatter[24, 32]
          for n in (32, 512)]
    np.testing.assert_allclose(bs[0], bs[1], rtol=0.01)


@pytest.mark.parametrize("cone", [1e-7, 0.0, MIN_CONE_DEG / 2, "30", True, np.nan, 91.0])
def test_spot_cones_outside_the_range_are_named(cone):
    with pytest.raises(ValueError, match=r"^Light.cone_deg: expected a half-angle in \[0.01, 90\] deg"):
        Light((0.4, 0, 0), 100.0, (0, 0, 1), cone)


def test_the_narrowest_spot_is_half_power_at_its_cone():
    lt = Light((0.0, 0.0, 0.0), 100.0, (0.0, 0.0, 1.0), MIN_CONE_DEG, "world")
    a = np.deg2rad(MIN_CONE_DEG)
    assert np.isfinite(lt.spot_exponent)
    p = lt.profile(np.array([[0.0, 0.0, 1.0], [np.sin(a), 0.0, np.cos(a)]]))
    np.testing.assert_allclose(p, [1.0, 0.5], rtol=1e-6)


@pytest.mark.parametrize("kw", [{"B": "x"}, {"B": None}, {"slice_scale": "x"}, {"fs_cone_deg": "10"},
                                {"slices": True}, {"backscatter_step": 2.0}, {"shadows": "no"},
                                {"forward_scatter": 0}, {"G": "abc"}, {"G": (0.1, True, 0.1)}, {"fs_layers": True}])
def test_optical_options_name_the_bad_argument(kw):
    (name,) = kw
    with pytest.raises(ValueError, match=rf"^OpticalOptions.{name}:"):
        OpticalOptions(**kw)


def test_light_intensity_that_is_not_numbers_is_named():
    with pytest.raises(ValueError, match="Light.intensity"):
        Light(intensity="bright")
