"""Scene build: a triangle mesh file to a ready ray caster, time and memory per triangle."""

from __future__ import annotations

import json
import os
import subprocess
import sys
import tempfile

import numpy as np

TITLE = "Scene build (mesh file to a ready ray caster)"
DESCRIPTION = (
    "A relief mesh (a grid with a smooth bump field and one sharp step, 1 M and 4 M triangles) "
    "written as binary PLY, loaded as a `Mesh` body (trimesh's reader; optiacoustic merges vertices "
    "by position, splits them along creases sharper than 30 deg and computes vertex normals; the "
    "caster uploads the triangles to Embree with one numpy copy per buffer and builds its BVH). Each "
    "build runs in a fresh process. Reference: Embree's own work on the same triangles, in the same "
    "process kind: `embreex` `TriangleMesh` upload (element by element) plus the BVH build (first "
    "query), from float32 arrays already in memory; the note gives the BVH build alone. Memory: "
    "resident set growth of the process after the build, ours minus the bare Embree build's, per "
    "triangle. Targets: <= 2 us and <= 200 bytes per triangle beyond Embree's own."
)

_CHILD = r"""
import json, os, sys, time
import numpy as np
def rss():
    with open("/proc/self/statm") as f:
        return int(f.read().split()[1]) * os.sysconf("SC_PAGE_SIZE")
path, kind = sys.argv[1], sys.argv[2]
if kind == "embree":
    import trimesh
    import embreex.mesh_construction as mc, embreex.rtcore_scene as rs
    m = trimesh.load(path, force="mesh", process=False)
    V, F = np.asarray(m.vertices, np.float32), np.asarray(m.faces, np.int32)
    del m
    r0 = rss(); t0 = time.perf_counter()
    sc = rs.EmbreeScene(); mc.TriangleMesh(sc, V, F)
    t_up = time.perf_counter() - t0
    sc.run(np.zeros((1, 3), np.float32), np.array([[0, 0, 1]], np.float32))
    t = time.perf_counter() - t0; n = len(F)
    print(json.dumps(dict(t=t, mem=rss() - r0, n=n, t_bvh=t - t_up)))
else:
    import trimesh  # imported before timing: its import is not the scene build
    from optiacoustic import Scene
    from optiacoustic.scene import Body, Mesh
    from optiacoustic.raycast import RayCaster
    from optiacoustic.scene.normals import merge_vertices, smooth_shading
    from optiacoustic.scene.shapes import _read_triangles
    import scipy.sparse.csgraph  # noqa: F401
    r0 = rss(); t0 = time.perf_counter()
    rc = RayCaster(Scene([Body("relief", Mesh(file=path))]))
    t = time.perf_counter() - t0
    mem = rss() - r0
    t1 = time.perf_counter(); v, f = merge_vertices(*_read_triangles(path)); tl = time.perf_counter() - t1
    t1 = time.perf_counter(); smooth_shading(v, f, np.deg2rad(30)); ts = time.perf_counter() - t1
    print(json.dumps(dict(t=t, mem=mem, n=int(rc._tri_offset[-1]), t_shade=ts, t_load=tl)))
"""


def relief_mesh(n_triangles: int):
    """A ``m x m`` grid relief with smooth bumps and one sharp 0.2 m step: ``(V, 3), (F, 3)``."""
    m = int(np.sqrt(n_triangles / 2)) + 1
    u, v = np.meshgrid(np.linspace(0, 1, m), np.linspace(0, 1, m), indexing="ij")
    z = 0.05 * np.sin(12 * u) * np.cos(9 * v) + 0.2 * (u > 0.5)
    V = np.stack([u.ravel() * 4, v.ravel() * 4, z.ravel()], -1)
    i, j = np.meshgrid(np.arange(m - 1), np.arange(m - 1), indexing="ij")
    a = (i * m + j).ravel()
    F = np.concatenate([np.stack([a, a + m, a + m + 1], -1), np.stack([a, a + m + 1, a + 1], -1)])
    return V, F


def _child(path, kind, threads):
    env = dict(os.environ, PYTHONPATH=os.pathsep.join(sys.path), OAS_THREADS=str(threads))
    out = subprocess.run([sys.executable, "-c", _CHILD, path, kind], capture_output=True, text=True, env=env,
                         check=True)
    return json.loads(out.stdout.strip().splitlines()[-1])


def _median(path, kind, threads, repeat):
    runs = [_child(path, kind, threads) for _ in range(repeat)]
    return {k: float(np.median([r[k] for r in runs])) for k in runs[0]}


def run() -> list[dict]:
    import trimesh

    from _timing import busy_core

    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        for n_req, repeat in ((1_000_000, 3), (4_000_000, 1)):
            V, F = relief_mesh(n_req)
            path = os.path.join(tmp, f"relief_{n_req}.ply")
            trimesh.Trimesh(V, F, process=False).export(path)
            del V, F
            ref = _median(path, "embree", 2, repeat)
            ours = _median(path, "ours", 2, repeat)
            n = ours["n"]
            tag = f"{n / 1e6:.1f} M triangles"
            rows.append(dict(name=f"reference: Embree upload + BVH, {tag}", value=1e6 * ref["t"] / n, unit="us/triangle",
                             reference="itself", ratio=1.0,
                             note=(f"{ref['mem'] / ref['n']:.0f} bytes/triangle resident (Embree's own); of which "
                                   f"BVH build {1e6 * ref['t_bvh'] / n:.2f} us/triangle, the rest embreex's "
                                   f"element-by-element upload")))
            rows.append(dict(name=f"scene build, PLY file to ready caster, {tag}", value=1e6 * ours["t"] / n,
                             unit="us/triangle", reference="Embree upload + BVH", ratio=ours["t"] / ref["t"],
                             note=(f"target <= 2 us/triangle; of which file read + vertex merge "
                                   f"{1e6 * ours['t_load'] / n:.2f}, crease split + normals "
                                   f"{1e6 * ours['t_shade'] / n:.2f}; {ours['t'] / ref['t_bvh']:.2f}x the BVH "
                                   f"build alone")))
            rows.append(dict(name=f"scene build memory beyond Embree's own, {tag}",
                             value=(ours["mem"] - ref["mem"] * n / ref["n"]) / n, unit="bytes/triangle",
                             reference="Embree upload + BVH", ratio=ours["mem"] / max(ref["mem"], 1),
                             note="target <= 200 bytes/triangle; resident set growth, fresh process"))
            if n_req == 1_000_000:
                with busy_core():
                    ref_b = _median(path, "embree", 2, repeat)
                    ours_b = _median(path, "ours", 2, repeat)
                rows.append(dict(name=f"scene build, {tag}, second core busy", value=1e6 * ours_b["t"] / n,
                                 unit="us/triangle", reference="Embree upload + BVH, second core busy",
                                 ratio=ours_b["t"] / ref_b["t"],
                                 note=f"the reference takes {1e6 * ref_b['t'] / n:.2f} us/triangle with the core busy"))
    return rows


if __name__ == "__main__":
    for r in run():
        print(r)
