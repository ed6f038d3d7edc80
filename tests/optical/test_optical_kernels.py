"""The compiled shading kernels (numba) against the numpy reference path, stage by stage."""

import subprocess
import sys

import numpy as np
import pytest

from optiacoustic import PinholeCamera, Pose, scenes
from optiacoustic.optical import Light, OpticalOptions, SensorNoise, backscatter, forward_scatter, simulate_optical
from optiacoustic.optical.lights import resolve_lights
from optiacoustic.optical.water import as_water

pytest.importorskip("numba")

CAM = PinholeCamera.from_sensor(150, 100)
STAGES = ("clear", "attenuated", "forward_scatter", "backscatter", "image", "depth", "normal")


def both_paths(monkeypatch, *args, **kw):
    monkeypatch.setenv("OAS_KERNELS", "numpy")
    ref = simulate_optical(*args, **kw)
    monkeypatch.delenv("OAS_KERNELS")
    return ref, simulate_optical(*args, **kw)


def assert_same_frame(ref, fast, rtol=2e-6):
    assert np.array_equal(ref.body, fast.body)
    for name in STAGES:
        a, b = getattr(ref, name), getattr(fast, name)
        assert a.dtype == b.dtype and a.shape == b.shape, name
        assert np.array_equal(np.isfinite(a), np.isfinite(b)), name
        fin = np.isfinite(a)
        scale = max(float(np.abs(a[fin]).max(initial=0.0)), 1e-30)
        # float32 arithmetic in another order: differences are rounding, relative to the stage's scale
        assert np.abs(a[fin] - b[fin]).max(initial=0.0) <= rtol * scale, name


@pytest.mark.parametrize("water", [None, "jerlov-II", "clear"])
def test_compiled_frame_equals_numpy_reference(monkeypatch, water):
    scene = scenes.get("thesis_scene1")
    pose = Pose.look_at((-0.25, -6.0, 2.0), (0.0, 0.0, 0.0), body="camera")
    ref, fast = both_paths(monkeypatch, scene, CAM, pose, water=water)
    assert np.any(ref.image > 0)
    assert_same_frame(ref, fast)


def test_compiled_frame_with_open_water_texture_spots_and_noise(monkeypatch):
    """Pixels that miss, a checker texture, three lamps (two spots, one isotropic) and sensor noise."""
    scene = scenes.get("perpendicular_planes")
    pose = Pose.look_at((0.4, -1.0, 0.3), (0.0, 1.5, 0.9), body="camera")
    lamps = [Light((0.3, -0.2, 0.0), 80.0, (0.0, 0.0, 1.0), 25.0), Light((-0.3, 0.0, 0.1), 60.0, (0.1, 0.0, 1.0), 60.0),
             Light((0.0, 0.3, 0.0), (40.0, 50.0, 60.0))]
    ref, fast = both_paths(monkeypatch, scene, CAM, pose, water="jerlov-II", lights=lamps, seed=3,
                           options=OpticalOptions(noise=SensorNoise()))
    assert np.any(ref.body < 0) and np.any(ref.body >= 0)  # some open water in view
    assert len(np.unique(ref.clear[ref.body >= 0].round(4), axis=0)) > 2  # the texture shows
    assert_same_frame(ref, fast)


def test_forward_scatter_and_veil_kernels_equal_numpy(monkeypatch):
    rng = np.random.default_rng(7)
    cam = PinholeCamera.from_sensor(300, 200)  # enough pixels for the two-thread binning
    H, W = cam.height, cam.width
    depth = rng.uniform(0.5, 9.0, (H, W))
    depth[rng.random((H, W)) < 0.1] = np.inf
    src = rng.random((H, W, 3)).astype(np.float32) * np.isfinite(depth)[..., None]
    pose = Pose.look_at((0.0, -3.0, 1.0), (0.0, 0.0, 0.0), body="camera")
    water = as_water("jerlov-II")
    lights = resolve_lights(None, pose)
    out = {}
    for mode in ("numpy", ""):
        monkeypatch.setenv("OAS_KERNELS", mode)
        out[mode] = (forward_scatter(src, depth, cam, B=0.05), forward_scatter(src, depth, cam, B=0.05, threads=2),
                     backscatter(cam, pose, depth, water, lights))
    assert np.array_equal(out["numpy"][0], out["numpy"][1])
    for a, b in zip(out["numpy"], out[""]):
        assert np.abs(a - b).max() <= 2e-6 * np.abs(a).max()
    with pytest.raises(ValueError, match="depth"):
        bad = depth.copy()
        bad[3, 4] = np.nan
        backscatter(cam, pose, bad, water, lights)


def test_import_and_help_stay_free_of_numba():
    code = "import sys, optiacoustic, optiacoustic.optical; print('numba' in sys.modules)"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "False"
    # every module `oas --help` imports is listed by -X importtime on stderr
    out = subprocess.run([sys.executable, "-X", "importtime", "-m", "optiacoustic.cli", "--help"], capture_output=True,
                         text=True)
    assert out.returncode == 0 and "Usage" in out.stdout
    assert "numba" not in out.stderr
