"""The scene of a glTF 2.0 document: which meshes it draws, where, with which morph weights and skin.

glTF 2.0 specification, sections 3.5 (nodes and hierarchy), 3.7.2.2 (morph
targets) and 3.7.3 (skins):

* a node's world matrix is its parents' times its own ``matrix`` or ``T * R * S``;
* a node's ``weights`` override its mesh's ``weights`` (default morph
  weights, zeros when neither is given);
* a skinned mesh ignores its node's transform: its vertices are placed by
  their joints, ``sum_k w_k * world(joint_k) * inverseBind_k`` (the scene's
  pose of the joints, which is what a viewer shows without an animation);
* a node whose transform is degenerate (a zero scale, the usual way to hide an
  object in the default pose) draws nothing visible: it is skipped with a
  warning rather than read as flat geometry or refused.

Every index is checked against its array (``"mesh": -1`` is not "the last
mesh"); a problem is one :class:`~fracture_cli.errors.InputError` line.
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from fracture_cli.errors import InputError
from fracture_cli.geometry import tolerances as tol
from fracture_cli.io.gltf_conventions import is_collision_only

log = logging.getLogger(__name__)
# The glTF document reader (fracture_cli.io.gltf_read._Document): index, accessor, attribute, fail, doc, scene.
_Reader = Any

# Vertices skinned at a time (the per-vertex 4 x 4 blends of one chunk: 8 MB).
_SKIN_CHUNK = 65536


@dataclass(frozen=True)
class Instance:
    """One node that draws a mesh.

    Attributes
    ----------
    node, mesh : int
        Node and mesh index.
    world : (4, 4) float64
        The node's world matrix (ignored by a skinned mesh, see ``skin``).
    weights : (t,) float64
        Default morph weights of the mesh at this node (node's, else mesh's, else zeros;
        ``t`` = the number of targets the mesh's first primitive has, 0 without targets).
    skin : int or None
        The node's skin, if any.
    """

    node: int
    mesh: int
    world: np.ndarray
    weights: np.ndarray
    skin: int | None


def index(doc: dict, kind: str, value, what: str, path: str) -> int:
    """``value`` as an index into ``doc[kind]`` (an integer in range), or a refusal naming ``what``.

    Raises
    ------
    InputError
        Not an integer (a float with a fraction, a string, ``true``), negative
        or past the end of the array.
    """
    items = doc.get(kind) or []
    if isinstance(value, bool) or not isinstance(value, (int, float)) or value != value or int(value) != value:
        raise InputError(f"{what} is {value!r}, not an index into '{kind}'", path=path)
    if not 0 <= int(value) < len(items):
        n = len(items)
        raise InputError(f"{what} is {int(value)}, but the file's '{kind}' has {n} entr{'y' if n == 1 else 'ies'}"
                         + (f" (indices 0..{n - 1})" if n else ""), path=path)
    return int(value)


def local_matrix(node: dict) -> np.ndarray:
    """A node's local (4, 4) matrix: ``matrix`` (column-major) or T * R * S."""
    if "matrix" in node:
        return np.asarray(node["matrix"], dtype=np.float64).reshape(4, 4).T
    m = np.eye(4)
    x, y, z, w = (float(c) for c in node.get("rotation", (0.0, 0.0, 0.0, 1.0)))
    norm = math.sqrt(x * x + y * y + z * z + w * w) or 1.0
    x, y, z, w = x / norm, y / norm, z / norm, w / norm
    rotation = np.array([
        [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
        [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
        [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
    ])
    m[:3, :3] = rotation * np.asarray(node.get("scale", (1.0, 1.0, 1.0)), dtype=np.float64)
    m[:3, 3] = np.asarray(node.get("translation", (0.0, 0.0, 0.0)), dtype=np.float64)
    return m


def determinant3(m: np.ndarray) -> np.ndarray:
    """Determinants (...,) of (..., 3, 3) matrices, by cofactors (products only: the same bits everywhere)."""
    return (m[..., 0, 0] * (m[..., 1, 1] * m[..., 2, 2] - m[..., 1, 2] * m[..., 2, 1])
            - m[..., 0, 1] * (m[..., 1, 0] * m[..., 2, 2] - m[..., 1, 2] * m[..., 2, 0])
            + m[..., 0, 2] * (m[..., 1, 0] * m[..., 2, 1] - m[..., 1, 1] * m[..., 2, 0]))


def cofactor3(m: np.ndarray) -> np.ndarray:
    """Cofactor matrices (..., 3, 3) of (..., 3, 3): ``det(m) * inverse(m).T``, defined for singular ``m`` too."""
    c = np.empty(m.shape, dtype=np.float64)
    for i in range(3):
        for j in range(3):
            r = [k for k in range(3) if k != i]
            s = [k for k in range(3) if k != j]
            minor = m[..., r[0], s[0]] * m[..., r[1], s[1]] - m[..., r[0], s[1]] * m[..., r[1], s[0]]
            c[..., i, j] = minor if (i + j) % 2 == 0 else -minor
    return c


def is_degenerate(linear: np.ndarray) -> bool:
    """Whether a (3, 3) linear map squashes space (a zero scale on some axis): it draws nothing solid."""
    if not np.all(np.isfinite(linear)):
        return True
    columns = [math.sqrt(float(np.dot(linear[:, k], linear[:, k]))) for k in range(3)]
    scale = columns[0] * columns[1] * columns[2]
    # Degenerate: |det| at or below ROUNDOFF of the product of its column lengths.
    return not abs(float(determinant3(linear))) > tol.ROUNDOFF * scale or scale == 0.0


class Scene:
    """The node hierarchy of a document: world matrices and the instances of the scene's meshes."""

    def __init__(self, doc: dict, path: str):
        self.doc = doc
        self.path = path
        self.nodes = doc.get("nodes", []) or []
        self.parent: dict[int, int] = {}
        for i, node in enumerate(self.nodes):
            for c in node.get("children", []) or []:
                child = index(doc, "nodes", c, f"node {i}'s child", path)
                if child in self.parent and self.parent[child] != i:
                    raise InputError(f"node {child} has two parents ({self.parent[child]} and {i}); a glTF node "
                                     "hierarchy is a tree", path=path)
                self.parent[child] = i
        self._world: dict[int, np.ndarray] = {}

    def fail(self, message: str) -> InputError:
        return InputError(message, path=self.path)

    def world(self, node: int) -> np.ndarray:
        """World (4, 4) matrix of node ``node`` (through its parents, wherever it is in the document)."""
        chain: list[int] = []
        at: int | None = node
        while at is not None and at not in self._world:
            if at in chain:
                raise self.fail(f"node {at} is its own ancestor (the node hierarchy has a cycle)")
            chain.append(at)
            at = self.parent.get(at)
        matrix = self._world[at] if at is not None else np.eye(4)
        for n in reversed(chain):
            matrix = matrix @ local_matrix(self.nodes[n])
            self._world[n] = matrix
        return self._world[node]

    def roots(self) -> list[int]:
        scenes = self.doc.get("scenes", []) or []
        if scenes:
            chosen = index(self.doc, "scenes", self.doc.get("scene", 0), "the document's 'scene'", self.path)
            return [index(self.doc, "nodes", r, f"scene {chosen}'s node", self.path)
                    for r in scenes[chosen].get("nodes", []) or []]
        return [i for i in range(len(self.nodes)) if i not in self.parent]

    def instances(self) -> list[Instance]:
        """Every node of the scene that draws a mesh, depth first (collision-only and degenerate nodes skipped)."""
        if not self.nodes and not (self.doc.get("scenes") or []):
            meshes = self.doc.get("meshes", []) or []
            return [Instance(-1, m, np.eye(4), self._weights({}, m), None) for m in range(len(meshes))]
        out: list[Instance] = []
        collision: list[str] = []
        degenerate: list[str] = []
        stack: list[tuple[int, tuple[int, ...]]] = [(r, ()) for r in reversed(self.roots())]
        while stack:
            node_index, ancestors = stack.pop()
            if node_index in ancestors:
                raise self.fail(f"node {node_index} is its own ancestor (the node hierarchy has a cycle)")
            node = self.nodes[node_index]
            if "mesh" in node:
                mesh = index(self.doc, "meshes", node["mesh"], f"node {node_index}'s mesh", self.path)
                skin = (index(self.doc, "skins", node["skin"], f"node {node_index}'s skin", self.path)
                        if "skin" in node else None)
                world = self.world(node_index)
                label = f"{node_index}" + (f" '{node['name']}'" if node.get("name") else "")
                if is_collision_only(node.get("name")):
                    collision.append(str(node["name"]))
                elif skin is None and is_degenerate(world[:3, :3]):
                    degenerate.append(label)
                else:
                    out.append(Instance(node_index, mesh, world, self._weights(node, mesh, node_index), skin))
            for child in reversed(node.get("children", []) or []):
                stack.append((int(child), ancestors + (node_index,)))
        if collision:
            log.warning("load: %s: %d collision-only node(s) skipped (%s%s): engines import them as collision, "
                        "not as the visible asset", self.path, len(collision),
                        ", ".join(collision[:3]), ", ..." if len(collision) > 3 else "")
        if degenerate:
            log.warning("load: %s: %d node(s) with a degenerate transform (a zero scale: drawn flat or as nothing) "
                        "skipped: node %s%s", self.path, len(degenerate), ", ".join(degenerate[:3]),
                        ", ..." if len(degenerate) > 3 else "")
        return out

    def _weights(self, node: dict, mesh: int, node_index: int | None = None) -> np.ndarray:
        spec = self.doc["meshes"][mesh]
        primitives = spec.get("primitives", []) or []
        targets = len((primitives[0].get("targets") or []) if primitives else [])
        for p, prim in enumerate(primitives):
            if len(prim.get("targets") or []) != targets:
                raise self.fail(f"mesh {mesh}: primitive {p} has {len(prim.get('targets') or [])} morph targets "
                                f"and primitive 0 has {targets} (the spec requires the same number)")
        where, weights = (f"node {node_index}", node["weights"]) if "weights" in node else \
            (f"mesh {mesh}", spec.get("weights"))
        if weights is None or targets == 0:
            return np.zeros(targets)
        values = np.asarray(weights, dtype=np.float64).reshape(-1)
        if len(values) != targets:
            raise self.fail(f"{where} has {len(values)} morph weights for {targets} morph targets")
        if not np.all(np.isfinite(values)):
            raise self.fail(f"{where} has non-finite morph weights")
        return values

    def skin_matrices(self, skin: int, inverse_bind: np.ndarray | None) -> np.ndarray:
        """The joint matrices (j, 4, 4) ``world(joint) @ inverseBind`` of skin ``skin`` in the scene's pose."""
        joints = self.doc["skins"][skin].get("joints") or []
        if not joints:
            raise self.fail(f"skin {skin} has no joints")
        if inverse_bind is not None and len(inverse_bind) != len(joints):
            raise self.fail(f"skin {skin} has {len(joints)} joints but {len(inverse_bind)} inverse bind matrices")
        out = np.empty((len(joints), 4, 4))
        for k, joint in enumerate(joints):
            node = index(self.doc, "nodes", joint, f"skin {skin}'s joint {k}", self.path)
            out[k] = self.world(node) @ (inverse_bind[k] if inverse_bind is not None else np.eye(4))
        return out


def morphed(reader: _Reader, prim: dict, positions: np.ndarray, normals: np.ndarray | None, weights: np.ndarray,
            what: str) -> tuple[np.ndarray, np.ndarray | None]:
    """Positions and normals with the morph targets added at ``weights`` (spec 3.7.2.2), in target order."""
    targets = prim.get("targets") or []
    if not len(targets) or not np.any(weights != 0):
        return positions, normals
    positions = positions.copy()
    normals = normals.copy() if normals is not None else None
    for t, (target, weight) in enumerate(zip(targets, weights)):
        if weight == 0:
            continue
        for name, values in (("POSITION", positions), ("NORMAL", normals)):
            if name not in target or values is None:
                continue
            delta = reader.attribute(target, name, f"{what} morph target {t}", (3, 4))[:, :3]
            if delta.shape != values.shape:
                raise reader.fail(f"{what} morph target {t}'s {name} has {len(delta)} values for "
                                  f"{len(values)} vertices")
            values += weight * delta
    return positions, normals


def _apply(linear: np.ndarray, rows: np.ndarray) -> np.ndarray:
    """``linear[v] @ rows[v]`` for every v: (v, 3, 3) times (v, 3), as products in a fixed order."""
    return linear[:, :, 0] * rows[:, 0, None] + linear[:, :, 1] * rows[:, 1, None] + linear[:, :, 2] * rows[:, 2, None]


def skinned(reader: _Reader, attributes: dict, skin: int, positions: np.ndarray, normals: np.ndarray | None,
            faces: np.ndarray, what: str) -> tuple[np.ndarray, np.ndarray | None, np.ndarray]:
    """Vertices placed by their joints (spec 3.7.3): ``sum_k w_k * joint matrix_k``, per vertex."""
    spec = reader.doc["skins"][skin]
    inverse_bind = None
    if "inverseBindMatrices" in spec:
        acc = reader.index("accessors", spec["inverseBindMatrices"], f"skin {skin}'s inverseBindMatrices")
        if reader.doc["accessors"][acc].get("type") != "MAT4":
            raise reader.fail(f"skin {skin}'s inverseBindMatrices (accessor {acc}) are not MAT4")
        inverse_bind = reader.accessor(acc).reshape(-1, 4, 4).transpose(0, 2, 1)  # column-major
    joints = reader.scene.skin_matrices(skin, inverse_bind)
    sets = sorted(int(k[7:]) for k in attributes if k.startswith("JOINTS_") and k[7:].isdigit())
    if not sets:
        raise reader.fail(f"{what} is skinned (skin {skin}) but has no JOINTS_0 / WEIGHTS_0 attributes")
    influences = []
    for k in sets:
        if f"WEIGHTS_{k}" not in attributes:
            raise reader.fail(f"{what} has JOINTS_{k} but no WEIGHTS_{k}")
        ids = reader.accessor(reader.index("accessors", attributes[f"JOINTS_{k}"], f"{what}'s JOINTS_{k}"),
                              as_float=False)
        w = reader.attribute(attributes, f"WEIGHTS_{k}", what, widths=(4,))
        if len(ids) != len(positions) or len(w) != len(positions) or ids.shape[1] != 4:
            raise reader.fail(f"{what}'s JOINTS_{k} / WEIGHTS_{k} do not give four joints per vertex")
        if ids.size and (ids.min() < 0 or ids.max() >= len(joints)):
            raise reader.fail(f"{what}'s JOINTS_{k} names joint {int(ids.max())}; skin {skin} has {len(joints)}")
        influences.append((ids, w))
    total = np.zeros(len(positions))
    for _, w in influences:
        for c in range(4):
            total += w[:, c]
    if np.any(~(total > 0)):
        raise reader.fail(f"{what} has {int(np.sum(~(total > 0)))} skinned vertices whose joint weights are all 0")
    vertices = np.empty_like(positions)
    det = np.empty(len(positions))
    out_normals = np.empty_like(normals) if normals is not None else None
    for start in range(0, len(positions), _SKIN_CHUNK):  # (chunk, 4, 4) blends, not one per vertex at once
        rows = slice(start, start + _SKIN_CHUNK)
        blend = np.zeros((len(total[rows]), 4, 4))
        for ids, w in influences:
            for c in range(4):
                blend += w[rows, c, None, None] * joints[ids[rows, c]]
        blend /= total[rows, None, None]  # weights sum to 1 by the spec; exporters round them
        linear = blend[:, :3, :3]
        vertices[rows] = _apply(linear, positions[rows]) + blend[:, :3, 3]
        det[rows] = determinant3(linear)
        if normals is not None and out_normals is not None:
            # Inverse transpose = cofactor / det: the cofactor keeps singular joints finite (their normals are 0).
            n = _apply(cofactor3(linear), normals[rows]) * np.where(det[rows] < 0, -1.0, 1.0)[:, None]
            out_normals[rows] = unit_rows(n)
    mirrored = det[faces] < 0  # a triangle whose three corners are mirrored is turned back outwards
    faces = np.where(mirrored.all(axis=1)[:, None], faces[:, ::-1], faces)
    return vertices, out_normals, faces


def unit_rows(n: np.ndarray) -> np.ndarray:
    """Rows of ``n`` (k, 3) scaled to unit length; zero rows stay zero (never NaN)."""
    length = np.linalg.norm(n, axis=1, keepdims=True)
    return np.divide(n, length, out=np.zeros_like(n), where=length > 0)


def placed(world: np.ndarray, positions: np.ndarray, normals: np.ndarray | None,
           faces: np.ndarray) -> tuple[np.ndarray, np.ndarray | None, np.ndarray]:
    """Positions, normals and faces of a primitive placed by its node's (non-degenerate) world matrix (4, 4)."""
    linear = world[:3, :3]
    if determinant3(linear) < 0:  # a mirroring transform turns triangles inside out
        faces = faces[:, ::-1]
    if normals is not None:
        normals = unit_rows(normals @ np.linalg.inv(linear))  # the inverse transpose, as rows
    return positions @ linear.T + world[:3, 3], normals, faces
