"""What a bake's and a chain's outputs are called: fragment and child node names, a saved surface's files,
the ways collision parts are written.

Apart from the writers so that checking the outputs before any work (the output guard, the bake's
preflight) loads neither the GLB writer nor the mesh libraries.
"""

from __future__ import annotations

import os

# How collision parts are written into the GLB (the collision stage's ``glb`` option): the parts' names and
# extensions depend on it.
COLLISION_FORMATS = ("omi", "godot", "unreal", "none")


def fragment_name(index: int, stem: str | None = None) -> str:
    """Stable node name of fragment ``index`` (export order): ``<stem>_fragment_###``, or ``fragment_###``.

    The asset's stem keeps two baked assets in one scene from colliding (an
    importer would rename the second ``fragment_000.001`` and the runtime
    file's names would no longer match).
    """
    return f"{stem}_fragment_{index:03d}" if stem else f"fragment_{index:03d}"


def child_name(parent: str, index: int) -> str:
    """The node name of a fragment's ``index``-th child: ``<parent>_c00``, ``<parent>_c01``, ... (docs/FORMAT.md 14.6).

    ``_c`` keeps it apart from the parent's collision-part nodes (``<parent>_00``, ``UCX_<parent>_00``).
    """
    return f"{parent}_c{index:02d}"


def surface_outputs(path: str) -> list[str]:
    """Every file :func:`save_surface` may write for ``path``: the file, and for an OBJ its ``<stem>.mtl``.

    The output guard checks all of them before any work.
    """
    if os.path.splitext(path)[1].lower() != ".obj":
        return [path]
    return [path, os.path.join(os.path.dirname(path), mtl_name(path))]


def mtl_name(path: str) -> str:
    """The material library of an OBJ output: named after it (no spaces: ``mtllib`` splits on them)."""
    stem = os.path.splitext(os.path.basename(path))[0]
    return "_".join(stem.split()) + ".mtl" if stem.strip() else "material.mtl"
