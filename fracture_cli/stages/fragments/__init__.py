"""Fragments: the input mesh intersected with each piece region (ALGORITHM.md section 6)."""

from __future__ import annotations

from typing import TYPE_CHECKING

from fracture_cli.stages.fragments.options import STAGE, FragmentOptions

if TYPE_CHECKING:
    from fracture_cli.stages.fragments.bodies import SplitReport
    from fracture_cli.types import Fragments, Regions, SurfaceMesh

__all__ = ["STAGE", "FragmentOptions", "fragments", "fragments_with_split"]


def fragments(surface: SurfaceMesh, regions: Regions, options: FragmentOptions = FragmentOptions()) -> Fragments:
    """Cut the input surface into closed one-body fragments (:func:`fragments_with_split`, without its report)."""
    return fragments_with_split(surface, regions, options)[0]


def fragments_with_split(surface: SurfaceMesh, regions: Regions,
                         options: FragmentOptions = FragmentOptions()) -> tuple[Fragments, SplitReport]:
    """Cut the input surface into one closed fragment per piece region, then one per connected body.

    Parameters
    ----------
    surface : SurfaceMesh
        The input as a closed solid, normalized coordinates: the result of
        :func:`~fracture_cli.stages.repair.repair` (the same surface the cage
        was built around). May have UV seams (split vertices), several
        materials, and an ``interior`` material slot (faces repair added).
    regions : Regions
        One closed region per piece, partitioning a volume that contains the input.
    options : FragmentOptions, optional
        ``uv_scale`` (default 1.0 world unit per UV unit).

    Returns
    -------
    fragments : Fragments
        Non-empty fragments, each one connected closed body, sorted by their centroid (x, then y, then z, rounded
        to 1e-6); ``Fragment.piece`` names the piece of each. ``materials`` are
        the input's plus the interior material as the last slot (or the
        input's own slot if one is already named ``interior``).
    split : SplitReport
        How many bodies each cut held and how many tiny ones were merged.

    Raises
    ------
    StageError
        If the input is not a closed solid (run ``repair`` first), or a region
        is not a valid closed mesh.

    Notes
    -----
    ALGORITHM.md section 6. The input is made a solid by the repair stage
    (welding, hole filling or shelling, union of overlapping bodies), so that
    the cage and the fragments agree on it; here it is only converted to a
    manifold3d solid (:func:`~fracture_cli.geometry.solids.surface_solid`:
    vertices at one position welded topologically, attributes kept).

    Each fragment is ``input ^ region`` in manifold3d with UV and normal as
    vertex properties: outer faces keep the input's values (interpolated where
    a face is cut), material ids travel as manifold3d run ids. Faces that come
    from the region are the new inside: interior material, flat normals
    (vertices split per plane), and UVs from a box projection of world-space
    positions divided by ``uv_scale``.

    Pieces whose region misses the input are logged and left out; the
    runtime uses ``Fragment.piece`` to map fragments to pieces.

    A cut can fall apart (a region holding the tips of two legs); a game spawns
    one rigid body per fragment, so every fragment is split into its closed
    bodies (:func:`~fracture_cli.stages.fragments.bodies.split_fragments`): bodies
    below ``min_body_fraction`` of the input's volume are glued to their
    largest-interface neighbour, the others become fragments of their own
    (same piece). Several fragments may then share one piece.
    """
    # on first use: a recipe reads FragmentOptions from this package without loading manifold3d and the cutting
    from fracture_cli.stages.fragments.cut import cut_fragments

    return cut_fragments(surface, regions, options)
