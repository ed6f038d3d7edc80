"""Data flows one way: scene -> ray caster -> sensors -> geometry and fusion -> experiments -> CLI.

Checked on the source: every import of every module, resolved to an absolute name.
"""

import ast
from pathlib import Path

import pytest

PKG = Path(__file__).resolve().parents[1] / "src" / "optiacoustic"

# module prefix -> prefixes it must never import
FORBIDDEN = {
    "optiacoustic.frames": ["optiacoustic.scene", "optiacoustic.sonar", "optiacoustic.optical", "optiacoustic.geometry"],
    "optiacoustic.scene": ["optiacoustic.raycast", "optiacoustic.sonar", "optiacoustic.optical", "optiacoustic.geometry"],
    "optiacoustic._embree_upload": ["optiacoustic.scene", "optiacoustic.sonar", "optiacoustic.optical",
                                    "optiacoustic.simulation", "optiacoustic.geometry"],
    # the direct rtcIntersect1 path: ctypes and numba over Embree, below the caster
    "optiacoustic._embree_kernels": ["optiacoustic.scene", "optiacoustic.raycast", "optiacoustic.sonar",
                                     "optiacoustic.optical", "optiacoustic.simulation", "optiacoustic.geometry", "embreex"],
    "optiacoustic.raycast": ["optiacoustic.sonar", "optiacoustic.optical", "optiacoustic.simulation", "optiacoustic.geometry", "optiacoustic.fusion"],
    # the two sensor simulators are siblings: neither imports the other nor the rig layer above them
    "optiacoustic.sonar": ["optiacoustic.optical", "optiacoustic.simulation", "optiacoustic.geometry", "optiacoustic.fusion",
                           "optiacoustic.experiments"],
    "optiacoustic.optical": ["optiacoustic.sonar", "optiacoustic.simulation", "optiacoustic.geometry", "optiacoustic.fusion",
                             "optiacoustic.experiments"],
    # rig simulation (pairs, trajectories, sequences) sits on both simulators, below datasets and everything that
    # works on measurements
    "optiacoustic.simulation": ["optiacoustic.io", "optiacoustic.geometry", "optiacoustic.fusion", "optiacoustic.matching",
                                "optiacoustic.experiments", "optiacoustic.workbench", "optiacoustic.cli", "embreex"],
    "optiacoustic.geometry": ["optiacoustic.sonar", "optiacoustic.optical", "optiacoustic.simulation", "optiacoustic.raycast", "optiacoustic.fusion",
                              "optiacoustic.experiments", "embreex"],
    "optiacoustic.fusion": ["optiacoustic.sonar", "optiacoustic.optical", "optiacoustic.simulation", "optiacoustic.raycast", "optiacoustic.experiments",
                            "embreex"],
    "optiacoustic.matching": ["optiacoustic.sonar", "optiacoustic.optical", "optiacoustic.simulation", "optiacoustic.raycast",
                              "optiacoustic.fusion", "optiacoustic.experiments", "optiacoustic.scene", "embreex"],
    "optiacoustic.experiments": ["optiacoustic.cli"],
    "optiacoustic.workbench": ["optiacoustic.cli", "optiacoustic.experiments", "optiacoustic.raycast", "embreex"],
    # exporting and converting read stored frames: no simulator (io.dataset, the dataset writer, sits above the
    # rig simulation layer and may import it)
    "optiacoustic.io.mcap_writer": ["optiacoustic.simulation", "optiacoustic.sonar.formation", "optiacoustic.optical.render"],
    "optiacoustic.io.convert": ["optiacoustic.simulation", "optiacoustic.sonar.formation", "optiacoustic.optical.render"],
    # readers never import a simulator (DESIGN.md): frames and specs only
    "optiacoustic.io": ["optiacoustic.sonar.formation", "optiacoustic.raycast", "optiacoustic.optical.render",
                        "optiacoustic.geometry", "optiacoustic.fusion", "optiacoustic.experiments",
                        "optiacoustic.cli", "embreex"],
}


def _modules():
    for path in sorted(PKG.rglob("*.py")):
        rel = path.relative_to(PKG.parent).with_suffix("")
        parts = list(rel.parts)
        if parts[-1] == "__init__":
            parts = parts[:-1]
        yield ".".join(parts), path


def _imports(name: str, path: Path):
    tree = ast.parse(path.read_text())
    package = name if path.name == "__init__.py" else name.rsplit(".", 1)[0]
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            for a in node.names:
                yield a.name
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = package.split(".")
                base = base[: len(base) - node.level + 1]
                mod = ".".join(base + ([node.module] if node.module else []))
            else:
                mod = node.module
            yield mod
            for a in node.names:  # `from . import sonar` imports a submodule
                yield f"{mod}.{a.name}"


@pytest.mark.parametrize("name, path", list(_modules()), ids=lambda x: str(x) if isinstance(x, str) else "")
def test_imports_flow_one_way(name, path):
    rules = [bad for prefix, bads in FORBIDDEN.items() if name == prefix or name.startswith(prefix + ".") for bad in bads]
    offending = sorted({m for m in _imports(name, path) if any(m == b or m.startswith(b + ".") for b in rules)})
    assert not offending, f"{name} imports {offending}"


def test_embree_is_behind_the_ray_caster():
    users = sorted(n for n, p in _modules() if any(m.startswith("embreex") for m in _imports(n, p)))
    assert users == ["optiacoustic.raycast"]


def test_numba_is_behind_the_kernel_modules():
    """numba is imported only by kernel modules, loaded on a frame's first kernel call (never by ``import optiacoustic``)."""
    users = sorted(n for n, p in _modules() if any(m == "numba" or m.startswith("numba.") for m in _imports(n, p)))
    assert users and all(n.rsplit(".", 1)[-1] in ("_kernels", "_numba_kernels", "_truth_kernels", "_aperture_kernels",
                                                                 "_embree_kernels")
               for n in users), users
