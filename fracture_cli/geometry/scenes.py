"""The input surface's :class:`~fracture_cli.geometry.surface_query.SurfaceQuery`, built once per bake.

The cage stage (distances to the input), the pieces stage (which sample
points are inside it) and the report's checks (distances of fragment
vertices to it) query the same surface, up to a million triangles, where
building the hierarchy takes most of a second. The last one built is kept
for as long as the arrays it was built from live, and given back for the same
arrays.
"""

from __future__ import annotations

import weakref
from typing import TYPE_CHECKING, Any

import numpy as np

if TYPE_CHECKING:
    from fracture_cli.geometry.surface_query import SurfaceQuery

_last: dict[str, Any] = {}


def surface_scene(vertices: np.ndarray, faces: np.ndarray) -> SurfaceQuery:
    """The :func:`~.surface_query.build` of triangles ``faces`` (m, 3) int over ``vertices`` (n, 3).

    The same one for the same two array objects (not copies), while they live; the arrays are never
    changed in place (surfaces are immutable), so it answers as a new one would.
    """
    refs = _last.get("arrays")
    if refs is not None and refs[0]() is vertices and refs[1]() is faces:
        return _last["query"]
    from fracture_cli.geometry.surface_query import build  # compiled (numba): imported when first needed

    query = build(vertices, faces)
    _last.clear()
    try:
        # Forget the hierarchy with its arrays (the next asset of a batch must not keep this one's alive).
        _last["arrays"] = (weakref.ref(vertices, _forget), weakref.ref(faces, _forget))
    except TypeError:  # arrays that cannot be weakly referenced are not kept
        return query
    _last["query"] = query
    return query


def _forget(_: Any) -> None:
    _last.clear()
