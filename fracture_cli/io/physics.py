"""Collision parts and mass properties in the fragments GLB, the way engines import them.

Four ways to write the convex parts of each fragment (the ``collision`` option):

``omi`` (default)
    The ``OMI_physics_shape`` and ``OMI_physics_body`` glTF extensions
    (omigroup/gltf-extensions). Every fragment node gets a body with
    ``motion: {type: "dynamic", mass, centerOfMass, inertiaDiagonal,
    inertiaOrientation}``; one child node per part carries ``collider:
    {shape: i}``, shape ``i`` being ``{type: "convex", convex: {mesh: m}}``.
    Godot 4 imports this as a ``RigidBody3D`` with ``CollisionShape3D``
    children; the shape meshes are referenced by no node, so viewers and
    importers that do not know the extensions show nothing extra.
``godot``
    One child node per part named ``<fragment>_NN-convcolonly`` with the
    part as its mesh: Godot's scene importer (3.x and 4.x) turns each into a
    ``StaticBody`` named ``<fragment>_NN`` with one convex shape and drops the
    visible mesh. The add-on's ``FractureBody`` (engines/godot) moves those
    shapes into its rigid bodies; other tools show them as ordinary meshes.
    Godot 3 builds that shape by a VHACD decomposition of the part, not from
    its corners, so it is slightly larger than the part (measured: touching
    fragments drift at ~0.1 m/s instead of ~0.005 with the exact parts).
``unreal``
    One child node and mesh per part named ``UCX_<fragment>_NN``: Unreal's
    FBX and Interchange importers attach such meshes as convex collision to
    the static mesh named ``<fragment>``.
``none``
    No collision data.

Mass properties go into every fragment node's ``extras`` whatever the format
(unit density, asset units; see :func:`node_extras`).

Parts of neighbouring fragments touch exactly. Engines that inflate convex
shapes by a collision margin (Bullet: 0.04 by default in Godot 3) must use a
small one (1e-4 asset units keeps resting fragments still; see
tests/test_gameready_engine.py).

The default is ``omi``: it is the only one of the four that carries mass and
inertia, that an importer can turn into a rigid body without a script, and
that leaves the file unchanged for tools that ignore it. The naming
conventions are opt-in because they add visible meshes everywhere else.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from fracture_cli.geometry import tolerances as tol
from fracture_cli.geometry.hulls import hull_mesh
from fracture_cli.geometry.mass import MassProperties, mass_properties, quaternion_xyzw
from fracture_cli.io.gltf import ARRAY_BUFFER, ELEMENT_ARRAY_BUFFER, FLOAT, UINT16
from fracture_cli.io.names import COLLISION_FORMATS
from fracture_cli.types import Fragments

PIVOTS = ("center_of_mass", "bbox")  # a fragment node's origin: its centre of mass or its bounding-box centre

__all__ = ["COLLISION_FORMATS", "PIVOTS", "FragmentPhysics", "fragment_physics", "node_extras", "node_origin",
           "physics_extender", "runtime_arrays"]
OMI_SHAPE = "OMI_physics_shape"
OMI_BODY = "OMI_physics_body"
GODOT_SUFFIX = "-convcolonly"
UNREAL_PREFIX = "UCX_"

_DECIMALS = 9


@dataclass(frozen=True)
class FragmentPhysics:
    """What the GLB says about one fragment node, in the asset's units and model space.

    Attributes
    ----------
    mass : MassProperties
        Unit-density volume, centre of mass and inertia (about the centre of
        mass), asset units (see :meth:`MassProperties.to_world`).
    origin : (3,) float
        The node's translation (its pivot); parts and the centre of mass are
        written relative to it.
    parts : sequence of (k, 3) float
        Corners of each convex part, model space.
    """

    mass: MassProperties
    origin: np.ndarray
    parts: Sequence[np.ndarray] = ()


def node_origin(world_points: np.ndarray) -> np.ndarray:
    """A node's pivot: the bounding-box centre of its points (3,), in input units.

    Game engines rotate a rigid body about its node's origin, so each fragment
    gets its own centre as pivot; positions are stored relative to it, which
    also keeps float32 precision for assets far from the origin.
    """
    return (world_points.min(axis=0) + world_points.max(axis=0)) / 2.0


def fragment_physics(fragments: Fragments, parts: Sequence[Sequence[np.ndarray]] | None = None,
                     pivot: str = "center_of_mass") -> list[FragmentPhysics]:
    """Mass properties (unit density, asset units), pivot and parts of every fragment, in order.

    Parameters
    ----------
    fragments : Fragments
        The fragments as the pipeline holds them (normalized coordinates).
    parts : sequence of sequence of (k, 3) float, optional
        Convex parts of every fragment, model space (the ``collision`` stage's).
    pivot : {"center_of_mass", "bbox"}, optional (default "center_of_mass")
        Where each node's origin goes.
    """
    out = []
    for index, frag in enumerate(fragments.fragments):
        mass = mass_properties(frag.vertices, frag.faces).to_world(fragments.normalization)
        if pivot == "center_of_mass":
            origin = mass.center
        else:
            origin = node_origin(fragments.normalization.to_world(frag.vertices))
        out.append(FragmentPhysics(mass=mass, origin=origin, parts=tuple(parts[index]) if parts else ()))
    return out


def node_extras(mass: MassProperties) -> dict:
    """The ``extras`` of a fragment node: its unit-density mass properties (asset units, model axes).

    ``{"fracture": {"volume": V, "center_of_mass": [x, y, z], "inertia": [Ixx, Iyy, Izz, Ixy, Ixz, Iyz]}}``;
    ``center_of_mass`` is in model space, ``inertia`` holds the tensor's entries
    about the centre of mass (off-diagonals are the negative products of
    inertia). Multiply volume and inertia by a density for mass and kg m^2.
    """
    inertia = mass.inertia6()
    # Products of inertia at rounding level (a box's) are written as zeros.
    inertia[np.abs(inertia) <= tol.ROUNDOFF * max(float(np.abs(inertia).max()), tol.SMALLEST_DIVISOR)] = 0.0
    return {"fracture": {
        "volume": _round(mass.volume),
        "center_of_mass": [_round(x) for x in mass.center],
        "inertia": [_round(x) for x in inertia],
    }}


def physics_extender(physics: Sequence[FragmentPhysics], collision: str = "omi", density: float = 1000.0):
    """A ``extend(doc, buffer)`` callback for :func:`fracture_cli.io.gltf.glb_bytes`.

    Parameters
    ----------
    physics : sequence of FragmentPhysics
        One per fragment node, in node order (node ``i`` is fragment ``i``).
    collision : {"omi", "godot", "unreal", "none"}, optional (default "omi")
        How the convex parts are written (module docstring).
    density : float, optional (default 1000)
        kg per cubic asset unit, for ``OMI_physics_body`` mass and inertia
        (glTF's unit is the metre; 1000 is water). The ``extras`` stay at unit
        density.

    Returns
    -------
    callable
        Adds the parts, the bodies and the ``extras`` to the document.

    Raises
    ------
    ValueError
        An unknown ``collision`` format (the option layer checks choices first).
    """
    if collision not in COLLISION_FORMATS:
        raise ValueError(f"collision = {collision!r} is not one of {', '.join(COLLISION_FORMATS)}")

    def extend(doc: dict, buffer) -> None:
        nodes, meshes = doc["nodes"], doc["meshes"]
        shapes: list[dict] = []
        for index, body in enumerate(physics):
            node = nodes[index]
            node["extras"] = node_extras(body.mass)
            if collision == "none":
                continue
            children = []
            for k, corners in enumerate(body.parts):
                name = _part_name(node["name"], k, collision)
                meshes.append({"name": name, "primitives": [_hull_primitive(corners, body.origin, buffer)]})
                child: dict[str, Any] = {"name": name}
                if collision == "omi":
                    shapes.append({"type": "convex", "convex": {"mesh": len(meshes) - 1}})
                    child["extensions"] = {OMI_BODY: {"collider": {"shape": len(shapes) - 1}}}
                else:
                    child["mesh"] = len(meshes) - 1
                nodes.append(child)
                children.append(len(nodes) - 1)
            if children:
                node["children"] = children
            if collision == "omi":
                node.setdefault("extensions", {})[OMI_BODY] = {"motion": _motion(body, density)}
        if collision == "omi" and physics:
            doc.setdefault("extensions", {})[OMI_SHAPE] = {"shapes": shapes}
            used = doc.setdefault("extensionsUsed", [])
            used.extend(e for e in (OMI_BODY, OMI_SHAPE) if e not in used)

    return extend


def _part_name(fragment: str, k: int, collision: str) -> str:
    if collision == "unreal":
        return f"{UNREAL_PREFIX}{fragment}_{k:02d}"
    if collision == "godot":
        return f"{fragment}_{k:02d}{GODOT_SUFFIX}"
    return f"{fragment}_{k:02d}"


def _hull_primitive(corners: np.ndarray, origin: np.ndarray, buffer) -> dict:
    """A positions-only triangle primitive of the convex hull of ``corners``, relative to ``origin``."""
    V, F = hull_mesh(np.asarray(corners, dtype=np.float64))
    positions = np.ascontiguousarray(V - np.asarray(origin, dtype=np.float64), dtype="<f4")
    indices = np.ascontiguousarray(F.reshape(-1), dtype="<u2")  # a convex part has < 256 corners
    return {
        "attributes": {"POSITION": buffer.add_accessor(positions, "VEC3", FLOAT, ARRAY_BUFFER, bounds=True)},
        "indices": buffer.add_accessor(indices, "SCALAR", UINT16, ELEMENT_ARRAY_BUFFER),
        "mode": 4,
    }


def _motion(body: FragmentPhysics, density: float) -> dict:
    """``OMI_physics_body.motion`` of a dynamic body: mass, centre of mass, principal inertia and its axes."""
    moments, axes = body.mass.principal()
    motion = {"type": "dynamic", "mass": _round(density * body.mass.volume)}
    offset = np.asarray(body.mass.center, dtype=np.float64) - np.asarray(body.origin, dtype=np.float64)
    if np.any(np.abs(offset) > 0):
        motion["centerOfMass"] = [_round(x) for x in offset]
    motion["inertiaDiagonal"] = [_round(density * m) for m in moments]
    motion["inertiaOrientation"] = [_round(q) for q in quaternion_xyzw(axes)]
    return motion


def _round(x: float) -> float:
    """A float for JSON with 9 significant digits (float32 precision and then some), -0.0 as 0.0."""
    value = float(f"{float(x):.{_DECIMALS}g}")
    return 0.0 if value == 0 else value


def runtime_arrays(physics: Sequence[FragmentPhysics]) -> dict[str, np.ndarray]:
    """The runtime-file arrays of the game-ready data (docs/FORMAT.md section 9).

    Returns
    -------
    dict of str -> array
        ``fragment_volume`` (p,) float32, ``fragment_center_of_mass`` (p, 3)
        float32 (model space), ``fragment_inertia`` (p, 6) float32 (``Ixx, Iyy,
        Izz, Ixy, Ixz, Iyz`` about the centre of mass, unit density),
        ``collision_vertices`` (n, 3) float32 (model space, each part's hull
        corners), ``collision_part_offsets`` (P + 1,) int32 (part ``k`` is
        vertices ``[off[k], off[k+1])``), ``collision_fragment_offsets``
        (p + 1,) int32 (fragment ``j`` owns parts ``[off[j], off[j+1])``).
    """
    parts = [np.asarray(c, dtype=np.float64).reshape(-1, 3) for body in physics for c in body.parts]
    part_sizes = [len(c) for c in parts]
    fragment_sizes = [len(body.parts) for body in physics]
    return {
        "fragment_volume": np.array([b.mass.volume for b in physics], dtype="<f4"),
        "fragment_center_of_mass": np.array([b.mass.center for b in physics], dtype="<f4").reshape(-1, 3),
        "fragment_inertia": np.array([b.mass.inertia6() for b in physics], dtype="<f4").reshape(-1, 6),
        "collision_vertices": (np.vstack(parts) if parts else np.zeros((0, 3))).astype("<f4"),
        "collision_part_offsets": np.concatenate([[0], np.cumsum(part_sizes)]).astype("<i4"),
        "collision_fragment_offsets": np.concatenate([[0], np.cumsum(fragment_sizes)]).astype("<i4"),
    }
