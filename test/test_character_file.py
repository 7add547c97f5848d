"""Character files: a mesh plus a skeleton in YAML, and their errors."""
from __future__ import annotations

import re

import numpy as np
import pytest
import trimesh
import yaml

from skin_node import Pipeline, load_character
from skin_node.builtin.characters import make_arm

JOINTS = [{"name": "shoulder", "position": [0, 0, 0]},
          {"name": "elbow", "parent": "shoulder", "position": [0.27, 0, 0]},
          {"name": "wrist", "parent": "elbow", "position": [0.5, 0, 0], "tip": [0.6, 0, 0]}]


@pytest.fixture(scope="module")
def arm_mesh(tmp_path_factory):
    d = tmp_path_factory.mktemp("char")
    V, F, _ = make_arm(1500)
    trimesh.Trimesh(V, F, process=False).export(d / "arm.obj")
    return d, V, F


def write(path, doc):
    path.write_text(doc if isinstance(doc, str) else yaml.safe_dump(doc))
    return path


def test_loads_and_deforms_like_the_builtin(arm_mesh, tmp_path, monkeypatch):
    monkeypatch.setenv("SKIN_NODE_CACHE", str(tmp_path / "cache"))
    d, V, F = arm_mesh
    ch = load_character(str(write(d / "arm.yaml", {"mesh": "arm.obj", "joints": JOINTS})),
                        progress=False)
    assert len(ch.V) == len(V) and ch.skeleton.names == ["shoulder", "elbow", "wrist"]
    # OBJ keeps about 8 significant digits
    assert abs(trimesh.Trimesh(ch.V, ch.F).volume / trimesh.Trimesh(V, F).volume - 1) < 1e-6
    out = Pipeline(ch).deform(ch.pose(elbow_rz=2.0))
    assert np.all(np.isfinite(out)) and np.abs(out - ch.V).max() > 0.1


def cube(open_: bool = False, nan: bool = False):
    m = trimesh.creation.box()
    V, F = m.vertices.tolist(), m.faces.tolist()
    if open_:
        F = F[:-1]
    if nan:
        V[0][0] = float("nan")
    return {"vertices": V, "faces": F,
            "joints": [{"name": "a", "position": [0, 0, 0], "tip": [0.2, 0, 0]}]}


@pytest.mark.parametrize("doc, message", [
    (None, "no such file"),
    ("", "file is empty"),
    ("joints: [\n", "malformed YAML"),
    ("- just\n- a list\n", "expected a mapping"),
    ({"mesh": "missing.obj", "joints": JOINTS}, "does not exist"),
    (cube(open_=True), "surface is open"),
    (cube(nan=True), "NaN"),
    ({**cube(), "joints": [{"name": "a", "position": [0, 0, 0]},
                           {"name": "b", "parent": "zz", "position": [1, 0, 0], "tip": [2, 0, 0]}]},
     "parent 'zz' is not a joint"),
    ({**cube(), "joints": [{"name": "a", "position": [0, 0, 0]},
                           {"name": "b", "parent": "c", "position": [1, 0, 0]},
                           {"name": "c", "parent": "b", "position": [2, 0, 0], "tip": [3, 0, 0]}]},
     "listed after it"),
    ({**cube(), "joints": [{"name": "a", "position": [0, 0, 0], "tip": [1, 0, 0]},
                           {"name": "a", "parent": "a", "position": [1, 0, 0]}]}, "listed twice"),
    ({**cube(), "joints": [{"name": "a", "position": [0, 0, 0]}]}, "needs a finite tip"),
])
def test_bad_files_name_the_file_and_the_problem(tmp_path, doc, message):
    path = tmp_path / "c.yaml"
    if doc is not None:
        write(path, doc)
    with pytest.raises(ValueError) as e:
        load_character(str(path), progress=False, cache=False)
    assert str(path) in str(e.value) and message in str(e.value), str(e.value)


@pytest.mark.parametrize("mesh, message", [
    ("open", "surface is open"),
    ("empty", "cannot be read as a mesh|holds no triangles"),
    ("missing", "mesh file does not exist"),
    ("crossing", r"its 2 shells pass through each other at rest \(\d+ intersecting triangle "
                 r"pairs\): the deformer needs one skin"),
])
def test_a_bad_mesh_names_the_mesh_file_and_the_yaml(tmp_path, mesh, message):
    """The mesh file is the one to fix: its path comes first, then the YAML's."""
    obj = tmp_path / "meshes" / "body.obj"
    obj.parent.mkdir()
    if mesh == "open":
        m = trimesh.creation.box()
        trimesh.Trimesh(m.vertices, m.faces[:-1], process=False).export(obj)
    elif mesh == "empty":
        obj.write_text("# nothing\n")
    elif mesh == "crossing":        # two closed boxes through each other: no one skin
        a, b = trimesh.creation.box(), trimesh.creation.box()
        b.apply_translation([0.5, 0.2, 0.1])
        trimesh.Trimesh(np.vstack([a.vertices, b.vertices]),
                        np.vstack([a.faces, b.faces + len(a.vertices)]), process=False).export(obj)
    path = write(tmp_path / "c.yaml", {"mesh": "meshes/body.obj", "joints": JOINTS})
    with pytest.raises(ValueError) as e:
        load_character(str(path), progress=False, cache=False)
    text = str(e.value)
    assert text.startswith(f"{obj.resolve()}: "), text
    assert f"(the mesh of {path})" in text and len(text.splitlines()) == 1, text
    assert re.search(message, text), text
