"""The underwater camera against analytic cases and an independent quadrature of the veil."""

import numpy as np
import pytest
from scipy.integrate import quad

from optiacoustic import PinholeCamera, Pose, scenes
from optiacoustic.optical import Light, OpticalOptions, PhaseFunction, SensorNoise, Water, forward_scatter, simulate_optical
from optiacoustic.scene import Body, Box, Material, Plane, Scene

CAM = PinholeCamera.from_sensor(150, 100)  # the thesis camera's field of view, 4x fewer pixels
THESIS_POSE = Pose.look_at((-0.25, -6.0, 2.0), (0.0, 0.0, 0.0), body="camera")
NO_FS = OpticalOptions(forward_scatter=False)


@pytest.fixture(scope="module")
def scene1():
    return scenes.get("thesis_scene1")


def world_rays(camera, pose):
    return pose.directions_to_world(camera.pixel_rays())


# --------------------------------------------------------------------------- direct term
def test_no_water_gives_the_clear_image_exactly(scene1):
    f = simulate_optical(scene1, CAM, THESIS_POSE, water="clear")
    assert np.array_equal(f.image, f.clear)
    assert np.array_equal(f.attenuated, f.clear)
    assert np.array_equal(f.forward_scatter, f.clear)
    assert not np.any(f.backscatter)
    assert np.all(f.clear >= 0) and np.any(f.clear > 0)


def test_direct_term_of_a_lambertian_plane_is_analytic():
    """rho / pi * I cos(gamma) / R_s^2 for a plane z = 0 lit by an isotropic point light (no water)."""
    rho = np.array([0.6, 0.5, 0.4])
    scene = Scene([Body("floor", Plane(size=(200.0, 200.0)), Pose.identity(), Material(color=tuple(rho)))])
    pose = Pose.look_at((0.3, -3.0, 2.5), (0.0, 0.0, 0.0), body="camera")
    light_pos = np.array([1.0, -1.0, 3.0])
    inten = np.array([50.0, 40.0, 30.0])
    f = simulate_optical(scene, CAM, pose, water="clear", lights=Light(tuple(light_pos), tuple(inten), frame="world"))
    d = world_rays(CAM, pose)
    t = -pose.t[2] / d[..., 2]                      # ray-plane intersection, independent of the caster
    P = pose.t + t[..., None] * d
    v = light_pos - P
    Rs = np.linalg.norm(v, axis=-1)
    cosg = v[..., 2] / Rs
    ref = rho / np.pi * inten * (cosg / Rs ** 2)[..., None]
    np.testing.assert_allclose(f.depth, t, rtol=1e-5)
    np.testing.assert_allclose(f.clear, ref, rtol=2e-4)


def test_attenuation_is_exp_of_both_legs(scene1):
    """attenuated / clear = exp(-c (R_s + R_c)) per channel, with R_s from the light to the surface point."""
    light = Light((1.0, -5.0, 3.0), 100.0, frame="world")
    w = Water.preset("thesis")
    f = simulate_optical(scene1, CAM, THESIS_POSE, water=w, lights=light)
    d = world_rays(CAM, THESIS_POSE)
    P = THESIS_POSE.t + f.depth[..., None] * d
    Rs = np.linalg.norm(np.asarray(light.position) - P, axis=-1)
    lit = np.all(f.clear > 1e-6, axis=-1)
    assert lit.mean() > 0.8
    ratio = f.attenuated[lit] / f.clear[lit]
    ref = np.exp(-(Rs[lit] + f.depth[lit])[:, None] * w.c)
    np.testing.assert_allclose(ratio, ref, rtol=1e-4)


def test_red_fades_faster_than_blue(scene1):
    f = simulate_optical(scene1, CAM, THESIS_POSE, water="thesis", options=NO_FS)
    lit = np.all(f.clear > 1e-6, axis=-1)
    tr = f.attenuated[lit] / f.clear[lit]
    assert np.all(tr[:, 0] < tr[:, 1]) and np.all(tr[:, 1] < tr[:, 2])
    # and the red-to-blue ratio falls with range
    rng = f.depth[lit]
    edges = np.quantile(rng, [0, 0.25, 0.5, 0.75, 1.0])
    rb = [np.mean(tr[(rng >= a) & (rng <= b), 0] / tr[(rng >= a) & (rng <= b), 2]) for a, b in zip(edges[:-1], edges[1:])]
    assert np.all(np.diff(rb) < 0)


def test_shadow_of_a_box():
    """A ground point whose segment to the light crosses the box is dark; one beside it is lit."""
    scene = Scene([
        Body("floor", Plane(size=(40.0, 40.0)), Pose.identity(), Material(color=(0.5, 0.5, 0.5))),
        Body("box", Box(size=(1.0, 1.0, 1.0)), Pose.from_euler_deg((0, 0, 0.5)), Material(color=(0.5, 0.5, 0.5))),
    ])
    light = Light((2.0, 0.0, 3.0), 100.0, frame="world")
    cam = PinholeCamera.from_sensor(61, 41)
    for target, shadowed in (((-1.0, 0.0, 0.0), True), ((-1.0, 1.5, 0.0), False)):
        pose = Pose.look_at((-4.0, target[1], 3.0), target, body="camera")
        f = simulate_optical(scene, cam, pose, water="clear", lights=light)
        g = simulate_optical(scene, cam, pose, water="clear", lights=light, options=OpticalOptions(shadows=False))
        assert f.body[20, 30] == 0
        assert g.clear[20, 30, 0] > 0
        assert (f.clear[20, 30, 0] == 0) == shadowed


# --------------------------------------------------------------------------- backscatter
def _quad_backscatter(pose, d_world, depth, water_a, water_b, vsf, light_pos, inten, G, spot=None):
    """Independent single-scattering integral along one ray (scipy.integrate.quad)."""
    c = np.asarray(water_a) + np.asarray(water_b)
    out = []
    for ch in range(3):
        def integrand(r):
            x = pose.t + r * d_world
            v = x - light_pos
            Rb = np.linalg.norm(v)
            cos_psi = -(v / Rb) @ d_world
            s = 1.0 if spot is None else max(float((v / Rb) @ spot), 0.0)
            return vsf(cos_psi, ch) * inten[ch] * s * np.exp(-G[ch] * Rb) / Rb ** 2 * np.exp(-c[ch] * r)
        brk = [0.0, 0.5, 2.0, 10.0]
        upper = depth if np.isfinite(depth) else np.inf
        pts = [b for b in brk if b < upper] + [upper]
        out.append(sum(quad(integrand, a, b, limit=400, epsrel=1e-9, epsabs=0)[0] for a, b in zip(pts[:-1], pts[1:])))
    return np.array(out)


@pytest.fixture(scope="module")
def open_water_view():
    scene = scenes.get("klein_bottle")
    pose = Pose.look_at((0.0, -3.0, 0.0), (0.0, 0.0, 3.0), body="camera")  # looks up, away from the bottle
    return scene, pose


def _hg_water(g=0.7):
    return Water((0.2, 0.1, 0.05), (0.3, 0.35, 0.4), PhaseFunction.henyey_greenstein(g))


def _hg(cos_psi, g=0.7):
    return (1 - g * g) / (4 * np.pi * (1 + g * g - 2 * g * cos_psi) ** 1.5)


@pytest.mark.parametrize("spot", [False, True])
def test_backscatter_of_open_water_matches_quadrature(open_water_view, spot):
    scene, pose = open_water_view
    w = _hg_water()
    light = (Light((0.4, -0.2, 0.0), (80.0, 90.0, 100.0), (0.0, 0.0, 1.0), 60.0) if spot
             else Light((0.4, -0.2, 0.0), (80.0, 90.0, 100.0)))
    f = simulate_optical(scene, CAM, pose, water=w, lights=light, options=NO_FS)
    lw = f.lights[0]
    axis = np.asarray(lw.direction) if spot else None
    for v, u in ((50, 75), (3, 4), (96, 145), (10, 140), (90, 10)):
        assert f.body[v, u] < 0
        d = pose.directions_to_world(CAM.pixel_rays(np.array([u, v], float)))
        ref = _quad_backscatter(pose, d, np.inf, w.a, w.b, lambda m, ch: w.b[ch] * _hg(m), np.asarray(lw.position),
                                np.asarray(lw.intensity), w.c, axis)
        np.testing.assert_allclose(f.backscatter[v, u], ref, rtol=0.02)


def test_backscatter_of_thesis_water_matches_quadrature(open_water_view):
    """Kopelevich + molecular VSF, forward scatter on the lamp leg (G), default slices and grid."""
    from optiacoustic.optical.render import forward_scatter_G

    scene, pose = open_water_view
    w = Water.preset("thesis")
    f = simulate_optical(scene, CAM, pose, water=w)
    G = forward_scatter_G(w, OpticalOptions())
    lw = f.lights[0]
    for v, u in ((50, 75), (5, 140), (95, 5)):
        d = pose.directions_to_world(CAM.pixel_rays(np.array([u, v], float)))
        ref = _quad_backscatter(pose, d, np.inf, w.a, w.b, lambda m, ch: float(w.vsf(m)[ch]),
                                np.asarray(lw.position), np.asarray(lw.intensity), G, np.asarray(lw.direction))
        np.testing.assert_allclose(f.backscatter[v, u], ref, rtol=0.02)


def test_backscatter_stops_at_the_surface():
    """On a seabed pixel the integral runs from the camera to the surface only."""
    scene = scenes.get("flat_seabed")
    pose = Pose.look_at((0.0, -3.0, 2.0), (0.0, 0.0, 0.0), body="camera")
    w = _hg_water(0.0).scaled(0.2)  # isotropic and clear: the water beyond the seabed would add veil
    # a lamp above the seabed ahead of the camera lights water both before and beyond the surface
    light = Light((0.0, 0.0, 1.5), 100.0, frame="world")
    f = simulate_optical(scene, CAM, pose, water=w, lights=light, options=NO_FS)
    pos, inten = np.asarray(light.position), np.asarray(light.intensity)
    for v, u in ((50, 75), (95, 10), (20, 130)):
        assert np.isfinite(f.depth[v, u])
        d = pose.directions_to_world(CAM.pixel_rays(np.array([u, v], float)))
        vsf = lambda m, ch: w.b[ch] * _hg(m, 0.0)  # noqa: E731
        ref = _quad_backscatter(pose, d, float(f.depth[v, u]), w.a, w.b, vsf, pos, inten, w.c)
        beyond = _quad_backscatter(pose, d, np.inf, w.a, w.b, vsf, pos, inten, w.c)
        assert np.all(beyond > 1.05 * ref)  # the cut matters here (by more than the 2 % tolerance)
        np.testing.assert_allclose(f.backscatter[v, u], ref, rtol=0.02)


def test_backscatter_converges_with_slices(scene1):
    b = {n: simulate_optical(scene1, CAM, THESIS_POSE, options=OpticalOptions(slices=n)).backscatter for n in (32, 64)}
    change = np.abs(b[64] - b[32]) / b[64]
    assert change.max() < 0.01
    assert change.max() > 0  # it is a discretisation, not an exact formula


def test_coarse_backscatter_grid_matches_full_resolution(scene1):
    """The veil computed on the default 16-px grid and remapped equals the per-pixel one, object edges included."""
    coarse = simulate_optical(scene1, CAM, THESIS_POSE).backscatter
    full = simulate_optical(scene1, CAM, THESIS_POSE, options=OpticalOptions(backscatter_step=1)).backscatter
    rel = np.abs(coarse - full) / full
    assert rel.max() < 0.01


def test_backscatter_saturates_with_distance():
    """The veil of a pixel grows with the distance to its surface and tends to the open-water value."""
    pose = Pose.look_at((0.0, 0.0, 0.0), (0.0, 1.0, 0.0), body="camera")
    w = Water.preset("jerlov-1C")
    vals = []
    for dist in (0.5, 1.0, 2.0, 4.0, 8.0):
        scene = Scene([Body("wall", Plane(size=(100.0, 100.0)), Pose.from_euler_deg((0, dist, 0), (90, 0, 0)),
                            Material(color=(0.0, 0.0, 0.0)))])
        vals.append(simulate_optical(scene, CAM, pose, water=w).backscatter[50, 75])
    far = simulate_optical(scenes.get("klein_bottle"), CAM, Pose.look_at((0, 5, 0), (0, 6, 0), body="camera"),
                           water=w).backscatter[50, 75]
    vals = np.array(vals)
    assert np.all(np.diff(vals, axis=0) > 0)
    np.testing.assert_allclose(vals[-1], far, rtol=0.02)


def test_contrast_falls_with_turbidity(scene1):
    """Michelson contrast between the white sphere and the seabed around it, in ever more turbid water."""
    base = Water.preset("thesis")
    contrast = []
    for k in (0.0, 1.0, 2.0, 4.0, 8.0, 16.0):
        f = simulate_optical(scene1, CAM, THESIS_POSE, water=base.scaled(k))
        lum = f.image @ np.array([0.2126, 0.7152, 0.0722])
        sphere = f.body == scene1.body_id("sphere_white")
        ring = (f.body == scene1.body_id("seabed")) & ~sphere
        lo, hi = lum[sphere].mean(), lum[ring].mean()
        contrast.append((lo - hi) / (lo + hi))
    assert np.all(np.diff(contrast) < 0), contrast


# --------------------------------------------------------------------------- forward scatter
@pytest.mark.parametrize("B, R", [(0.01, 1.0), (0.03, 6.0), (0.05, 10.0)])
def test_forward_scatter_conserves_light_and_has_the_stated_width(B, R):
    """A point's light spreads into a Gaussian of the stated sigma; what stays in the image is
    exactly the Gaussian's mass inside the image borders (no light created or lost inside)."""
    from scipy.special import ndtr

    cam = PinholeCamera.from_sensor(601, 401)
    src = np.zeros((401, 601, 3), np.float32)
    src[200, 300] = (1.0, 2.0, 3.0)
    depth = np.full((401, 601), np.inf)
    depth[200, 300] = R
    out = forward_scatter(src, depth, cam, B=B)
    sigma = B * R / (np.pi * np.sqrt(2 * np.log(2))) * np.sqrt(cam.fx * cam.fy)
    inside = (ndtr(300.5 / sigma) - ndtr(-300.5 / sigma)) * (ndtr(200.5 / sigma) - ndtr(-200.5 / sigma))
    # exact inside; the reduced grid treats the border cells approximately (1 % of the total here)
    np.testing.assert_allclose(out.sum(axis=(0, 1)), src.sum(axis=(0, 1)) * inside, rtol=3e-3 if inside > 0.99 else 0.015)
    if inside > 0.99:
        v, u = np.indices(out.shape[:2])
        wgt = out[..., 0] / out[..., 0].sum()
        var_u = np.sum(wgt * (u - np.sum(wgt * u)) ** 2)
        assert np.sqrt(var_u) == pytest.approx(sigma, rel=0.05)


def test_forward_scatter_blur_grows_with_range():
    cam = PinholeCamera.from_sensor(600, 400)
    widths = []
    for R in (2.0, 4.0, 8.0):
        src = np.zeros((400, 600, 3), np.float32)
        src[200, 300] = 1.0
        depth = np.full((400, 600), np.inf)
        depth[200, 300] = R
        out = forward_scatter(src, depth, cam, B=0.03)[..., 0]
        wgt = out / out.sum()
        u = np.arange(600)
        widths.append(np.sqrt(np.sum(wgt.sum(0) * (u - 300) ** 2)))
    np.testing.assert_allclose(np.array(widths) / widths[0], [1, 2, 4], rtol=0.1)


def test_forward_scatter_in_a_frame_adds_only_what_attenuation_removed(scene1):
    """Forward scatter returns light that narrow-beam attenuation counted as lost, never more:
    at most e^{-G (R_s + R_c)} of the surface's light survives on the two legs."""
    from optiacoustic.optical.render import forward_scatter_G

    w = Water.preset("jerlov-IB")
    pose = Pose.look_at((-0.25, -3.5, 1.5), (0.0, 0.0, 0.3), body="camera")
    light = Light((0.4, -0.2, 0.0), 100.0)
    f = simulate_optical(scene1, CAM, pose, water=w, lights=light)
    added = f.forward_scatter - f.attenuated
    assert added.min() > -1e-7
    G = forward_scatter_G(w, OpticalOptions())
    d = world_rays(CAM, pose)
    P = pose.t + f.depth[..., None] * d
    Rs = np.linalg.norm(np.asarray(f.lights[0].position) - P, axis=-1)[..., None]
    Rc = f.depth[..., None]
    # the same surfaces with G instead of c on both legs (analytic rescaling of the attenuated image)
    kept = f.attenuated * np.exp((w.c - G) * (Rs + Rc))
    budget = (kept - f.attenuated).sum(axis=(0, 1))
    total = added.sum(axis=(0, 1))
    assert np.all(total <= budget * 1.001) and np.all(total >= 0.7 * budget)  # the rest left over the border
    g = simulate_optical(scene1, CAM, pose, water=w, lights=light, options=NO_FS)
    assert np.array_equal(g.forward_scatter, g.attenuated)


# --------------------------------------------------------------------------- noise, outputs
def test_sensor_noise_is_seeded_and_unbiased(scene1):
    a = simulate_optical(scene1, CAM, THESIS_POSE, seed=3)
    b = simulate_optical(scene1, CAM, THESIS_POSE, seed=3)
    c = simulate_optical(scene1, CAM, THESIS_POSE, seed=4)
    clean = simulate_optical(scene1, CAM, THESIS_POSE)
    assert np.array_equal(a.image, b.image) and not np.array_equal(a.image, c.image)
    assert np.array_equal(clean.image, clean.forward_scatter + clean.backscatter)
    from optiacoustic.optical import auto_exposure

    sn = SensorNoise()
    k = sn.full_well / auto_exposure(clean.image)
    n = clean.image * k
    z = (a.image * k - n) / np.sqrt(n + sn.read_noise ** 2)
    # 45000 standard normal residuals: mean within 5 standard errors, spread within 3 %
    assert abs(z.mean()) < 5 / np.sqrt(z.size)
    assert 0.97 < z.std() < 1.03


def test_frame_outputs(scene1, tmp_path):
    f = simulate_optical(scene1, CAM, THESIS_POSE)
    assert f.image.dtype == np.float32 and f.image.shape == (100, 150, 3)
    assert f.depth.shape == (100, 150) and f.body.dtype == np.int32
    assert set(np.unique(f.body)) <= set(range(len(scene1.bodies)))
    n = np.linalg.norm(f.normal, axis=-1)
    np.testing.assert_allclose(n, 1, atol=1e-4)
    with pytest.raises(ValueError):
        f.image[0, 0, 0] = 1.0
    p = f.save_npz(tmp_path / "o.npz")
    z = np.load(p)
    for key in ("image", "clear", "depth", "body", "backscatter", "K", "pose_R"):
        assert key in z.files
    png = f.save_png(tmp_path / "o.png")
    import cv2

    img = cv2.imread(str(png))
    assert img.shape == (100, 150, 3)
    # bluish-green: blue and green dominate red in the final image
    m = f.to_srgb8().reshape(-1, 3).mean(0)
    assert m[2] > m[0] and m[1] > m[0]


def test_open_water_depth_and_body():
    f = simulate_optical(scenes.get("klein_bottle"), CAM, Pose.look_at((0, 5, 0), (0, 6, 0), body="camera"))
    assert np.all(np.isinf(f.depth)) and np.all(f.body == -1)
    assert np.all(np.isnan(f.normal)) and not np.any(f.clear)


# --------------------------------------------------------------------------- bad input
def test_camera_inside_a_body(scene1):
    with pytest.raises(ValueError, match="camera .* inside body 'sphere_white'"):
        simulate_optical(scene1, CAM, Pose.look_at((0.5, -0.8, 0.45), (0, 0, 0), body="camera"))


def test_light_inside_a_body(scene1):
    with pytest.raises(ValueError, match=r"lights\[1\]: .* inside body 'cuboid_red'"):
        simulate_optical(scene1, CAM, THESIS_POSE,
                         lights=[Light((0.4, 0, 0)), Light((-1.6, 0.2, 0.3), frame="world")])


def test_bad_arguments(scene1):
    with pytest.raises(ValueError, match="unknown water type"):
        simulate_optical(scene1, CAM, THESIS_POSE, water="swamp")
    with pytest.raises(ValueError, match="Water.a"):
        simulate_optical(scene1, CAM, THESIS_POSE, water=Water((-1, 0, 0), (0, 0, 0)))
    with pytest.raises(ValueError, match="pose"):
        simulate_optical(scene1, CAM, np.eye(4))
    with pytest.raises(ValueError, match="OpticalOptions.slices"):
        OpticalOptions(slices=0)
    with pytest.raises(ValueError, match="OpticalOptions.G"):
        simulate_optical(scene1, CAM, THESIS_POSE, options=OpticalOptions(G=1.0))
    with pytest.raises(ValueError, match="Light.intensity"):
        Light(intensity=(-1, 0, 0))
    with pytest.raises(ValueError, match="Light.cone_deg"):
        Light(cone_deg=30)


def test_camera_below_the_seabed_is_documented_not_an_error():
    """A one-sided plane encloses nothing: a camera under the seabed sees its underside (body 0)."""
    scene = scenes.get("flat_seabed")
    f = simulate_optical(scene, CAM, Pose.look_at((0.0, 0.0, -1.0), (0.0, 3.0, 0.0), body="camera"), water="clear")
    assert np.all(f.body[:40] == 0)          # the upper half of the view looks up at the plane
    assert np.all(f.normal[:40, :, 2] < 0)   # shaded on the side facing the camera
