"""Write surfaces and fragments, one writer per format, always atomically."""

from __future__ import annotations

import dataclasses
import logging
import os
from collections.abc import Sequence

import numpy as np

from fracture_cli.errors import InputError
from fracture_cli.io.atomic import atomic_path, write_bytes_atomic
from fracture_cli.io.gltf import Primitive, glb_bytes
from fracture_cli.io.names import child_name, fragment_name, mtl_name
from fracture_cli.io.physics import OMI_BODY, FragmentPhysics, node_origin
from fracture_cli.types import Fragments, Normalization, SurfaceMesh

log = logging.getLogger(__name__)

WRITERS = (".glb", ".obj", ".ply", ".stl", ".off")


def split_by_material(vertices, faces, normals, uvs, material_ids, normalization: Normalization,
                      origin=None) -> list[Primitive]:
    """Split a mesh into one primitive per material, in world units.

    Parameters
    ----------
    vertices : (n, 3) float
        Normalized positions.
    faces : (m, 3) int
    normals : (n, 3) float
    uvs : (n, 2) float or None
    material_ids : (m,) int
    normalization : Normalization
        Maps positions back to the input's units.
    origin : (3,) float, optional (default 0)
        Subtracted from the world positions (the node's translation), in float64
        before the float32 conversion, so assets far from the origin keep their
        precision.

    Returns
    -------
    list of Primitive
        Sorted by material id; each with only the vertices it uses (in
        increasing id order, so output is deterministic).
    """
    world = normalization.to_world(vertices)
    if origin is not None:
        world = world - np.asarray(origin, dtype=np.float64)
    prims = []
    for mat in np.unique(material_ids):
        sel = faces[material_ids == mat]
        used, local = _compact(sel, len(vertices))
        prims.append(
            Primitive(
                positions=world[used],
                normals=normals[used],
                uvs=None if uvs is None else uvs[used],
                indices=local.reshape(-1, 3),
                material=int(mat),
            )
        )
    return prims


def save_surface(path: str | os.PathLike, surface: SurfaceMesh) -> None:
    """Write ``surface`` in the input's units; the format follows the extension.

    Parameters
    ----------
    path : str or PathLike
        Output file: .glb, .obj, .ply, .stl or .off.
    surface : SurfaceMesh

    Raises
    ------
    InputError
        Unsupported extension.
    """
    path = os.fspath(path)
    ext = os.path.splitext(path)[1].lower()
    if ext not in WRITERS:
        raise InputError(f"cannot write '{ext or '(none)'}'; pick one of {', '.join(WRITERS)}", path=path)
    normals = surface.normals if surface.normals is not None else np.zeros_like(surface.vertices)
    if ext == ".glb":
        origin = node_origin(surface.normalization.to_world(surface.vertices))
        prims = split_by_material(surface.vertices, surface.faces, normals, surface.uvs, surface.material_ids,
                                  surface.normalization, origin)
        name = os.path.splitext(surface.name)[0] or "mesh"
        write_bytes_atomic(path, glb_bytes([(name, prims, origin)], surface.materials))
        return
    import trimesh

    mesh = trimesh.Trimesh(
        vertices=surface.world_vertices(), faces=surface.faces, vertex_normals=normals, process=False
    )
    if ext == ".obj":
        _save_obj(path, mesh, surface.uvs)
        return
    with atomic_path(path) as tmp:
        mesh.export(tmp, file_type=ext[1:])


def _save_obj(path: str, mesh, uvs) -> None:
    """Write an OBJ (with UVs: and its ``<stem>.mtl``), each file atomically, nothing else beside it.

    trimesh's own file export would also write ``material.mtl`` and a texture
    under fixed names next to the output, over whatever has those names; here the
    material has no image and the library is named after the output.
    """
    import trimesh
    from trimesh.exchange.obj import export_obj

    mtl = mtl_name(path)
    if uvs is not None:
        material = trimesh.visual.material.SimpleMaterial(name=mtl[: -len(".mtl")])
        mesh.visual = trimesh.visual.TextureVisuals(uv=uvs, material=material)
    text, companions = export_obj(mesh, return_texture=True, mtl_name=mtl)
    folder = os.path.dirname(path)
    for name, data in companions.items():
        if name != mtl:  # only the library fracture_cli.io.names.surface_outputs() names is written
            continue
        write_bytes_atomic(os.path.join(folder, name), data)
    write_bytes_atomic(path, text.encode("utf-8"))


def prefixed_materials(materials, stem: str | None):
    """``materials`` renamed ``<stem>_<name>`` (``chair_interior``): engines share materials by name across files."""
    import dataclasses

    if not stem:
        return tuple(materials)
    return tuple(dataclasses.replace(m, name=f"{stem}_{m.name}") for m in materials)


def _compact(faces: np.ndarray, n: int) -> tuple[np.ndarray, np.ndarray]:
    """``np.unique(faces, return_inverse=True)`` of vertex ids ``faces`` (k, 3) in [0, n), by counting."""
    if faces.size == 0 or faces.min() < 0:
        return np.unique(faces, return_inverse=True)
    used = np.flatnonzero(np.bincount(faces.reshape(-1), minlength=n))
    local = np.zeros(max(n, int(faces.max()) + 1), dtype=np.intp)
    local[used] = np.arange(len(used))
    return used, local[faces]




def write_fragments_glb(path: str | os.PathLike, fragments: Fragments, pivot: str = "center_of_mass",
                        parts=None, collision: str = "none", stem: str | None = None,
                        physics: Sequence[FragmentPhysics] | None = None,
                        children: Sequence[tuple[int, Fragments, Sequence[FragmentPhysics]]] = ()) -> None:
    """Write all fragments to one GLB: one node and mesh per fragment, named ``<stem>_fragment_###``.

    Each mesh has one primitive per material it uses (the input's materials and
    the interior material). Each node is translated to its fragment's pivot and
    the positions are relative to it, so the fragments sit in the input's units
    and placement. Each node's ``extras.fracture`` holds the fragment's
    unit-density volume, centre of mass and inertia tensor (asset units; see
    :func:`fracture_cli.io.physics.node_extras`).

    Parameters
    ----------
    pivot : {"center_of_mass", "bbox"}, optional (default "center_of_mass")
        Node origins at the centre of mass (where engines put a rigid body's
        origin) or at the bounding-box centre.
    parts : sequence of sequence of (k, 3) float, optional
        Convex collision parts of every fragment (corners, model space), from
        the ``collision`` stage.
    collision : {"omi", "godot", "unreal", "none"}, optional (default "none")
        How the parts are written (:mod:`fracture_cli.io.physics`).
    stem : str, optional
        The asset's stem: prefix of node, mesh and material names (``chair_fragment_000``,
        ``chair_interior``); without it the names are unprefixed.
    physics : sequence of FragmentPhysics, optional
        Mass properties, pivots and parts of every fragment as the pipeline computed them
        (:func:`fracture_cli.io.physics.fragment_physics`); computed here from ``pivot`` and
        ``parts`` when not given.
    children : sequence of (int, Fragments, sequence of FragmentPhysics), optional
        Fragments broken again (levels, docs/FORMAT.md section 14.6): the parent's index, its children
        (same materials) and their physics. Each child is a node under its parent's node, named
        :func:`child_name`, positioned relative to it, its ``extras.fracture`` with ``"level": 2``; its
        collision parts as ``collision`` says, except ``omi`` (a dynamic body inside another: the parts
        are in the runtime file only).
    """
    # on first use: reading or writing one format loads only what it needs
    from fracture_cli.io.physics import fragment_physics, physics_extender

    if physics is None:
        physics = fragment_physics(fragments, parts, pivot)
    meshes = []
    for i, (frag, body) in enumerate(zip(fragments.fragments, physics)):
        prims = split_by_material(frag.vertices, frag.faces, frag.normals, frag.uvs, frag.material_ids,
                                  fragments.normalization, body.origin)
        meshes.append((fragment_name(i, stem), prims, body.origin))
    every, parents = list(physics), []
    for parent, kids, kid_physics in children:
        for j, (frag, body) in enumerate(zip(kids.fragments, kid_physics)):
            prims = split_by_material(frag.vertices, frag.faces, frag.normals, frag.uvs, frag.material_ids,
                                      kids.normalization, body.origin)
            meshes.append((child_name(fragment_name(parent, stem), j), prims, body.origin))
            every.append(dataclasses.replace(body, parts=()) if collision == "omi" else body)
            parents.append(parent)
    materials = prefixed_materials(fragments.materials, stem)
    extend = physics_extender(every, collision)
    if parents:
        extend = _nested(extend, len(physics), parents, every)
    write_bytes_atomic(path, glb_bytes(meshes, materials, extend=extend))


def _nested(extend, p: int, parents: list[int], physics: Sequence[FragmentPhysics]):
    """``extend`` followed by moving the child nodes ``p ..`` under their parents' nodes (one scene tree)."""
    def nest(doc: dict, buffer) -> None:
        extend(doc, buffer)
        nodes = doc["nodes"]
        doc["scenes"][0]["nodes"] = list(range(p))
        for offset, parent in enumerate(parents):
            node = nodes[p + offset]
            relative = np.asarray(physics[p + offset].origin, np.float64) - np.asarray(physics[parent].origin,
                                                                                        np.float64)
            node.pop("translation", None)
            if np.any(relative != 0):
                node["translation"] = [float(x) for x in relative]
            node.get("extensions", {}).pop(OMI_BODY, None)  # a dynamic body inside another is not a body
            if "extensions" in node and not node["extensions"]:
                del node["extensions"]
            node["extras"]["fracture"]["level"] = 2
            nodes[parent].setdefault("children", []).append(p + offset)

    return nest
