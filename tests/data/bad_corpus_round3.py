"""Corpus cases of issue 38 (hostile and odd-but-valid inputs, round 3), registered by make_bad_corpus.py.

Kept apart from make_bad_corpus.py so that neither grows past a screenful of
cases; ``add_cases(m)`` receives that module (its ``case`` and helpers), which
also works when it runs as a script (``__main__``).
"""

from __future__ import annotations

import base64
import json

import numpy as np

UNIT = ((-0.5,) * 3, (0.5,) * 3)


def _identity_ibm(count: int) -> np.ndarray:
    return np.tile(np.eye(4, dtype="<f4").T.reshape(1, 16), (count, 1))


def _translation(x: float, y: float, z: float) -> np.ndarray:
    m = np.eye(4)
    m[:3, 3] = (x, y, z)
    return m


def _embedded(m, g, roots: list[int]) -> str:
    """A .gltf with its buffer in a data URI (no companion file)."""
    uri = "data:application/octet-stream;base64," + base64.b64encode(bytes(g.binary)).decode()
    text, _ = g.gltf(roots, uri)
    return text


def _textured(m, uri: str) -> str:
    """A box .gltf whose material's base-colour image is the file ``uri``."""
    g = m.Gltf()
    g.doc["images"] = [{"uri": uri}]
    g.doc["textures"] = [{"source": 0}]
    g.doc["materials"] = [{"pbrMetallicRoughness": {"baseColorTexture": {"index": 0}}}]
    g.node(mesh=g.mesh([m.box_primitive(g, material=0)]))
    return _embedded(m, g, [0])


def add_cases(m) -> None:
    """Register the round-3 cases with ``m.case`` (``m`` is make_bad_corpus)."""
    V, F = m.box()
    _morph_cases(m, V, F)
    _skin_cases(m, V, F)
    _index_cases(m, V, F)
    _reference_cases(m)
    _wrong_reason_cases(m, V, F)
    _size_cases(m, V, F)


def _morph_cases(m, V, F) -> None:
    top = (V[:, 2] > 0).astype(np.float64)
    # One dense target lifting the top corners by 1; the mesh's default weight 0.5 gives a 1 x 1 x 1.5 box.
    g = m.Gltf()
    lift = g.accessor((np.outer(top, [0.0, 0.0, 1.0])).astype("<f4"), 5126, "VEC3")
    prim = m.box_primitive(g)
    prim["targets"] = [{"POSITION": lift}]
    g.doc["meshes"].append({"primitives": [prim], "weights": [0.5]})
    g.node(mesh=0)
    m.case("morph_default_weights.glb", g.glb([0]), outcome="ok", check="load", volume=1.5,
           bbox=((-0.5, -0.5, -0.5), (0.5, 0.5, 1.0)),
           why="a morph target at the mesh's default weight 0.5 (the posed box is 1.5 high, not 1)")
    # Two sparse targets (no bufferView: zeros, the listed vertices moved); the node's weights override the mesh's.
    g = m.Gltf()
    prim = m.box_primitive(g)
    targets = []
    for axis in (2, 0):
        moved = np.flatnonzero(V[:, axis] > 0)
        delta = np.zeros((len(moved), 3), dtype="<f4")
        delta[:, axis] = 1.0
        targets.append({"POSITION": g.accessor(np.zeros((8, 3), "<f4"), 5126, "VEC3", view=False, sparse={
            "count": len(moved), "indices": {"bufferView": g.view(moved.astype("<u1").tobytes()),
                                             "componentType": 5121},
            "values": {"bufferView": g.view(delta.tobytes())}})})
    prim["targets"] = targets
    g.doc["meshes"].append({"primitives": [prim], "weights": [1.0, 1.0]})
    g.node(mesh=0, weights=[0.25, 1.0])
    m.case("morph_sparse_node_weights.glb", g.glb([0]), outcome="ok", check="load", volume=2.5,
           bbox=((-0.5, -0.5, -0.5), (1.5, 0.5, 0.75)),
           why="two sparse morph targets; the node's weights (0.25, 1) override the mesh's (1, 1)")
    g = m.Gltf()
    prim = m.box_primitive(g)
    prim["targets"] = [{"POSITION": g.accessor(np.zeros((8, 3), "<f4"), 5126, "VEC3")}]
    g.doc["meshes"].append({"primitives": [prim], "weights": [0.5, 0.5]})
    g.node(mesh=0)
    m.case("morph_weights_mismatch.glb", g.glb([0]), outcome="error", message="2 morph weights for 1 morph targets",
           why="two default weights for one morph target (the spec requires one each)")


def _skinned_box(m, g, joint_of_vertex: np.ndarray, joints: list[int], ibm: np.ndarray | None,
                 with_joint_attributes: bool = True) -> int:
    """A skinned box primitive's mesh (joint of each vertex, weight 1) and its skin; returns the skin index."""
    prim = m.box_primitive(g)
    if with_joint_attributes:
        ids = np.zeros((8, 4), dtype="<u1")
        ids[:, 0] = joint_of_vertex
        weights = np.zeros((8, 4), dtype="<f4")
        weights[:, 0] = 1.0
        prim["attributes"]["JOINTS_0"] = g.accessor(ids, 5121, "VEC4")
        prim["attributes"]["WEIGHTS_0"] = g.accessor(weights, 5126, "VEC4")
    g.mesh([prim])
    skin = {"joints": joints}
    if ibm is not None:
        skin["inverseBindMatrices"] = g.accessor(ibm.astype("<f4"), 5126, "MAT4")
    g.doc.setdefault("skins", []).append(skin)
    return len(g.doc["skins"]) - 1


def _skin_cases(m, V, F) -> None:
    # The skinned node's own transform (moved by 100, scaled 5) must be ignored; its one joint places it at y = 3.
    g = m.Gltf()
    skin = _skinned_box(m, g, np.zeros(8, int), [1], _identity_ibm(1))
    g.node(mesh=0, skin=skin, translation=[100.0, 0.0, 0.0], scale=[5.0, 5.0, 5.0])
    g.node(translation=[0.0, 3.0, 0.0])
    m.case("skinned_node_transform.glb", g.glb([0, 1]), outcome="ok", check="load", volume=1.0,
           bbox=((-0.5, 2.5, -0.5), (0.5, 3.5, 0.5)),
           why="a skinned mesh whose node is moved and scaled: the spec ignores that transform, its joint places it")
    # Two joints: the bottom corners follow joint 1 (at its bind pose), the top ones joint 2, posed 1 higher than
    # its bind pose (node at z = 2, inverse bind matrix a translation by -1): a 1 x 1 x 2 box.
    g = m.Gltf()
    ibm = np.stack([np.eye(4).T.reshape(16), _translation(0.0, 0.0, -1.0).T.reshape(16)])
    skin = _skinned_box(m, g, (V[:, 2] > 0).astype(int), [1, 2], ibm)
    g.node(mesh=0, skin=skin)
    g.node()
    g.node(translation=[0.0, 0.0, 2.0])
    m.case("skinned_two_joints.glb", g.glb([0, 1, 2]), outcome="ok", check="load", volume=2.0,
           bbox=((-0.5, -0.5, -0.5), (0.5, 0.5, 1.5)),
           why="a box skinned to two joints with inverse bind matrices; the scene's pose stretches it to 2 high")
    g = m.Gltf()
    skin = _skinned_box(m, g, np.zeros(8, int), [1], None, with_joint_attributes=False)
    g.node(mesh=0, skin=skin)
    g.node()
    m.case("skin_without_joints.glb", g.glb([0, 1]), outcome="error", message="has no JOINTS_0",
           why="a skinned node whose mesh has no JOINTS_0 / WEIGHTS_0 (the spec requires them)")


def _index_cases(m, V, F) -> None:
    g = m.Gltf()
    g.mesh([m.box_primitive(g)])
    g.mesh([m.box_primitive(g, extents=(9.0, 9.0, 9.0))])
    g.node(mesh=-1)
    m.case("mesh_minus_one.glb", g.glb([0]), outcome="error", message="node 0's mesh is -1",
           why="'mesh': -1 (not 'the last mesh': an invalid index)")
    g = m.Gltf()
    g.mesh([m.box_primitive(g)])
    g.node(mesh=5)
    m.case("mesh_out_of_range.glb", g.glb([0]), outcome="error", message="node 0's mesh is 5",
           why="a node naming mesh 5 of 1")
    g = m.Gltf()
    prim = m.box_primitive(g)
    prim["attributes"]["POSITION"] = 7
    g.node(mesh=g.mesh([prim]))
    m.case("accessor_out_of_range.glb", g.glb([0]), outcome="error", message="POSITION is 7",
           why="POSITION names accessor 7 of 2")
    g = m.Gltf()
    pos = g.accessor(V.astype("<f4"), 5126, "VEC3")
    idx = g.accessor(F.reshape(-1).astype("<f4"), 5126, "SCALAR")
    g.node(mesh=g.mesh([{"attributes": {"POSITION": pos}, "indices": idx}]))
    m.case("float_indices.glb", g.glb([0]), outcome="error", message="are SCALAR float",
           why="indices stored as floats (glTF indices are unsigned integers)")


def _reference_cases(m) -> None:
    for name, uri, message, why in (
            ("image_absolute_uri.gltf", "/etc/hostname", "(an absolute path)",
             "an image uri that is an absolute path (never read into the output GLB)"),
            ("image_parent_uri.gltf", "../make_bad_corpus.py", "outside the asset's folder",
             "an image uri that climbs out of the asset's folder"),
            ("image_encoded_parent_uri.gltf", "%2E%2E/make_bad_corpus.py", "outside the asset's folder",
             "a percent-encoded '../' image uri"),
            ("image_url.gltf", "https://example.com/wood.png", "a URL",
             "an image on the network (a build must not depend on it)")):
        m.case(name, _textured(m, uri), outcome="error", message=message, why=why)
    g = m.Gltf()
    g.node(mesh=g.mesh([m.box_primitive(g)]))
    text, _ = g.gltf([0], "../secret.bin")
    m.case("buffer_parent_uri.gltf", text, outcome="error", message="outside the asset's folder",
           why="a buffer uri that climbs out of the asset's folder")
    doc = json.loads(text)
    doc["buffers"][0]["uri"] = "/dev/zero"
    m.case("buffer_device_uri.gltf", json.dumps(doc), outcome="error", message="(an absolute path)",
           why="a buffer uri naming a device by absolute path")


def _wrong_reason_cases(m, V, F) -> None:
    lines = m.obj_text(V, F).splitlines()
    tabbed = "\n".join(("\t" + line.replace(" ", "\t")) if i % 2 else line.replace(" ", "\t\t")
                       for i, line in enumerate(lines)) + "\n"
    m.case("tabs.obj", tabbed, outcome="ok", check="load", volume=1.0, bbox=UNIT,
           why="OBJ whose words are separated by tabs, some lines indented (valid OBJ)")
    tris = V[F]
    facets = []
    for t in tris:
        n = np.cross(t[1] - t[0], t[2] - t[0])
        n = n / np.linalg.norm(n)
        facets += [f"  FACET NORMAL {m.fmt(n[0])} {m.fmt(n[1])} {m.fmt(n[2])}", "    OUTER LOOP"]
        facets += [f"      VERTEX {m.fmt(c[0])} {m.fmt(c[1])} {m.fmt(c[2])}" for c in t]
        facets += ["    ENDLOOP", "  ENDFACET"]
    m.case("uppercase.stl", "\n".join(["SOLID BOX", *facets, "ENDSOLID BOX"]) + "\n", outcome="ok", check="load",
           volume=1.0, bbox=UNIT, why="ASCII STL with uppercase keywords (SOLID, FACET, VERTEX, ...)")
    # A node scaled to zero (the usual way to hide an object in the default pose) next to a visible box.
    g = m.Gltf()
    normals = g.accessor((V / np.linalg.norm(V, axis=1, keepdims=True)).astype("<f4"), 5126, "VEC3")
    prim = m.box_primitive(g)
    prim["attributes"]["NORMAL"] = normals
    mesh = g.mesh([prim])
    g.node(mesh=mesh, scale=[0.0, 0.0, 0.0], translation=[5.0, 0.0, 0.0])
    g.node(mesh=mesh)
    m.case("zero_scale_node.glb", g.glb([0, 1]), outcome="ok", check="load", volume=1.0, bbox=UNIT,
           why="a node with scale 0 (hidden: drawn as nothing) beside a visible box: skipped with a warning")
    g = m.Gltf()
    g.node(mesh=g.mesh([m.box_primitive(g)]), scale=[1.0, 0.0, 1.0])
    m.case("only_zero_scale.glb", g.glb([0]), outcome="error", message="contains no triangles",
           why="the only mesh node has a zero scale on one axis (flattened: nothing solid to read)")


def _size_cases(m, V, F) -> None:
    SV, SF = m.icosphere(1, 1.0e9)
    m.case("sphere_radius_1e9.obj", m.obj_text(SV, SF), outcome="error", message="too large for the outputs",
           why="a sphere of radius 1e9 units: its inertia (units^5) cannot be stored as float32 (refused before any "
               "work, not at export)")
    m.case("coordinates_1e30.obj", m.obj_text(V * 1.0e30, F), outcome="error", message="too large for the outputs",
           why="a box 1e30 units across (refused at load, not after the whole pipeline)")
    m.case("box_1e-9.obj", m.obj_text(V * 1.0e-9, F), outcome="error", message="too small for the outputs",
           why="a box 1e-9 units across: its inertia underflows float32")
