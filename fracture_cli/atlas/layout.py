"""Where the fragments are and how much each weighs, for the atlas's figures.

The runtime file's required arrays (docs/FORMAT.md section 2) say how fragments
respond but not where they are. The atlas takes fragment volumes and centroids,
in this order of preference:

1. ``gameready``: the optional arrays of docs/FORMAT.md section 9
   (``fragment_volume`` and ``fragment_center_of_mass``), which every current
   bake writes;
2. ``glb``: the fragments GLB beside the runtime file (``<stem>.glb``): volume and
   centre of mass of each fragment node's closed mesh (divergence theorem,
   :func:`fracture_cli.geometry.mass.mass_properties`), the same quantities
   from the geometry, for files baked before the game-ready arrays;
3. ``none``: no positions (a synthetic file); every fragment weighs the same and
   the figures that need positions (hit fragment, locality) are undefined.

A fragment's *centroid* is its centre of mass (not its mean vertex: a fragment's
mesh can be dense in one corner); the asset's centre is the volume-weighted
mean of the fragments' centres (its centre of mass), or the mean of the contact
sites without positions.

The fragment a hit lands on (:meth:`FragmentLayout.hit_fragment`) is the one a
game's collider reports: the fragment whose convex collision parts (the
game-ready arrays) lie nearest the hit point. Where a file has no parts, it is
the fragment whose centroid is nearest (the hit may then be attributed to a
smaller neighbour whose centre lies closer than the centre of the fragment hit).
"""

from __future__ import annotations

import logging
import os
from dataclasses import dataclass

import numpy as np

from fracture_cli.atlas.hits import nearest_fragment
from fracture_cli.geometry.parts import gameready_parts, nearest_part, part_planes
from fracture_cli.runtime.format import RuntimeData

log = logging.getLogger(__name__)


@dataclass(frozen=True, eq=False)
class FragmentLayout:
    """Volumes and centroids of the fragments.

    Attributes
    ----------
    volumes : (p,) float64
        Fragment volumes (asset units cubed), or all ones without positions.
    centroids : (p, 3) float64 or None
        Centres of mass, model space; None when unknown.
    source : str
        ``"gameready"``, ``"glb"`` or ``"none"`` (module docstring).
    """

    volumes: np.ndarray
    centroids: np.ndarray | None
    source: str
    part_planes: tuple[tuple[np.ndarray, ...], ...] | None = None

    def hit_fragment(self, point: np.ndarray) -> int | None:
        """The fragment (index) a hit at ``point`` (3,) lands on (module docstring); None without positions.

        With collision parts: the smallest over a fragment's parts of the part's largest plane value
        ``n . x + c`` (0 on the part's surface, negative inside, outside a lower bound of the distance);
        ties by the smallest index.
        """
        if self.part_planes is None:
            return None if self.centroids is None else nearest_fragment(self.centroids, point)
        return nearest_part(self.part_planes, point)

    def asset_center(self, data: RuntimeData) -> np.ndarray:
        """The asset's centre (3,): volume-weighted mean of the centroids, else the mean contact site."""
        if self.centroids is None or not float(self.volumes.sum()) > 0.0:
            return np.asarray(data.sites, dtype=np.float64).mean(axis=0)
        weights = self.volumes / float(self.volumes.sum())
        return weights @ self.centroids


def fragment_layout(data: RuntimeData, glb_path: str | os.PathLike | None = None) -> FragmentLayout:
    """Volumes and centroids of ``data``'s fragments (module docstring for the sources).

    Parameters
    ----------
    data : RuntimeData
    glb_path : path, optional (default None)
        The fragments GLB, read only when ``data`` has no game-ready arrays and
        the file exists.

    Returns
    -------
    FragmentLayout
    """
    if data.gameready:
        return FragmentLayout(volumes=np.asarray(data.gameready["fragment_volume"], dtype=np.float64),
                              centroids=np.asarray(data.gameready["fragment_center_of_mass"], dtype=np.float64),
                              source="gameready", part_planes=_part_planes(data.gameready, data.p))
    if glb_path is not None and os.path.exists(glb_path):
        layout = _layout_from_glb(data, os.fspath(glb_path))
        if layout is not None:
            return layout
    return FragmentLayout(volumes=np.ones(data.p), centroids=None, source="none")


def _part_planes(gameready: dict[str, np.ndarray], p: int) -> tuple[tuple[np.ndarray, ...], ...] | None:
    """Per fragment, each convex part's face planes (:func:`fracture_cli.geometry.parts.part_planes`)."""
    return part_planes(gameready_parts(gameready, p))


def _layout_from_glb(data: RuntimeData, glb_path: str) -> FragmentLayout | None:
    """Mass properties of the GLB's fragment nodes, matched by name; None if a fragment is missing."""
    # Function-level imports: the GLB reader and the mass integrals are only needed for old files.
    from fracture_cli.geometry.mass import mass_properties
    from fracture_cli.io.gltf import glb_meshes, read_glb_chunks

    doc, binary = read_glb_chunks(glb_path)
    by_name = {mesh.name: mesh for mesh in glb_meshes(doc, binary)}
    volumes = np.zeros(data.p)
    centroids = np.zeros((data.p, 3))
    for j, name in enumerate(data.fragment_names):
        mesh = by_name.get(name)
        if mesh is None:
            log.warning("atlas: %s has no node named %s; fragment positions unknown", glb_path, name)
            return None
        vertices, faces, base = [], [], 0
        for prim in mesh.primitives:
            vertices.append(prim.positions)
            faces.append(prim.indices + base)
            base += len(prim.positions)
        props = mass_properties(np.concatenate(vertices), np.concatenate(faces))
        volumes[j], centroids[j] = props.volume, props.center
    return FragmentLayout(volumes=volumes, centroids=centroids, source="glb")
