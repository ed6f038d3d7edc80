"""Mesh text files that are not UTF-8 (exporters write comments and names in Latin-1 or cp1252) load."""

import numpy as np

from optiacoustic.scene import Scene


def test_obj_with_a_latin1_comment_loads(tmp_path):
    (tmp_path / "rock.obj").write_bytes("# modèle créé par Blender\nv 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n"
                                        .encode("latin-1"))
    (tmp_path / "s.yaml").write_text("bodies:\n  - {name: rock, shape: mesh, file: rock.obj}\n")
    surf = Scene.load(tmp_path / "s.yaml").surfaces()
    assert len(surf) == 1 and surf[0].n_faces == 1
    assert np.allclose(sorted(map(tuple, surf[0].vertices)), [(0, 0, 0), (0, 1, 0), (1, 0, 0)])
