"""The ``load`` stage: read a mesh file into a :class:`~fracture_cli.types.SurfaceMesh`.

Every format goes through one function, :func:`load_surface`: it refuses what
is over the triangle limit or mislabelled before decoding (:mod:`fracture_cli.io.probe`),
reads the file's parts with the format's reader (:mod:`fracture_cli.io.parts`), joins them
(one material slot per material of the file), checks what the pipeline relies
on (finite coordinates, at least one triangle), and reports problems as
one-line :class:`InputError` messages that name the file.
"""

from __future__ import annotations

import os
from typing import TYPE_CHECKING

from fracture_cli.stages.load.options import READERS, LoadOptions

if TYPE_CHECKING:
    from fracture_cli.types import SurfaceMesh

__all__ = ["READERS", "LoadOptions", "load_surface"]


def load_surface(path: str | os.PathLike, options: LoadOptions = LoadOptions()) -> SurfaceMesh:
    """Read a mesh file into a normalized :class:`SurfaceMesh`.

    Parameters
    ----------
    path : str or PathLike
        An OBJ, PLY, STL, OFF, GLB or glTF file.
    options : LoadOptions, optional
        Limits applied while loading.

    Returns
    -------
    SurfaceMesh
        All geometry of the file (scene node transforms applied), with UVs,
        normals, vertex colours and material ids where present, normalized to a
        unit bounding-box diagonal (ALGORITHM.md section 0).

    Raises
    ------
    InputError
        Missing, empty or unreadable file; unsupported extension; no triangles;
        NaN or inf coordinates; more triangles than ``options.max_triangles``.
    """
    # on first use: a recipe reads LoadOptions from this package without loading the readers
    from fracture_cli.stages.load.read import read_surface

    return read_surface(path, options)
