"""Regroup the fragments of a baked GLB after an impact: one mesh per group.

Used by ``fracture impact ... -o broken.glb`` to show which fragments an impact
separates. The fragments GLB is rewritten at the glTF level rather than through
a mesh library: the groups reuse the fragments' own primitives (same buffers,
accessors, materials and textures), so the output is lossless, exact and
deterministic.
"""

from __future__ import annotations

import os

import numpy as np

from fracture_cli.errors import InputError
from fracture_cli.io.atomic import write_bytes_atomic
from fracture_cli.io.gltf import pack_glb, read_glb_chunks

_TRANSFORM_KEYS = ("matrix", "translation", "rotation", "scale")


def group_name(group: int) -> str:
    """Node name of a group, after its smallest fragment index."""
    return f"group_{group:03d}"


def write_groups_glb(fragments_glb_path: str | os.PathLike, groups, out_path: str | os.PathLike,
                     fragment_names: tuple[str, ...] | None = None) -> list[str]:
    """Write a GLB with one node (and one mesh) per group of fragments.

    Parameters
    ----------
    fragments_glb_path : path
        The baked fragments GLB: one node per fragment, named as ``fragment_names`` says.
    groups : (p,) int
        Group of every fragment, e.g. ``ImpactResult.groups``.
    out_path : path
        Output ``.glb``; written atomically.
    fragment_names : tuple of str, optional (default ``fragment_000``, ...)
        Node name of fragment ``j`` (``RuntimeData.fragment_names``).

    Returns
    -------
    list of str
        The group node names, in order of group id.

    Notes
    -----
    Group ``g`` becomes node ``group_{g:03d}`` whose mesh holds the primitives
    of all its fragments (in fragment order); ``extras.fragments`` lists them.
    When the fragments of a group carry different node transforms, the group
    node gets the fragment nodes as children instead.
    """
    path = os.fspath(fragments_glb_path)
    groups = np.asarray(groups).astype(np.int64).reshape(-1)
    p = len(groups)
    if fragment_names is None:
        fragment_names = tuple(f"fragment_{j:03d}" for j in range(p))
    if len(fragment_names) != p:
        raise InputError(f"{len(fragment_names)} fragment names for {p} groups entries", path=path)
    doc, binary = read_glb_chunks(path)
    nodes = doc.get("nodes", [])
    by_name = {node.get("name"): index for index, node in enumerate(nodes) if "name" in node}
    missing = [name for name in fragment_names if name not in by_name]
    if missing:
        raise InputError(f"{len(missing)} of {p} fragment nodes are missing from the GLB (first: {missing[0]}); "
                         "is this the fragments file of the same bake?", path=path)
    old_meshes = doc.get("meshes", [])
    new_nodes, new_meshes, names = [], [], []
    for group in np.unique(groups).tolist():
        members = np.flatnonzero(groups == group).tolist()
        member_nodes = [nodes[by_name[fragment_names[j]]] for j in members]
        name = group_name(group)
        names.append(name)
        transforms = [{key: node[key] for key in _TRANSFORM_KEYS if key in node} for node in member_nodes]
        extras = {"fragments": [fragment_names[j] for j in members]}
        if all(t == transforms[0] for t in transforms):
            primitives = [prim for node in member_nodes if "mesh" in node
                          for prim in old_meshes[node["mesh"]]["primitives"]]
            group_node = {"name": name, "extras": extras, **transforms[0]}
            if primitives:
                new_meshes.append({"name": name, "primitives": primitives})
                group_node["mesh"] = len(new_meshes) - 1
            new_nodes.append(group_node)
        else:
            children = []
            for j, node in zip(members, member_nodes):
                child = {key: value for key, value in node.items() if key != "children"}
                if "mesh" in node:
                    new_meshes.append(dict(old_meshes[node["mesh"]], name=fragment_names[j]))
                    child["mesh"] = len(new_meshes) - 1
                new_nodes.append(child)
                children.append(len(new_nodes) - 1)
            new_nodes.append({"name": name, "extras": extras, "children": children})
    out = _without_physics(doc)
    for node in new_nodes:
        _drop_physics(node)
    out["nodes"] = new_nodes
    out["meshes"] = new_meshes
    group_nodes = [i for i, node in enumerate(new_nodes) if node.get("name") in set(names)]
    out["scenes"] = [{"nodes": group_nodes}]
    out["scene"] = 0
    write_bytes_atomic(out_path, pack_glb(out, binary))
    return names


# Physics extensions of the fragments file: their shapes point at meshes this file renumbers, and a group is not
# one rigid body of the bake, so the groups file carries none.
_PHYSICS_EXTENSIONS = ("OMI_physics_body", "OMI_physics_shape")


def _without_physics(doc: dict) -> dict:
    out = dict(doc)
    extensions = {k: v for k, v in doc.get("extensions", {}).items() if k not in _PHYSICS_EXTENSIONS}
    out.pop("extensions", None)
    if extensions:
        out["extensions"] = extensions
    for key in ("extensionsUsed", "extensionsRequired"):
        kept = [e for e in doc.get(key, []) if e not in _PHYSICS_EXTENSIONS]
        out.pop(key, None)
        if kept:
            out[key] = kept
    return out


def _drop_physics(node: dict) -> None:
    extensions = {k: v for k, v in node.get("extensions", {}).items() if k not in _PHYSICS_EXTENSIONS}
    node.pop("extensions", None)
    if extensions:
        node["extensions"] = extensions
