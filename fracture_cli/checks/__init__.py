"""What the bake report says about fragments: invariants (closed, volumes, overlap).

Not a stage: measurements on the fragments stage's output (ALGORITHM.md section 6), used by the
pipeline's report and by the tests. How the faults look is :mod:`fracture_cli.checks.faultshape`.
"""

from __future__ import annotations

import dataclasses
import logging

import manifold3d
import numpy as np

from fracture_cli.checks.faultshape import fault_shape, fragment_faults
from fracture_cli.errors import StageError
from fracture_cli.geometry import trigeom
from fracture_cli.geometry.rows import unique_rows
from fracture_cli.geometry.tetgeom import triangle_areas
from fracture_cli.geometry.weld_check import MeshCheck, as_written, check_mesh, collapsed, weld_by_position
from fracture_cli.system import parallel
from fracture_cli.types import INTERIOR_MATERIAL_NAME, Fragment, Fragments, SurfaceMesh

log = logging.getLogger(__name__)

# Report values of the fragment checks: numbers and flags.
CheckValue = float | int | bool

# A bake fails when the fragments' volumes differ from the input solid's by more than this fraction
# (they are exact booleans of it: the error is rounding, ~1e-9, plus zero-volume slivers dropped).
VOLUME_TOLERANCE = 1e-5
FLOAT32_HALF_STEP = 5.9604644775390625e-08  # 2**-24: float32 rounds to within this relative error


def written_fragments(fragments: Fragments, pivot: str = "center_of_mass") -> tuple[Fragments, list[MeshCheck]]:
    """Check every fragment on its positions exactly as the GLB stores them, dropping faces rounding collapses.

    Parameters
    ----------
    fragments : Fragments
    pivot : {"center_of_mass", "bbox"}, optional
        The fragment nodes' origins, as the writer will use them.

    Returns
    -------
    fragments : Fragments
        The same fragments, except that faces with two corners at one position
        once written (float32, relative to the fragment's pivot, as
        :func:`~fracture_cli.io.write.write_fragments_glb` does) are left out:
        they have no area, and removing them collapses their short edge as the
        writer's rounding already did (the vertices one written position joins
        then share the float64 position of the first of them, so the fragment
        stays closed in its own coordinates too).
    checks : list of MeshCheck
        One per fragment, welded by exact written position (see
        :func:`~fracture_cli.geometry.weld_check.check_mesh`).
    """
    # Each fragment on its own (pivot, written positions, check): on parallel.current_jobs() processes, in order.
    done = parallel.ordered_map(_written_fragment, range(len(fragments.fragments)), (fragments, pivot))
    out = [frag if changed is None else changed for frag, (changed, _) in zip(fragments.fragments, done)]
    return dataclasses.replace(fragments, fragments=tuple(out)), [check for _, check in done]


def _written_fragment(shared: tuple[Fragments, str], index: int) -> tuple[Fragment | None, MeshCheck]:
    """Fragment ``index`` without the faces its written positions collapse (None: none do) and its check."""
    # numba kernels load on first use
    from fracture_cli.io.physics import fragment_physics

    fragments, pivot = shared
    frag = fragments.fragments[index]
    # The pivot of one fragment depends on that fragment only.
    body = fragment_physics(dataclasses.replace(fragments, fragments=(frag,)), pivot=pivot)[0]
    world = fragments.normalization.to_world(frag.vertices)
    stored = as_written(world, body.origin)
    welded = weld_by_position(stored)  # checked below too: the faces left out do not change the positions
    index_of = welded[1]
    degenerate = collapsed(index_of[frag.faces])
    changed = None
    if degenerate.any():
        # Corners one written position joins take one float64 position too (the first's): without the
        # faces, the later stages (collision: welded by exact float64 position) would find a hole there.
        first = np.full(int(index_of.max()) + 1, len(index_of))
        np.minimum.at(first, index_of, np.arange(len(index_of)))
        changed = dataclasses.replace(frag, vertices=frag.vertices[first[index_of]], faces=frag.faces[~degenerate],
                                      material_ids=frag.material_ids[~degenerate])
    return changed, check_mesh(stored, (frag if changed is None else changed).faces, welded)


def written_summary(checks: list[MeshCheck]) -> dict:
    """The report's verdict on the written fragments (:func:`written_fragments`).

    Returns
    -------
    dict
        ``watertight`` (every fragment: every edge in exactly two faces of
        opposite orientation, no degenerate face, positive volume),
        ``connected`` (every fragment one body: faces connected across
        two-face edges), ``open_edges``, ``pinched_edges`` (more than two
        faces), ``misoriented_edges`` and ``degenerate_faces`` summed over the
        fragments, and ``fragment_bodies_max``.
    """
    return {
        "watertight": bool(all(c.watertight for c in checks)),
        "connected": bool(all(c.bodies == 1 for c in checks)),
        "open_edges": int(sum(c.open_edges for c in checks)),
        "pinched_edges": int(sum(c.pinched_edges for c in checks)),
        "misoriented_edges": int(sum(c.misoriented_edges for c in checks)),
        "degenerate_faces": int(sum(c.degenerate_faces for c in checks)),
        "fragment_bodies_max": int(max((c.bodies for c in checks), default=0)),
    }


def require_sound(checks: list[MeshCheck], fragments: Fragments | None = None) -> None:
    """Raise unless every written fragment is watertight; warn about fragments of several bodies.

    Parameters
    ----------
    checks : list of MeshCheck
        :func:`written_fragments`'s.
    fragments : Fragments, optional
        The fragments checked: the message then says where the first broken
        one is (its centre, in the input's units).

    Raises
    ------
    StageError
        Naming the first fragment that is not watertight (``fragment_NNN``, as
        written), what is wrong with it, where it is, and the recipe key that
        moves the cuts. The fragments stage has already split every fragment
        that pinched into its closed bodies, so what is left could not be
        made closed. Nothing has been written yet, so earlier outputs stay as
        they were.
    """
    # numba kernels load on first use
    from fracture_cli.io.names import fragment_name

    bad = [i for i, c in enumerate(checks) if not c.watertight]
    if bad:
        i = bad[0]
        more = f" (and {len(bad) - 1} more fragments)" if len(bad) > 1 else ""
        where = ""
        if fragments is not None:
            frag = fragments.fragments[i]
            centre = fragments.normalization.to_world(
                (0.5 * (frag.vertices.min(axis=0) + frag.vertices.max(axis=0)))[None])[0]
            where = " at ({:.4g}, {:.4g}, {:.4g})".format(*centre)
        raise StageError(f"{fragment_name(i)}{where} would be written as a broken mesh: "
                         f"{', '.join(checks[i].problems())}{more}, and splitting it where it pinches does not close "
                         "it; a different cut avoids it: --set cage.target_faces=<another value> (moves every fault) "
                         "or --set smooth.smoothing=0 (faults along tet faces); rerun with -v for the repair log",
                         stage="fragments")
    multi = [i for i, c in enumerate(checks) if c.bodies > 1]
    if multi:
        log.warning("fragments: %d fragment(s) consist of several separate bodies (up to %d, e.g. %s)", len(multi),
                    max(checks[i].bodies for i in multi), fragment_name(multi[0]))


def volume_tolerance(fragments: Fragments) -> float:
    """The relative volume error the written fragments can have from their float32 storage alone.

    Every position is stored as float32 about its fragment's pivot, so it
    moves by up to half a float32 step of its coordinate; a face moved that
    way changes the volume by at most its area times the move. On a thin or
    large input (much area per volume) that bound can exceed
    :data:`VOLUME_TOLERANCE`; the check then allows twice the bound, and the
    report says so (``volume_tolerance``), never silently.

    Returns
    -------
    float
        ``max(VOLUME_TOLERANCE, 2 * sum_f area_f * sqrt(3) * 2**-24 * extent_f / input volume)``,
        ``extent_f`` the largest pivot-relative coordinate of fragment ``f``
        (normalized units, like the areas and the volume).
    """
    bound = 0.0
    for frag in fragments.fragments:
        if not len(frag.faces):
            continue
        centre = 0.5 * (frag.vertices.min(axis=0) + frag.vertices.max(axis=0))
        extent = float(np.abs(frag.vertices - centre).max()) * 2.0  # the pivot lies inside the fragment's box
        area = float(triangle_areas(frag.vertices, frag.faces).sum())
        bound += area * np.sqrt(3.0) * FLOAT32_HALF_STEP * extent
    return max(VOLUME_TOLERANCE, 2.0 * bound / fragments.input_volume) if fragments.input_volume > 0 else \
        VOLUME_TOLERANCE


def require_volume(report: dict, difference: float | None = None, tolerance: float = VOLUME_TOLERANCE) -> None:
    """Raise when the fragments' volumes differ from the input's by more than ``tolerance`` (relative).

    Parameters
    ----------
    report : dict
        The checks, with ``volume_error`` (|sum - input| / input).
    difference : float, optional
        (sum of the fragments' volumes - input volume) / input volume: says
        whether the fragments hold more or less than the input (the message
        states which was measured).
    tolerance : float, optional (default :data:`VOLUME_TOLERANCE`)
        See :func:`volume_tolerance`.
    """
    error = report.get("volume_error", 0.0)
    if error <= tolerance:
        return
    measured = f"{error:.3g} of the input's volume (tolerance {tolerance:.3g})"
    if difference is not None and difference > 0:
        raise StageError(f"the fragments hold more volume than the input, by {measured}: fragments overlap or a "
                         "cut added material", stage="fragments")
    if difference is not None and difference < 0:
        raise StageError(f"the fragments hold less volume than the input, by {measured}: some of the input is "
                         "missing from the fragments", stage="fragments")
    raise StageError(f"the fragments' volumes add up to the input's only within {measured}", stage="fragments")


def fragment_invariants(surface: SurfaceMesh, fragments: Fragments, *, max_pairs: int = 2000,
                        written: list[MeshCheck] | None = None, jobs: int | None = None,
                        faults: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None) -> dict:
    """Measure what ALGORITHM.md section 6 promises of the fragments.

    Parameters
    ----------
    surface : SurfaceMesh
        The input the fragments were cut from (normalized coordinates).
    fragments : Fragments
        The fragments.
    max_pairs : int, optional (default 2000)
        At most this many neighbouring fragment pairs are intersected for the
        overlap estimate (closest centroids first).
    jobs : int, optional (default :func:`fracture_cli.system.parallel.current_jobs`)
        Processes for the pairwise booleans; the result does not depend on it.
    written : list of MeshCheck, optional
        The checks of :func:`written_fragments` (computed when not given).
    faults : tuple of arrays, optional
        :func:`~fracture_cli.checks.faultshape.fragment_faults` of ``fragments`` (computed when not given).

    Returns
    -------
    dict
        ``fragments`` count; the keys of :func:`written_summary`
        (``watertight``, ``connected``, edge counts: checked on the positions
        as written); ``volume_error`` (|sum of fragment volumes - input volume|
        / input volume, input volume = ``fragments.input_volume``);
        ``max_outer_distance`` (largest distance from a vertex of a non-interior
        face to the input surface, in units of the bounding-box diagonal);
        ``max_overlap`` (largest intersection volume of two neighbouring
        fragments, those sharing a fault (:func:`fragment_neighbours`), relative
        to the smaller one); the fragment volumes relative to the input:
        ``min_fragment_volume`` (= ``fragment_volume_min``),
        ``fragment_volume_median``, ``fragment_volume_max``.

    Notes
    -----
    Overlaps are measured between neighbours only: fragments that share no
    fault are kept apart by the regions between them, so an overlap there
    would also show as a volume error (the volumes sum to more than the
    input's) or a fragment reaching outside the input (``max_outer_distance``).
    """
    if written is None:
        written = written_fragments(fragments)[1]
    interior = [i for i, m in enumerate(fragments.materials) if m.name == INTERIOR_MATERIAL_NAME]
    interior_id = interior[-1] if interior else -1
    volume_list: list[float] = []
    outer_points = []
    for frag in fragments.fragments:
        volume_list.append(trigeom.signed_volume(frag.vertices, frag.faces))
        outer = frag.faces[frag.material_ids != interior_id]
        outer_points.append(frag.vertices[np.unique(outer)])
    volumes = np.array(volume_list)
    reference = fragments.input_volume
    points = np.concatenate(outer_points) if outer_points else np.zeros((0, 3))
    relative = np.sort(volumes) / reference if len(volumes) and reference > 0 else np.zeros(1)
    return {
        "fragments": len(fragments.fragments),
        **written_summary(written),
        "volume_error": float(abs(volumes.sum() - reference) / reference) if reference > 0 else float("nan"),
        "max_outer_distance": float(_max_distance_to_surface(points, surface.vertices, surface.faces)),
        "max_overlap": float(_max_overlap(fragments, volumes, max_pairs, jobs, faults)),
        "min_fragment_volume": float(relative[0]),
        "fragment_volume_min": float(relative[0]),
        "fragment_volume_median": float(np.median(relative)),
        "fragment_volume_max": float(relative[-1]),
    }


def _solid(V: np.ndarray, F: np.ndarray):
    _, first, pos = unique_rows(V, return_index=True, return_inverse=True)  # np.unique's, by column sorts
    pos = pos.reshape(-1)
    target = first[pos]
    src = np.flatnonzero(target != np.arange(len(V)))
    mesh = manifold3d.Mesh64(
        vert_properties=np.ascontiguousarray(V, dtype=np.float64),
        tri_verts=np.ascontiguousarray(F, dtype=np.uint64),
        merge_from_vert=src.astype(np.uint64),
        merge_to_vert=target[src].astype(np.uint64),
    )
    return manifold3d.Manifold(mesh)


def fragment_neighbours(fragments: Fragments,
                        faults: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None) -> np.ndarray:
    """Pairs ``(i, j)``, ``i < j`` (e, 2) int64, of fragments that share a fault (the fragment graph).

    Measured on the meshes: ``j`` owns the interior face nearest to some
    interior face of ``i`` (or the other way round), as in :func:`fragment_faults`
    (``faults``: its result, when the caller has it).
    """
    q = len(fragments.fragments)
    fault = (fragment_faults(fragments) if faults is None else faults)[2]
    labels = np.unique(fault[fault >= 0])
    pairs = np.sort(np.column_stack([labels // max(q, 1), labels % max(q, 1)]), axis=1)
    return unique_rows(pairs) if len(pairs) else np.zeros((0, 2), dtype=np.int64)


def _max_overlap(fragments: Fragments, volumes: np.ndarray, max_pairs: int, jobs: int | None,
                 faults: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None) -> float:
    frags = fragments.fragments
    if len(frags) < 2:
        return 0.0
    lo = np.array([f.vertices.min(axis=0) for f in frags])
    hi = np.array([f.vertices.max(axis=0) for f in frags])
    pairs = fragment_neighbours(fragments, faults)
    i, j = pairs[:, 0], pairs[:, 1]
    touching = np.all((lo[i] <= hi[j]) & (lo[j] <= hi[i]), axis=1)
    i, j = i[touching], j[touching]
    centres = (lo + hi) / 2
    order = np.argsort(np.linalg.norm(centres[i] - centres[j], axis=1), kind="stable")[:max_pairs]
    todo = list(zip(i[order].tolist(), j[order].tolist()))
    # One boolean per pair, independent; the pairs go to the workers in groups of nearby fragments (fragments are
    # in centroid order), so a worker builds the solids of its group (and their neighbours) once, instead of the
    # parent building them all before the fork. The same max on any number of processes.
    count = parallel.current_jobs() if jobs is None else max(int(jobs), 1)
    groups = _pair_groups(todo, centres, np.array([len(f.faces) for f in frags]), count)
    overlaps: dict[tuple[int, int], float] = {}
    for group, values in zip(groups, parallel.ordered_map(_group_overlaps, groups, _Overlaps(frags, {}), jobs=jobs)):
        overlaps.update(zip(group, values))
    worst = 0.0
    for a, b in todo:
        smaller = min(volumes[a], volumes[b])
        if smaller > 0:
            worst = max(worst, overlaps[a, b] / smaller)
    return worst


@dataclasses.dataclass(frozen=True)
class _Overlaps:
    """The fragments and the solids a process has built of them (each forked worker fills its own copy)."""

    fragments: tuple
    solids: dict


def _pair_groups(pairs: list[tuple[int, int]], centres: np.ndarray, sizes: np.ndarray,
                 count: int) -> list[list[tuple[int, int]]]:
    """``pairs`` in at most ``count`` groups of about equal cost, each pair with the group of its larger fragment.

    The fragments are split into ``count`` sets of about equal triangle count by halving the heaviest set at
    its weighted median along its widest axis (``centres`` (q, 3), ``sizes`` (q,) triangles); a pair whose
    fragments fall in two sets goes with the larger one, so the solid a second process builds is the smaller.
    """
    if not pairs:
        return []
    involved = np.unique(np.array(pairs, dtype=np.int64))
    sets = [involved]
    while len(sets) < count:
        heaviest = max(range(len(sets)), key=lambda s: (int(sizes[sets[s]].sum()), -s))
        members = sets[heaviest]
        if len(members) < 2:
            break
        axis = int(np.argmax(np.ptp(centres[members], axis=0)))
        ordered = members[np.lexsort((members, centres[members, axis]))]
        weight = np.cumsum(sizes[ordered], dtype=np.float64)
        half = int(np.clip(np.searchsorted(weight, weight[-1] / 2), 1, len(ordered) - 1))
        sets[heaviest:heaviest + 1] = [np.sort(ordered[:half]), np.sort(ordered[half:])]
    owner = np.zeros(len(sizes), dtype=np.int64)
    for index, members in enumerate(sets):
        owner[members] = index
    groups: list[list[tuple[int, int]]] = [[] for _ in sets]
    for a, b in sorted(pairs):
        groups[owner[b] if sizes[b] > sizes[a] else owner[a]].append((a, b))
    return [g for g in groups if g]


def _group_overlaps(shared: _Overlaps, pairs: list[tuple[int, int]]) -> list[float]:
    """Intersection volume of each pair of fragments (solids built once per process)."""
    for k in sorted({k for pair in pairs for k in pair} - shared.solids.keys()):
        frag = shared.fragments[k]
        shared.solids[k] = _solid(frag.vertices, frag.faces)
    return [float((shared.solids[a] ^ shared.solids[b]).volume()) for a, b in pairs]


def _max_distance_to_surface(points: np.ndarray, V: np.ndarray, F: np.ndarray) -> float:
    """Largest distance (float64, exact: :func:`fracture_cli.geometry.surface_query.distances`) from ``points`` to the
    triangles ``F`` over ``V``."""
    # Most outer vertices are the input's own vertices, at distance 0 exactly: only the others (where a fault
    # crosses the surface) are measured.
    points = points[~_on_vertices(points, V, F)]
    if len(points) == 0:
        return 0.0
    from fracture_cli.geometry.scenes import surface_scene
    from fracture_cli.geometry.surface_query import distances  # compiled (numba): imported when first needed

    # The cage stage's hierarchy of the same surface arrays when it is still alive (0.6 s to build at 1M).
    return float(distances(surface_scene(V, F), points).max())


def _on_vertices(points: np.ndarray, V: np.ndarray, F: np.ndarray) -> np.ndarray:
    """Points (n,) bool with exactly (bit for bit) the coordinates of a corner of a triangle ``F`` (f, 3) over ``V``."""
    used = np.zeros(len(V), dtype=bool)
    used[np.asarray(F).reshape(-1)] = True  # an unreferenced vertex is not on the surface
    row = np.dtype((np.void, 3 * np.dtype(np.float64).itemsize))
    keys = np.ascontiguousarray(points, dtype=np.float64).view(row).reshape(-1)
    return np.isin(keys, np.ascontiguousarray(V[used], dtype=np.float64).view(row).reshape(-1))


def checked_fragments(surface: SurfaceMesh, frags: Fragments) -> tuple[Fragments, dict[str, CheckValue]]:
    """The fragments as they will be written and the report's checks of them; a broken fragment stops the bake.

    The one place the report's ``checks`` of the fragments are assembled (the ``fragments`` and
    ``simplify`` stages call it; later stages add their own keys, e.g. ``collision_*``).

    Parameters
    ----------
    surface : SurfaceMesh
        The solid the fragments were cut from.
    frags : Fragments
        The fragments, with their pivot rule.

    Returns
    -------
    Fragments, dict of str -> CheckValue
        The fragments without faces their written positions collapse, and the checks.
    """
    # Checked as they will be written (float32 about each pivot).
    frags, written = written_fragments(frags, frags.pivot)
    require_sound(written, frags)
    faults = fragment_faults(frags)  # the overlap check's fragment graph and the fault shape both read them
    checks: dict[str, CheckValue] = dict(fragment_invariants(surface, frags, written=written, faults=faults))
    total = sum(trigeom.signed_volume(f.vertices, f.faces) for f in frags.fragments)
    tolerance = volume_tolerance(frags)
    checks["volume_tolerance"] = float(f"{tolerance:.3g}")
    if tolerance > VOLUME_TOLERANCE:
        log.warning("fragments: the volume check allows %.3g (not %g): float32 storage of this thin or large "
                    "asset's positions can move its volume that much", tolerance, VOLUME_TOLERANCE)
    require_volume(checks, (total - frags.input_volume) / frags.input_volume, tolerance)
    scale = surface.normalization.scale
    checks["input_volume"] = float(frags.input_volume * (scale * scale * scale))
    # How jagged the faults look (what smoothing is for), so a recipe change shows up in review.
    shape = fault_shape(*faults)
    checks["fault_mean_dihedral_degrees"] = round(shape["mean_dihedral_degrees"], 6)
    checks["fault_crease_density"] = round(shape["crease_density"], 6)
    return frags, checks
