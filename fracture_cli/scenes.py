"""open3d ray-casting scenes of the input surface, built once per bake.

The cage stage (distances to the input) and the pieces stage (which sample
points are inside it) query the same million-triangle surface; building the
scene's BVH is most of the first query's cost (0.6 s at a million
triangles). The last scene built is kept for as long as the arrays it was
built from live, and given back for the same arrays.
"""

from __future__ import annotations

import weakref
from typing import Any

import numpy as np

_last: dict[str, Any] = {}


def surface_scene(vertices: np.ndarray, faces: np.ndarray) -> Any:
    """An ``open3d.t.geometry.RaycastingScene`` of triangles ``faces`` (m, 3) int over ``vertices`` (n, 3) float.

    The same scene for the same two array objects (not copies), while they live; the arrays are never
    changed in place (surfaces are immutable), so it answers as a new one would.
    """
    from fracture_cli._open3d import open3d as _import_open3d

    refs = _last.get("arrays")
    if refs is not None and refs[0]() is vertices and refs[1]() is faces:
        return _last["scene"]
    o3d = _import_open3d()
    scene = o3d.t.geometry.RaycastingScene()
    scene.add_triangles(o3d.core.Tensor(np.asarray(vertices, dtype=np.float32)),
                        o3d.core.Tensor(np.asarray(faces, dtype=np.uint32)))
    _last.clear()
    try:
        # Forget the scene with its arrays (the next asset of a batch must not keep this one's alive).
        _last["arrays"] = (weakref.ref(vertices, _forget), weakref.ref(faces, _forget))
    except TypeError:  # arrays that cannot be weakly referenced are not kept
        return scene
    _last["scene"] = scene
    return scene


def _forget(_: Any) -> None:
    _last.clear()
