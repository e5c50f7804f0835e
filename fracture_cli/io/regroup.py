"""Regroup the fragments of a baked GLB after an impact: one mesh per group.

Used by ``fracture impact ... -o broken.glb`` to show which fragments an impact
separates. The fragments GLB is rewritten at the glTF level rather than through
a mesh library: the groups reuse the fragments' own primitives (same buffers,
accessors, materials and textures), so the output is lossless, exact and
deterministic.
"""

from __future__ import annotations

import json
import os
import struct

import numpy as np

from fracture_cli.errors import InputError
from fracture_cli.io.atomic import write_bytes_atomic

_GLB_MAGIC = b"glTF"
_CHUNK_JSON = 0x4E4F534A
_CHUNK_BIN = 0x004E4942
_TRANSFORM_KEYS = ("matrix", "translation", "rotation", "scale")


def _read_glb(path: str) -> tuple[dict, bytes | None]:
    try:
        with open(path, "rb") as handle:
            raw = handle.read()
    except FileNotFoundError:
        raise InputError("fragments file not found", path=path) from None
    if len(raw) < 20 or raw[:4] != _GLB_MAGIC:
        raise InputError("not a binary glTF (.glb) file", path=path)
    _, version, total = struct.unpack_from("<4sII", raw, 0)
    if version != 2 or total > len(raw):
        raise InputError(f"unsupported or truncated GLB (version {version}, {len(raw)} of {total} bytes)", path=path)
    offset, doc, binary = 12, None, None
    while offset + 8 <= total:
        length, kind = struct.unpack_from("<II", raw, offset)
        chunk = raw[offset + 8: offset + 8 + length]
        if len(chunk) != length:
            raise InputError("truncated GLB chunk", path=path)
        if kind == _CHUNK_JSON and doc is None:
            doc = json.loads(chunk.decode("utf-8"))
        elif kind == _CHUNK_BIN and binary is None:
            binary = chunk
        offset += 8 + length
    if doc is None:
        raise InputError("GLB has no JSON chunk", path=path)
    return doc, binary


def _glb_bytes(doc: dict, binary: bytes | None) -> bytes:
    text = json.dumps(doc, separators=(",", ":"), sort_keys=False).encode("utf-8")
    text += b" " * ((4 - len(text) % 4) % 4)
    chunks = struct.pack("<II", len(text), _CHUNK_JSON) + text
    if binary is not None:
        binary = binary + b"\0" * ((4 - len(binary) % 4) % 4)
        chunks += struct.pack("<II", len(binary), _CHUNK_BIN) + binary
    return struct.pack("<4sII", _GLB_MAGIC, 2, 12 + len(chunks)) + chunks


def group_name(group: int) -> str:
    """Node name of a group, after its smallest fragment index."""
    return f"group_{group:03d}"


def write_groups_glb(fragments_glb_path: str | os.PathLike, groups, out_path: str | os.PathLike,
                     fragment_names: tuple[str, ...] | None = None) -> list[str]:
    """Write a GLB with one node (and one mesh) per group of fragments.

    Parameters
    ----------
    fragments_glb_path : path
        The baked fragments GLB: one node per fragment, named ``fragment_###``.
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
    doc, binary = _read_glb(path)
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
    out = dict(doc)
    out["nodes"] = new_nodes
    out["meshes"] = new_meshes
    group_nodes = [i for i, node in enumerate(new_nodes) if node.get("name") in set(names)]
    out["scenes"] = [{"nodes": group_nodes}]
    out["scene"] = 0
    write_bytes_atomic(out_path, _glb_bytes(out, binary))
    return names
