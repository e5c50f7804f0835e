"""The ``runtime`` stage: precompute the impact-projection data a game needs (ALGORITHM.md section 4).

Named ``precompute`` so it is not confused with :mod:`fracture_cli.runtime`, the
game-side reader of what it writes; the recipe section keeps the name ``runtime``.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import TYPE_CHECKING

from fracture_cli.stages.runtime.options import STAGE, RuntimeOptions

if TYPE_CHECKING:
    import numpy as np

    from fracture_cli.runtime.format import RuntimeData
    from fracture_cli.types import Anchors, Fragments, Modes, Pieces, TetMesh

__all__ = ["STAGE", "RuntimeOptions", "runtime", "with_structure"]


def runtime(tet_mesh: TetMesh, modes: Modes, pieces: Pieces, options: RuntimeOptions = RuntimeOptions(),
            fragment_pieces: Sequence[int] | np.ndarray | None = None, fragment_names: tuple[str, ...] | None = None,
            fragment_graph: tuple[np.ndarray, np.ndarray] | None = None) -> RuntimeData:
    """Compute the contact sites, site-to-mode coefficients ``B`` and piece modes ``W``.

    Parameters
    ----------
    tet_mesh : TetMesh
        The mesh the modes live on (normalized coordinates); its boundary
        vertices are the contact sites.
    modes : Modes
        ``U : (k, t, d)`` M_T-orthonormal fracture modes.
    pieces : Pieces
        Atomic pieces: ``W : (k, p, d)``, ``edges : (e, 2)``, ``edge_areas : (e,)``.
    options : RuntimeOptions, optional
    fragment_pieces : (f,) int, optional (default ``0..p-1``)
        The piece of every exported fragment, in the fragments file's order
        (``[frag.piece for frag in fragments.fragments]``). Pieces without a
        fragment (regions that miss the input) are left out with their edges:
        there is no material there to hold fragments together. A piece may
        hold several fragments (a region cut into separate bodies): each gets
        the piece's column of ``W``; ``fragment_graph`` is then required.
    fragment_names : tuple of str, optional (default ``fragment_000``, ...)
        Node name of every fragment, in the same order.
    fragment_graph : ((e, 2) int, (e,) float), optional
        Bonds between fragments measured on their meshes (pairs ``P < Q`` in
        the fragments' order, sorted; shared fault area in normalized units
        squared, see :func:`fracture_cli.stages.fragments.interfaces.fragment_graph`).
        Default: the piece graph mapped to the fragments, which may bond
        fragments that touch only outside the input.

    Returns
    -------
    RuntimeData
        Sites and areas in the input's units; ``B`` and ``W`` scaled so the
        threshold is a dimensionless toughness (see Notes).

    Notes
    -----
    ALGORITHM.md section 4, with the two scalings of section 8 that make the
    result independent of the mesh and of the asset's size: the impulse is
    spread as a unit-mass density, and modes are rescaled to unit RMS over the
    volume. ``B`` for all sites costs ``k d`` solves with one factorization
    (``M_V + tau K`` is symmetric).
    """
    # on first use: a recipe reads RuntimeOptions from this package without loading the runtime file format
    from fracture_cli.stages.runtime.build import precompute

    return precompute(tet_mesh, modes, pieces, options, fragment_pieces, fragment_names, fragment_graph)


def with_structure(data: RuntimeData, anchors: Anchors | None, fragments: Fragments,
                   options: RuntimeOptions) -> RuntimeData:
    """``data`` with what a structure needs (docs/FORMAT.md section 12), where the recipe asks for it.

    Parameters
    ----------
    data : RuntimeData
        The runtime data of ``fragments`` (same order, ``p`` fragments, bonds ``data.edges (e, 2)``).
    anchors : Anchors or None
        From the ``anchors`` stage; with at least one anchored fragment the data gets ``anchored (p,)`` and the
        header's ``anchors`` object (feature ``"anchors"``). None or no fragment anchored: unchanged.
    fragments : Fragments
        The baked fragments, for the crack lines.
    options : RuntimeOptions
        With ``damage``: the ``damage`` object (``crack_level``, ``damage_rate``; feature ``"damage"``) and
        ``crack_ptr (e+1,)``, ``crack_segments (n, 2, 3)``.

    Returns
    -------
    RuntimeData
    """
    # on first use: as for runtime()
    from fracture_cli.stages.runtime.build import structure_data

    return structure_data(data, anchors, fragments, options)
