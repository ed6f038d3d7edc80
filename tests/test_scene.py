"""Scenes: schema, validation errors naming file/body/field, meshes, tessellation, built-ins."""

import json

import numpy as np
import pytest
import trimesh

from optiacoustic import scenes

from optiacoustic.scene import Body, Box, Cylinder, Ellipsoid, KleinBottle, Scene, SceneError, Sphere

ISSUE_YAML = """
bodies:
  - name: seabed
    shape: plane
    size: [60, 60]
    pose: {position: [0, 0, 0], rotation_deg: [0, 0, 0]}
    material: {reflectivity: 0.5, color: [0.55, 0.5, 0.4]}
  - {name: ball, shape: sphere, radius: 0.5, pose: {position: [1, 0, 0.5]}}
  - {name: tank, shape: cylinder, radius: 0.3, height: 1.0, pose: {position: [2, 1, 0.5]}}
  - {name: egg, shape: ellipsoid, radii: [0.6, 0.3, 0.3], pose: {position: [-1, 1, 0.3]}}
  - {name: rock, shape: mesh, file: rock.obj, scale: 1.0}
"""


@pytest.fixture()
def scene_dir(tmp_path):
    rock = trimesh.creation.icosphere(subdivisions=2, radius=0.4)
    rock.vertices *= [1.0, 0.7, 0.5]
    rock.export(tmp_path / "rock.obj")
    (tmp_path / "scene.yaml").write_text(ISSUE_YAML)
    return tmp_path


def test_issue_schema_loads(scene_dir):
    s = Scene.load(scene_dir / "scene.yaml")
    assert s.body_names() == ["seabed", "ball", "tank", "egg", "rock"]
    assert s.name == "scene"
    assert np.allclose(s.body("ball").pose.t, [1, 0, 0.5])
    surf = s.surfaces()
    # the sphere's tessellation lies on the sphere and its normals are radial
    ball = surf[1]
    d = ball.vertices - [1, 0, 0.5]
    assert np.allclose(np.linalg.norm(d, axis=1), 0.5)
    assert np.allclose(ball.normals, d / 0.5)
    # the mesh was read relative to the YAML file
    assert surf[4].n_faces == 320


def test_json_and_export_roundtrip(scene_dir, tmp_path):
    s = Scene.load(scene_dir / "scene.yaml")
    out = tmp_path / "sub" / "copy.json"
    s.save(out)
    data = json.loads(out.read_text())
    assert data["bodies"][4]["file"] == "../rock.obj"  # relative to the new file
    s2 = Scene.load(out)
    for a, b in zip(s.surfaces(), s2.surfaces()):
        assert np.allclose(a.vertices, b.vertices)


@pytest.mark.parametrize("name", scenes.names())
def test_builtins_roundtrip_through_yaml(name, tmp_path):
    s = scenes.get(name)
    assert s.view is not None and len(s) >= 1
    s.save(tmp_path / f"{name}.yaml")
    s2 = Scene.load(tmp_path / f"{name}.yaml")
    assert s2.body_names() == s.body_names()
    for a, b in zip(s.surfaces(), s2.surfaces()):
        assert np.allclose(a.vertices, b.vertices, atol=1e-6)
    for a, b in zip(s, s2):
        assert a.material == b.material


def _load(tmp_path, text):
    p = tmp_path / "bad.yaml"
    p.write_text(text)
    with pytest.raises(SceneError) as exc:
        Scene.load(p)
    return str(exc.value)


@pytest.mark.parametrize(
    "text, fragments",
    [
        ("bodies:\n  - {name: a, shape: torus, radius: 1}\n", ["bad.yaml", "body 'a'", "field 'shape'", "torus"]),
        ("bodies:\n  - {name: a, shape: sphere}\n", ["body 'a'", "field 'radius'", "required"]),
        ("bodies:\n  - {name: a, shape: sphere, radius: 1, colour: red}\n", ["body 'a'", "field 'colour'", "unknown field"]),
        ("bodies:\n  - {name: a, shape: box, size: [1, -2, 1]}\n", ["body 'a'", "field 'size[1]'", "greater than 0"]),
        ("bodies:\n  - {name: a, shape: sphere, radius: .nan}\n", ["body 'a'", "field 'radius'", "finite"]),
        ("bodies:\n  - {name: a, shape: sphere, radius: 1, pose: {position: [0, .nan, 0]}}\n", ["field 'pose.position'", "finite"]),
        ("bodies:\n  - {name: a, shape: sphere, radius: 1, pose: {rotation: [0, 0, 0]}}\n", ["field 'pose.rotation'"]),
        ("bodies:\n  - {name: a, shape: sphere, radius: 1, material: {reflectivity: 2}}\n", ["field 'material.reflectivity'", "less than or equal to 1"]),
        ("bodies:\n  - {name: a, shape: sphere, radius: 1, material: {color: [1, 0]}}\n", ["field 'material.color"]),
        ("bodies:\n  - {name: a, shape: mesh, file: nope.obj}\n", ["body 'a'", "field 'file'", "not found"]),
        ("bodies:\n  - {shape: sphere, radius: 1}\n", ["body #0", "field 'name'", "missing"]),
        ("bodies:\n  - {name: a, shape: sphere, radius: 1}\n  - {name: a, shape: sphere, radius: 2}\n", ["body 'a' (#1)", "duplicate"]),
        ("bodies: []\n", ["field 'bodies'"]),
        ("bodys:\n  - {name: a, shape: sphere, radius: 1}\n", ["field 'bodys'", "unknown top-level"]),
        ("bodies:\n  - {name: a, shape: sphere, radius: 1\n", ["not valid YAML"]),
    ],
)
def test_bad_scene_files_name_file_body_field(tmp_path, text, fragments):
    msg = _load(tmp_path, text)
    for f in fragments:
        assert f in msg, msg


def test_unreadable_mesh(tmp_path):
    (tmp_path / "junk.obj").write_text("this is not an obj file\n\x00\x01")
    msg = _load(tmp_path, "bodies:\n  - {name: rock, shape: mesh, file: junk.obj}\n")
    assert "body 'rock'" in msg and "field 'file'" in msg


def test_missing_file():
    with pytest.raises(SceneError, match="not found"):
        Scene.load("/nonexistent/scene.yaml")


def test_python_construction_validates():
    with pytest.raises(ValueError, match="radius"):
        Sphere(radius=-1)
    with pytest.raises(SceneError, match="unique"):
        Scene([Body("a", Sphere(radius=1)), Body("a", Sphere(radius=1))])
    with pytest.raises(SceneError, match="non-empty"):
        Body("", Sphere(radius=1))


def test_tessellations_are_closed_and_outward():
    for shape in (Box(size=(1, 2, 3)), Sphere(radius=0.7), Ellipsoid(radii=(0.6, 0.3, 0.2)), Cylinder(radius=0.3, height=1.2)):
        s = shape.tessellate()
        m = trimesh.Trimesh(s.vertices, s.faces, process=True)
        assert m.is_watertight, shape
        assert m.volume > 0, shape  # outward winding
        # shading normals point outward: positive dot with (vertex - centroid)
        assert np.all(np.einsum("ij,ij->i", s.normals, s.vertices) > 0), shape
    # analytic volumes within tessellation error
    assert np.isclose(trimesh.Trimesh(*_vf(Sphere(radius=1.0))).volume, 4 / 3 * np.pi, rtol=2e-3)
    assert np.isclose(trimesh.Trimesh(*_vf(Cylinder(radius=1, height=2))).volume, 2 * np.pi, rtol=1e-3)


def _vf(shape):
    s = shape.tessellate()
    return s.vertices, s.faces


def test_ellipsoid_normals_are_gradients():
    e = Ellipsoid(radii=(0.6, 0.3, 0.2))
    s = e.tessellate()
    g = s.vertices / np.array(e.radii) ** 2
    g /= np.linalg.norm(g, axis=1, keepdims=True)
    assert np.allclose(s.normals, g)


def test_klein_bottle_size():
    s = KleinBottle(height=0.5).tessellate()
    ext = s.vertices.max(0) - s.vertices.min(0)
    assert np.isclose(ext[2], 0.5, rtol=1e-2)
    assert np.all(np.isfinite(s.normals)) and np.allclose(np.linalg.norm(s.normals, axis=1), 1)


def test_rotation_convention_of_scene_files(tmp_path):
    # rotation_deg is about fixed x, then y, then z: a box long in x, turned 90 deg about z, is long in y
    p = tmp_path / "r.yaml"
    p.write_text("bodies:\n  - {name: b, shape: box, size: [4, 1, 1], pose: {rotation_deg: [0, 0, 90]}}\n")
    v = Scene.load(p).surfaces()[0].vertices
    ext = v.max(0) - v.min(0)
    assert np.allclose(ext, [1, 4, 1])


@pytest.mark.parametrize("ext", ["obj", "stl", "ply", "glb"])
def test_mesh_formats(tmp_path, ext):
    """Meshes load through trimesh from OBJ, STL, PLY and GLB with the same geometry."""
    rock = trimesh.creation.icosphere(subdivisions=2, radius=0.4)
    rock.export(tmp_path / f"rock.{ext}")
    (tmp_path / "s.yaml").write_text(f"bodies:\n  - {{name: rock, shape: mesh, file: rock.{ext}, scale: 2.0,"
                                     f" pose: {{position: [1, 2, 3]}}}}\n")
    surf = Scene.load(tmp_path / "s.yaml").surfaces()[0]
    assert surf.n_faces == len(rock.faces)
    assert np.allclose(np.linalg.norm(surf.vertices - [1, 2, 3], axis=1), 0.8, atol=1e-5)
    # smooth shading on a smooth mesh: vertex normals close to radial
    radial = (surf.vertices - [1, 2, 3]) / 0.8
    assert np.min(np.einsum("ij,ij->i", surf.normals, radial)) > 0.98


def test_smooth_shading_splits_creases_and_keeps_smooth_parts_smooth():
    import trimesh

    from optiacoustic.scene.normals import smooth_shading

    box = trimesh.creation.box((1.0, 2.0, 3.0))  # 8 shared vertices, 12 faces, 90 deg edges
    v, f, n = smooth_shading(box.vertices, box.faces, np.deg2rad(30))
    assert len(v) == 24  # every corner split three ways: flat faces
    fn = np.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]])
    fn /= np.linalg.norm(fn, axis=1, keepdims=True)
    assert np.allclose(n[f], fn[:, None, :], atol=1e-12)  # each corner carries its face's normal
    assert np.allclose(v[f], box.vertices[box.faces])  # the same triangles
    v2, f2, n2 = smooth_shading(box.vertices, box.faces, np.deg2rad(100))
    assert len(v2) == 8  # nothing split: one smooth patch
    assert np.all(np.einsum("ij,ij->i", n2, v2) > 0)  # outward
    # a sphere: one patch, normals radial
    ball = trimesh.creation.icosphere(subdivisions=3)
    v3, f3, n3 = smooth_shading(ball.vertices, ball.faces, np.deg2rad(30))
    assert len(v3) == len(ball.vertices)
    assert np.min(np.einsum("ij,ij->i", n3, v3 / np.linalg.norm(v3, axis=1, keepdims=True))) > 0.999


def test_merge_vertices_matches_trimesh_and_keeps_the_triangles():
    from optiacoustic.scene.normals import merge_vertices

    ball = trimesh.creation.icosphere(subdivisions=3)
    rng = np.random.default_rng(5)
    # an unindexed soup (as STL stores it), shuffled, plus unused vertices
    soup = ball.vertices[ball.faces].reshape(-1, 3)
    perm = rng.permutation(len(soup))
    V = np.concatenate([soup[perm], rng.normal(size=(7, 3))])
    F = np.argsort(perm).reshape(-1, 3)
    v, f = merge_vertices(V, F)
    assert np.array_equal(v[f], V[F])  # the same triangles, corner for corner
    assert len(v) == len(ball.vertices)  # the merge trimesh does (position only: the soup has no normals)
    ref = trimesh.Trimesh(V, F)  # process=True merges and drops unused vertices
    assert len(ref.vertices) == len(v)
    assert np.array_equal(np.unique(v.round(12), axis=0), np.unique(ref.vertices.round(12), axis=0))
    # an already indexed mesh with nothing to merge comes back as it is
    v2, f2 = merge_vertices(ball.vertices, ball.faces)
    assert v2 is ball.vertices or np.array_equal(v2, ball.vertices)
    assert np.array_equal(f2, ball.faces)


def test_mesh_file_reads_as_a_merged_surface(tmp_path):
    from optiacoustic.scene import Mesh

    box = trimesh.creation.box((1.0, 2.0, 3.0))
    path = tmp_path / "box.stl"  # STL stores every triangle's corners separately
    box.export(path)
    s = Mesh(file=str(path)).tessellate()
    assert s.n_faces == 12 and len(s.vertices) == 24  # merged to 8, then split along the 12 sharp edges
    assert Body("b", Mesh(file=str(path))).surface() is s  # identity pose and scale: no copy
