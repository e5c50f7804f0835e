"""Naming conventions that change what a glTF node or material means.

Engines read some node names as collision geometry rather than something to
draw: Unreal's ``UCX_`` (convex), ``UBX_`` (box), ``USP_`` (sphere) and
``UCP_`` (capsule) prefixes, and Godot's ``-colonly`` / ``-convcolonly``
import suffixes. A fracture bake must not cut those meshes as if they were part
of the visible asset (they overlap it), so the reader skips them.

A GLB written by ``fracture`` prefixes its material names with the asset's stem
(``chair_wood``, ``chair_interior``) so that two baked assets in one scene do
not share materials. Baking such a file again (fracturing a fragment further)
reads the names without that prefix, so the old fault faces keep the
``interior`` slot and the new names are not prefixed twice.
"""
from __future__ import annotations

import re
from collections import Counter

#: Unreal Engine's static-mesh collision prefixes (FBX/glTF import).
UNREAL_COLLISION_PREFIXES = ("UCX_", "UBX_", "USP_", "UCP_")
#: Godot's import hints that make a node collision only (no visual mesh).
GODOT_COLLISION_SUFFIXES = ("-colonly", "-convcolonly")

_FRAGMENT_NODE = re.compile(r"^(?P<stem>.+)_fragment_\d{3,}$")


def is_collision_only(node_name: str | None) -> bool:
    """True when an engine would import the node named ``node_name`` as collision geometry only."""
    if not node_name:
        return False
    return node_name.startswith(UNREAL_COLLISION_PREFIXES) or node_name.lower().endswith(GODOT_COLLISION_SUFFIXES)


def baked_material_prefix(doc: dict) -> str:
    """``"<stem>_"`` when ``doc`` was written by fracture with stem-prefixed names, else ``""``.

    The stem is read from the fragment nodes' names (``<stem>_fragment_###``),
    all of which must agree; the generator must be fracture's.
    """
    generator = str((doc.get("asset") or {}).get("generator", ""))
    if not generator.startswith("fracture"):
        return ""
    stems = Counter(m.group("stem") for node in doc.get("nodes", []) or []
                    if (m := _FRAGMENT_NODE.match(str(node.get("name", "")))))
    if len(stems) != 1:
        return ""
    return next(iter(stems)) + "_"


def unprefixed(name: str, prefix: str) -> str:
    """``name`` without ``prefix`` (when it has it and something is left)."""
    return name[len(prefix):] if prefix and name.startswith(prefix) and len(name) > len(prefix) else name
