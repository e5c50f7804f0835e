"""The ``faults`` stage: value noise on the shared faults (``faults.noise``; ALGORITHM.md section 9).

The piece regions (the smooth stage's closed meshes that partition the cage)
share their faults: a fault face of one region is, vertex for vertex, a face
of its neighbour. With ``noise > 0`` every region is refined by midpoint
subdivision (``noise_subdivisions`` times, the same midpoints on both sides
of a shared edge) and every vertex inside one fault sheet (two regions meet
there; not on a junction of three, not on the cage's surface) moves along
the fault's normal by a value noise of its position alone, at most a share of
the fault's edge length there, and less where the moved faults would cross. Both sides of a fault therefore move
identically, the regions still partition the cage, and the fragments cut
from them stay closed; mass properties, collision parts, the triangle budget
and the checks are computed after it, by the later stages.

The noise is built from integer hashing (splitmix64 on the lattice corners)
and smoothstep-weighted trilinear interpolation, ``+ - *`` only: the same bits
on every CPU, no libm.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass

import numpy as np

from fracture_cli.geometry import tolerances as tol
from fracture_cli.options import option
from fracture_cli.types import Regions

log = logging.getLogger(__name__)

STAGE = "faults"
_GOLDEN = np.uint64(0x9E3779B97F4A7C15)
# A fault vertex moves by at most this share of its shortest edge before subdivision (no fold-over).
_EDGE_SHARE = 0.3
# Halvings of the noise where moved faults cross (:func:`_unfold`) before it is dropped there.
_UNFOLD_HALVINGS = 4
_PRIMES = (np.uint64(0xC2B2AE3D27D4EB4F), np.uint64(0x165667B19E3779F9), np.uint64(0x27D4EB2F165667C5))


@dataclass(frozen=True)
class FaultOptions:
    """Options of the ``faults`` stage (a recipe's ``[faults]`` section)."""

    noise: float = option(0.0, "noise amplitude on the faults (fraction of the diagonal); 0 = faults as smoothed",
                          min=0.0, max=0.05)
    noise_frequency: float = option(20.0, "noise frequency: lattice cells per diagonal of the first octave",
                                    min=0.1, max=1000.0)
    noise_octaves: int = option(2, "noise octaves, each of twice the frequency and half the amplitude", min=1,
                                max=8)
    noise_subdivisions: int = option(2, "midpoint subdivisions of the regions before the noise (4x faces each)",
                                     min=0, max=4)
    seed: int = option(0, "seed of the noise's lattice hash", min=0)


def _mix(h: np.ndarray) -> np.ndarray:
    """splitmix64's finalizer on uint64 (wrapping arithmetic)."""
    h = h ^ (h >> np.uint64(30))
    h = h * np.uint64(0xBF58476D1CE4E5B9)
    h = h ^ (h >> np.uint64(27))
    h = h * np.uint64(0x94D049BB133111EB)
    return h ^ (h >> np.uint64(31))


def _lattice(i: np.ndarray, salt: int) -> np.ndarray:
    """A value in [-1, 1) for every integer lattice point ``i`` (n, 3) and ``salt``."""
    u = i.astype(np.int64).view(np.uint64)
    salted = np.uint64((int(salt) * int(_GOLDEN)) & 0xFFFFFFFFFFFFFFFF)  # Python ints: no overflow warning
    h = _mix(u[:, 0] * _PRIMES[0] ^ u[:, 1] * _PRIMES[1] ^ u[:, 2] * _PRIMES[2] ^ salted)
    return (h >> np.uint64(11)).astype(np.float64) * (2.0 / 9007199254740992.0) - 1.0


def value_noise(points: np.ndarray, frequency: float, octaves: int, seed: int = 0) -> np.ndarray:
    """Vector value noise (n, 3) in [-1, 1] per component at ``points`` (n, 3).

    Octave ``o`` has ``frequency * 2**o`` lattice cells per unit and weight
    ``2**-o``; the sum is divided by the total weight. A function of each
    point's coordinates only (equal points, equal noise).
    """
    points = np.asarray(points, dtype=np.float64)
    out = np.zeros((len(points), 3))
    total = 0.0
    scale, weight = float(frequency), 1.0
    for octave in range(int(octaves)):
        q = points * scale
        base = np.floor(q)
        t = q - base
        s = t * t * (3.0 - 2.0 * t)  # smoothstep: C1 across lattice cells
        cell = base.astype(np.int64)
        for corner in range(8):
            offset = np.array([(corner >> 2) & 1, (corner >> 1) & 1, corner & 1], dtype=np.int64)
            w = np.ones(len(points))
            for a in range(3):
                w = w * (s[:, a] if offset[a] else 1.0 - s[:, a])
            for component in range(3):
                salt = (int(seed) * 8 + octave) * 3 + component
                out[:, component] += weight * w * _lattice(cell + offset, salt)
        total += weight
        scale, weight = scale * 2.0, weight * 0.5
    return out / total


def subdivide(vertices: np.ndarray, faces: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """One 1-to-4 midpoint subdivision of a closed mesh; a shared edge gets the same midpoint on either side."""
    edges = np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]])
    key = np.sort(edges, axis=1)
    unique, inverse = np.unique(key, axis=0, return_inverse=True)
    inverse = inverse.reshape(-1)
    # (a + b) * 0.5 is symmetric in a and b: both regions compute the same bits.
    mids = (vertices[unique[:, 0]] + vertices[unique[:, 1]]) * 0.5
    m = len(faces)
    ab, bc, ca = (len(vertices) + inverse[j * m:(j + 1) * m] for j in range(3))
    a, b, c = faces[:, 0], faces[:, 1], faces[:, 2]
    new = np.concatenate([np.stack([a, ab, ca], 1), np.stack([ab, b, bc], 1), np.stack([ca, bc, c], 1),
                          np.stack([ab, bc, ca], 1)])
    return np.concatenate([vertices, mids]), new


def _normal_shift(positions: np.ndarray, faces: np.ndarray, owner: np.ndarray, face_key: np.ndarray,
                  counts: np.ndarray, moving: np.ndarray, options: FaultOptions) -> np.ndarray:
    """Displacement (n, 3) of every vertex: noise along its fault's normal, 0 where it does not move.

    The normal is the area-weighted normal of the fault faces around the vertex, oriented as the
    lower-numbered region sees them (both sides get the same vector). The move is at most
    :data:`_EDGE_SHARE` of the vertex's shortest edge before subdivision, so a fault does not fold
    over its neighbours.
    """
    n = len(positions)
    # One occurrence of every fault face: the first in region order (the lower region's orientation).
    shared = np.flatnonzero(counts[face_key] == 2)  # faces are in region order: the first seen is the lower's
    _, first = np.unique(face_key[shared], return_index=True)
    keep = np.zeros(len(faces), dtype=bool)
    keep[shared[first]] = True
    tri = positions[faces[keep]]
    cross = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    corners = faces[keep].reshape(-1)
    normal = np.stack([np.bincount(corners, weights=np.repeat(cross[:, a], 3), minlength=n) for a in range(3)],
                      axis=1)
    length = np.sqrt(np.einsum("ij,ij->i", normal, normal))
    unit = normal / np.maximum(length, tol.SMALLEST_DIVISOR)[:, None]
    edges = np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]])
    d = positions[edges[:, 0]] - positions[edges[:, 1]]
    edge_length = np.sqrt(np.einsum("ij,ij->i", d, d))
    shortest = np.full(n, np.inf)
    np.minimum.at(shortest, edges.reshape(-1), np.repeat(edge_length, 2))
    value = float(options.noise) * value_noise(positions, options.noise_frequency, options.noise_octaves,
                                               options.seed)[:, 0]
    # In units of the edges before subdivision (each halves them): the noise field itself is smooth.
    bound = _EDGE_SHARE * shortest * float(1 << int(options.noise_subdivisions))
    value = np.clip(value, -bound, bound)
    value[~moving | ~(length > 0)] = 0.0
    return value[:, None] * unit


def _unfold(positions: np.ndarray, faces: np.ndarray, shift: np.ndarray) -> tuple[np.ndarray, int]:
    """The shift (n, 3) with less noise wherever the moved faults would cross; how many vertices that held back.

    The bound of :func:`_normal_shift` keeps a fault from folding over its own neighbourhood, not from crossing
    another fault (or itself) that comes close, which left a region intersecting itself: its boolean with the
    input then counts the crossing twice (the pillar's fragments came out 1.7e-6 above its volume). Every
    vertex of a face that crosses another (``faces``: each face of the regions once) has its shift halved, up
    to :data:`_UNFOLD_HALVINGS` times, then dropped; pairs that met before the noise are left as they were.
    """
    # on first use: compiled kernels the stage needs only with noise
    from fracture_cli.geometry.trigeom import self_intersections

    shift = shift.copy()
    held = np.zeros(len(positions), dtype=bool)
    # Pairs that meet before the noise (faces of two faults folded flat onto each other along a junction) are
    # not the noise's doing: they stay, and their vertices move as the noise says.
    before = {(int(f), int(g)) for f, g in self_intersections(positions, faces)}
    for attempt in range(_UNFOLD_HALVINGS + 1):
        pairs = self_intersections(positions + shift, faces)
        pairs = pairs[[(int(f), int(g)) not in before for f, g in pairs]].reshape(-1, 2)
        if len(pairs) == 0:
            break
        corners = np.unique(faces[pairs.reshape(-1)])
        held[corners] = True
        shift[corners] *= 0.0 if attempt == _UNFOLD_HALVINGS else 0.5
    return shift, int(held.sum())


def faults(regions: Regions, options: FaultOptions = FaultOptions()) -> Regions:
    """The regions with noise on their shared faults (unchanged when ``options.noise`` is 0).

    Parameters
    ----------
    regions : Regions
        Closed, outward-oriented region meshes that partition the cage (normalized units).
    options : FaultOptions

    Returns
    -------
    Regions
        The same number of regions, refined and with every fault-only vertex
        moved by ``noise * value_noise(x)``.
    """
    if options.noise <= 0.0:
        return regions
    meshes = [(np.asarray(v, dtype=np.float64), np.asarray(f, dtype=np.int64)) for v, f in regions.meshes]
    for _ in range(int(options.noise_subdivisions)):
        meshes = [subdivide(v, f) for v, f in meshes]
    # One id per distinct position over all regions; a face seen in one region only is on the cage's surface.
    stacked = np.concatenate([v for v, _ in meshes])
    positions, global_id = np.unique(stacked, axis=0, return_inverse=True)
    global_id = global_id.reshape(-1)
    starts = np.cumsum([0] + [len(v) for v, _ in meshes])
    region_faces = [global_id[starts[r] + f] for r, (_, f) in enumerate(meshes)]
    all_faces = np.concatenate(region_faces)
    owner = np.concatenate([np.full(len(f), r) for r, f in enumerate(region_faces)])
    _, face_key, counts = np.unique(np.sort(all_faces, axis=1), axis=0, return_inverse=True, return_counts=True)
    face_key = face_key.reshape(-1)
    outer = counts[face_key] == 1
    n = len(positions)
    fixed = np.zeros(n, dtype=bool)
    fixed[all_faces[outer].reshape(-1)] = True
    # Only vertices inside one fault sheet move (two regions meet there): junctions of three or more stay.
    pairs = np.unique(np.stack([np.repeat(owner, 3), all_faces.reshape(-1)], axis=1), axis=0)
    moving = ~fixed & (np.bincount(pairs[:, 1], minlength=n) == 2)
    shift = _normal_shift(positions, all_faces, owner, face_key, counts, moving, options)
    unique_faces = all_faces[np.unique(face_key, return_index=True)[1]]
    shift, damped = _unfold(positions, unique_faces, shift)
    moved = positions + shift
    out = tuple((moved[global_id[starts[r]:starts[r + 1]]], f) for r, (_, f) in enumerate(meshes))
    log.info("%s: noise %.3g on %d fault vertices of %d regions (%d subdivisions; %d held back where the faults "
             "would cross)", STAGE, options.noise, int(moving.sum()), len(out), options.noise_subdivisions, damped)
    return Regions(meshes=out, smoothing=regions.smoothing, vanished=regions.vanished)
