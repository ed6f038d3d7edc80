"""The ray caster against analytic ray-plane and ray-sphere intersections."""

import re

import numpy as np
import pytest

from optiacoustic.frames import Pose
from optiacoustic.raycast import RayCaster
from optiacoustic.scene import Body, Box, Plane, Scene, Sphere

C = np.array([0.3, 4.0, 1.2])
R = 0.8


@pytest.fixture(scope="module")
def caster():
    scene = Scene([
        Body("floor", Plane(size=(50, 50))),
        Body("ball", Sphere(radius=R), Pose(np.eye(3), C)),
    ])
    return RayCaster(scene)


def sphere_hit(o, d):
    """First intersection distance of unit rays with the analytic sphere (inf if none)."""
    oc = o - C
    b = np.einsum("ij,ij->i", oc, d)
    c = np.einsum("ij,ij->i", oc, oc) - R * R
    disc = b * b - c
    t = -b - np.sqrt(np.where(disc > 0, disc, np.nan))
    return np.where((disc > 0) & (t > 0), t, np.inf)


def test_against_analytic_sphere_and_plane(caster):
    rng = np.random.default_rng(0)
    n = 50000
    o = np.array([0.0, -1.0, 2.0])
    d = rng.normal(size=(n, 3))
    d[:, 1] = np.abs(d[:, 1]) + 1.0
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    hits = caster.cast(o, d)
    t_s = sphere_hit(np.broadcast_to(o, d.shape), d)
    t_p = np.where(d[:, 2] < 0, -o[2] / d[:, 2], np.inf)
    t_p = np.where(np.abs(o[:2] + t_p[:, None] * d[:, :2]).max(1) <= 25, t_p, np.inf)
    t = np.minimum(t_s, t_p)
    on_sphere = (t_s < t_p) & np.isfinite(t_s)
    # tessellation (icosphere, 5 subdivisions) bounds the distance error; away from the silhouette it is tiny
    graze = np.abs(np.einsum("ij,ij->i", (o + t_s[:, None] * d - C) / R, d))
    good = on_sphere & (graze > 0.2)
    assert np.all(hits.body[good] == 1)
    assert np.max(np.abs(hits.distance[good] - t[good])) < 5e-4 * R / 0.2
    floor = (t_p < t_s) & np.isfinite(t_p)
    assert np.all(hits.body[floor & (t_s == np.inf)] == 0)
    assert np.allclose(hits.distance[floor & (t_s == np.inf)], t_p[floor & (t_s == np.inf)], rtol=1e-5)
    # smooth normals follow the true sphere normal closely (interpolated vertex normals)
    true_n = (hits.point[good] - C) / R
    assert np.max(np.linalg.norm(hits.normal[good] - true_n, axis=1)) < 2e-3
    assert np.allclose(hits.normal[floor & (t_s == np.inf)], [0, 0, 1])
    # misses
    miss = ~np.isfinite(t)
    assert np.all(hits.body[miss] == -1) and np.all(np.isinf(hits.distance[miss]))
    assert np.all(np.isnan(hits.normal[miss])) and np.all(np.isnan(hits.point[miss]))


def test_threads_do_not_change_results():
    scene = Scene([Body("b", Box(size=(1, 2, 3)), Pose(np.eye(3), [0, 5, 0]))])
    rng = np.random.default_rng(3)
    d = rng.normal(size=(60000, 3)) + [0, 3, 0]
    a = RayCaster(scene, threads=1).cast(np.zeros(3), d)
    b = RayCaster(scene, threads=2).cast(np.zeros(3), d)
    assert np.array_equal(a.body, b.body) and np.array_equal(a.distance, b.distance)


@pytest.mark.parametrize("value", ["abc", "0", "-2", "1.5", "\u00b2", "2 threads"])
def test_bad_oas_threads_is_an_error_naming_the_variable(monkeypatch, value):
    from optiacoustic.raycast import default_threads

    monkeypatch.setenv("OAS_THREADS", value)
    with pytest.raises(ValueError, match=r"OAS_THREADS: expected a whole number .* got " + re.escape(repr(value))):
        default_threads()


def test_oas_threads_read_and_unset(monkeypatch):
    import os

    from optiacoustic.raycast import default_threads

    monkeypatch.setenv("OAS_THREADS", " 3 ")
    assert default_threads() == 3
    monkeypatch.setenv("OAS_THREADS", "")  # empty: as unset
    assert default_threads() == len(os.sched_getaffinity(0))
    monkeypatch.delenv("OAS_THREADS")
    assert default_threads() == len(os.sched_getaffinity(0))


@pytest.mark.parametrize("threads", [0, -1, 1.5, True, "2"])
def test_bad_thread_count_is_refused(threads):
    scene = Scene([Body("b", Box(size=(1, 1, 1)))])
    expected = r"RayCaster: threads must be a whole number, 1 or more .* got " + re.escape(repr(threads))
    with pytest.raises(ValueError, match=expected):
        RayCaster(scene, threads=threads)
    assert RayCaster(scene, threads=np.int64(2)).threads == 2


def test_shapes_max_distance_occlusion(caster):
    d = np.zeros((2, 3, 3))
    d[..., 1] = 1.0
    h = caster.cast([0.3, -1.0, 1.2], d)
    assert h.distance.shape == (2, 3) and h.normal.shape == (2, 3, 3)
    assert np.allclose(h.distance, 5.0 - R - 1e-9, atol=1e-4)
    h2 = caster.cast([0.3, -1.0, 1.2], d, max_distance=2.0)
    assert np.all(h2.body == -1)
    occ = caster.occluded([0.3, -1.0, 1.2], [0, 1, 0], max_distance=np.array([1.0, 10.0]))
    assert occ.tolist() == [False, True]


def test_bad_input(caster):
    with pytest.raises(ValueError, match="directions"):
        caster.cast(np.zeros(3), [[0, 0, 0]])
    with pytest.raises(ValueError, match="directions"):
        caster.cast(np.zeros(3), [[np.nan, 0, 1]])
    with pytest.raises(ValueError, match="broadcast"):
        caster.cast(np.zeros((4, 3)), np.ones((5, 3)))
    with pytest.raises(ValueError, match="max_distance"):
        caster.cast(np.zeros(3), [0, 1, 0], max_distance=-1)
    with pytest.raises(TypeError):
        RayCaster("not a scene")


def test_vectorised_upload_gives_the_same_hits_as_embreex_trianglemesh(monkeypatch):
    """The ctypes upload (one numpy copy per buffer) against embreex's own element-by-element upload."""
    import optiacoustic._embree_upload as up
    from optiacoustic import scenes
    from optiacoustic.raycast import RayCaster

    scene = scenes.get("thesis_scene1")
    fast = RayCaster(scene)
    from embreex.rtcore_scene import EmbreeScene

    tri = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0]], np.float32)
    assert up._library_of(EmbreeScene()) is not None  # the wheel's Embree was found
    assert up.upload_triangles(EmbreeScene(), tri, np.array([[0, 1, 2]], np.int32)) == 0  # the fast path is taken
    monkeypatch.setattr(up, "upload_triangles", lambda *a, **k: None)  # forces TriangleMesh
    slow = RayCaster(scene)
    rng = np.random.default_rng(11)
    o = np.column_stack([rng.uniform(-5, 5, (20000, 2)), rng.uniform(0.3, 4.0, 20000)])
    d = rng.normal(size=o.shape)
    a, b = fast.cast(o, d), slow.cast(o, d)
    assert 0.2 < a.hit.mean() < 0.9
    assert np.array_equal(a.distance, b.distance) and np.array_equal(a.body, b.body)
    assert np.array_equal(a.triangle, b.triangle)
    assert np.array_equal(a.normal, b.normal, equal_nan=True)


@pytest.mark.parametrize("threads", [1, 2])
def test_intersect_each_hands_over_each_chunk_as_intersect_raw_casts_it(caster, threads):
    # every ray handed over exactly once, with intersect_raw's output for it; distances checked
    # against the analytic sphere for the rays that hit the ball
    rng = np.random.default_rng(5)
    n = 9000
    d = rng.normal(size=(n, 3)) * 0.1 + (C - [0, 0, 8]) / np.linalg.norm(C - [0, 0, 8])  # about the ball
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    o = np.tile(np.array([0, 0, 8.0]), (n, 1))
    o32, d32 = o.astype(np.float32), d.astype(np.float32)
    ref = caster.intersect_raw(o32, d32, np.full(n, 1e3, np.float32), normals=False)
    old = caster.threads
    caster.threads = threads
    got = {k: np.full(n, -7, ref[i].dtype) for i, k in enumerate(("t", "g", "p", "u", "v"))}
    seen = np.zeros(n, int)
    try:
        def each(a, b, t, g, p, u, v):
            seen[a:b] += 1
            for k, arr in zip(("t", "g", "p", "u", "v"), (t, g, p, u, v)):
                assert len(arr) == b - a
                got[k][a:b] = arr

        caster.intersect_each(o32, d32, np.full(n, 1e3, np.float32), each)
    finally:
        caster.threads = old
    assert np.all(seen == 1)
    for i, k in enumerate(("t", "g", "p")):
        assert np.array_equal(got[k], ref[i])
    miss_dist = np.linalg.norm(np.cross(C - o, d), axis=1)  # the ray's closest approach to the ball's centre
    ball = (got["g"] == 1) & (miss_dist < 0.5 * R)  # away from the silhouette, where the facets are steep
    assert ball.sum() > 100
    assert np.max(np.abs(got["t"][ball] - sphere_hit(o, d)[ball])) < 5e-4 * R / 0.2  # the tessellated ball, as above


def test_a_scene_far_from_the_origin_renders_as_near_it_or_is_refused():
    """Scene and sensors moved together by (T, T, 0) render the same frames (float32 geometry) up to
    MAX_COORDINATE; beyond it the caster refuses rather than render shadow acne and drifted depth."""
    import dataclasses

    from optiacoustic import PinholeCamera, Pose, Scene, SonarSpec, scenes, simulate_optical, simulate_sonar
    from optiacoustic.raycast import MAX_COORDINATE
    from optiacoustic.scene import SceneError

    sc = scenes.get("thesis_scene1")
    spec = SonarSpec.preset("blueview-p900-90")
    cam = PinholeCamera.from_sensor(300, 200, (36, 24), 50)
    s_pose = Pose.look_at((0, -6, 2), (0, 0, 0))
    c_pose = Pose.look_at((-0.25, -6, 2), (0, 0, 0), body="camera")
    f0, o0 = simulate_sonar(sc, spec, s_pose, noise=False), simulate_optical(sc, cam, c_pose)
    for off, tol in ((4e3, (2e-3, 5e-4)), (3 * MAX_COORDINATE, None)):
        T = Pose(np.eye(3), np.array([off, off, 0.0]))
        moved = Scene([dataclasses.replace(b, pose=T @ b.pose) for b in sc])
        if tol is None:
            with pytest.raises(SceneError, match="local coordinates"):
                simulate_sonar(moved, spec, T @ s_pose, noise=False)
            continue
        f1, o1 = simulate_sonar(moved, spec, T @ s_pose, noise=False), simulate_optical(moved, cam, T @ c_pose)
        assert np.abs(f1.intensity - f0.intensity).sum() / f0.intensity.sum() < tol[0]  # measured 6.9e-4
        assert np.abs(o1.image - o0.image).sum() / o0.image.sum() < tol[1]  # measured 9.6e-5


def test_a_sonar_inside_a_closed_body_is_refused_as_a_camera_is():
    # was: an all-zero frame (inside a sphere) or its inner walls (inside a box), rc 0
    from optiacoustic import SonarSpec, scenes, simulate_sonar

    sc = scenes.get("thesis_scene1")
    spec = SonarSpec.preset("blueview-p900-90")
    with pytest.raises(ValueError, match="the sonar at .* is inside body 'sphere_white'"):
        simulate_sonar(sc, spec, Pose.look_at((0.5, -0.8, 0.45), (0, 0, 0)), noise=False)
    caster = RayCaster(sc)
    assert caster.enclosing_body((0.5, -0.8, 0.45)) == sc.body_names().index("sphere_white")
    assert caster.enclosing_body((0, -6, 2)) == -1 and caster.enclosing_body((0, 0, -1)) == -1  # under the seabed plane
