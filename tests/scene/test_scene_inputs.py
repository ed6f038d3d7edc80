"""Scene files with values of the wrong type or no physical meaning: a SceneError naming file, body and field."""

import json

import numpy as np
import pytest

from optiacoustic import Scene
from optiacoustic.scene import SceneError
from optiacoustic.scene.normals import merge_vertices
from optiacoustic.scene.parts import BOTTOM_TYPE_NAMES
from optiacoustic.scene.shapes import MIN_SIZE, Mesh, Sphere

BOX = {"name": "b", "shape": "box", "size": [1, 1, 1]}


def _load(tmp_path, data, name="scene.json"):
    p = tmp_path / name
    p.write_text(json.dumps(data))
    with pytest.raises(SceneError) as e:
        Scene.load(p)
    msg = str(e.value)
    assert msg.startswith(str(p)), msg
    return msg


@pytest.mark.parametrize("body, field, words", [
    ({"name": "b", "shape": ["box"], "size": [1, 1, 1]}, "shape", "unknown shape ['box']"),
    ({"name": "b", "shape": {"a": 1}, "size": [1, 1, 1]}, "shape", "unknown shape"),
    ({"name": "b", "shape": "box", "size": ["1", "2", "3"]}, "size[0]", "expected a number, not str"),
    ({"name": "b", "shape": "box", "size": [True, 1, 1]}, "size[0]", "expected a number, not bool"),
    ({"name": "b", "shape": "sphere", "radius": 1, "subdivisions": "2"}, "subdivisions", "expected an integer"),
    ({"name": "b", "shape": "sphere", "radius": 1, "subdivisions": True}, "subdivisions", "expected an integer"),
    ({"name": "b", "shape": "sphere", "radius": 1e-300}, "radius", "at least MIN_SIZE"),
    ({"name": "b", "shape": "cylinder", "radius": 1, "height": "1"}, "height", "expected a number"),
    ({"name": "b", "shape": "box", "size": [1, 1, 1], "material": {"reflectivity": True}},
     "material.reflectivity", "expected a number"),
    ({"name": "b", "shape": "plane", "size": [40, 40], "material": {"bottom_type": "lava"}},
     "material.bottom_type", "unknown seabed 'lava'"),
])
def test_bad_body_fields_are_named(tmp_path, body, field, words):
    msg = _load(tmp_path, {"bodies": [body]})
    assert "body 'b' (#0)" in msg and f"field '{field}'" in msg and words in msg, msg


def test_bottom_types_are_the_sonars():
    from optiacoustic.sonar import BOTTOM_TYPES

    assert set(BOTTOM_TYPE_NAMES) == set(BOTTOM_TYPES)


def test_known_bottom_types_load_in_any_spelling(tmp_path):
    p = tmp_path / "bed.yaml"
    p.write_text("bodies:\n  - {name: bed, shape: plane, size: [4, 4], material: {bottom_type: Coarse_Sand}}\n")
    assert Scene.load(p).bodies[0].material.bottom_type == "Coarse_Sand"


@pytest.mark.parametrize("data, field, words", [
    ({"bodies": [BOX], "view": [0, 0]}, "view", "expected an eye position of 3 numbers"),
    ({"bodies": [BOX], "view": "up"}, "view", "expected a mapping"),
    ({"bodies": [BOX], "view": {"eye": [1, 2, 3], "target": [1, 2, 3]}}, "view", "eye == target"),
    ({"bodies": [BOX], "view": {"eye": [0, 0, "x"]}}, "view.eye[2]", "expected a number"),
    ({"bodies": [BOX], "name": ["x"]}, "name", "expected a string"),
    ({"bodies": [BOX], "description": 5}, "description", "expected a string"),
])
def test_bad_top_level_fields_are_named(tmp_path, data, field, words):
    msg = _load(tmp_path, data)
    assert f"field '{field}'" in msg and words in msg, msg


def test_minimum_size_is_documented_and_accepted():
    assert Sphere(radius=MIN_SIZE).radius == MIN_SIZE
    with pytest.raises(ValueError, match="radius"):
        Sphere(radius=MIN_SIZE / 2)


def test_mesh_of_zero_area_triangles_is_refused(tmp_path):
    (tmp_path / "degen.obj").write_text("v 0 0 0\nv 1 0 0\nv 2 0 0\nf 1 2 3\nf 1 1 2\n")
    msg = _load(tmp_path, {"bodies": [{"name": "m", "shape": "mesh", "file": "degen.obj"}]})
    assert "field 'file'" in msg and "degen.obj" in msg and "no triangle with non-zero area" in msg


def test_a_mesh_in_nanometres_keeps_its_triangles_apart(tmp_path):
    """Two triangles 1e11 file units apart (1e2 m at scale 1e-9): the int64 rounding key overflowed and merged them."""
    f = tmp_path / "nm.obj"
    f.write_text("v 2e11 0 0\nv 2e11 1e9 0\nv 2e11 0 1e9\nv 3e11 0 0\nv 3e11 1e9 0\nv 3e11 0 1e9\nf 1 2 3\nf 4 5 6\n")
    s = Mesh(file=str(f), scale=1e-9).tessellate()
    tri = s.vertices[s.faces]  # (2, 3, 3)
    np.testing.assert_allclose(tri[0], [[200, 0, 0], [200, 1, 0], [200, 0, 1]], rtol=1e-12)
    np.testing.assert_allclose(tri[1], [[300, 0, 0], [300, 1, 0], [300, 0, 1]], rtol=1e-12)
    assert s.area() == pytest.approx(1.0, rel=1e-12)  # two right triangles of legs 1 m


def test_merge_vertices_still_merges_shared_corners_at_any_size():
    for scale in (1.0, 1e12, 1e-6):
        V = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [1, 0, 0], [0, 1, 0], [1, 1, 0]], float) * scale
        v, f = merge_vertices(V, np.array([[0, 1, 2], [3, 5, 4]]))
        assert len(v) == 4 and f.tolist() == [[0, 1, 2], [1, 3, 2]]
