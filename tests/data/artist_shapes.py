"""Procedural stand-ins for the failure classes of issue 39 (real models that should bake as an artist expects).

Used by make_realworld_corpus.py; every shape is deterministic (fixed seeds, the
same trigonometry bits on every CPU) and small (a few thousand triangles), so
every built-in recipe can bake each of them in the test suite.
"""

from __future__ import annotations

import json
import struct

import numpy as np
from make_realworld_corpus import _cos, _sin, bumpy, concat, icosphere, prism, revolve, tube


def closed_tube(path: np.ndarray, radii: np.ndarray, segments: int) -> tuple[np.ndarray, np.ndarray]:
    """A tube along a polyline (k, 3), closed by a fan cap at each end; faces point outward."""
    V, F = tube(path, radii, segments)
    k = len(path)
    ends = np.array([path[0], path[-1]])
    start, stop = len(V), len(V) + 1
    V = np.vstack([V, ends])
    caps = []
    for i in range(segments):
        j = (i + 1) % segments
        caps.append([start, j, i])  # first ring: faces point back along the path
        last = (k - 1) * segments
        caps.append([stop, last + i, last + j])
    return V, np.vstack([F, np.array(caps, dtype=np.int64)])


def cylinder(centre: np.ndarray, axis: int, radius: float, width: float, segments: int) -> tuple[np.ndarray,
                                                                                                  np.ndarray]:
    """A closed cylinder (wheel) about ``axis`` (0, 1 or 2) through ``centre``, ``width`` long."""
    angles = 2 * np.pi * np.arange(segments) / segments
    poly = np.column_stack([radius * _cos(angles), radius * _sin(angles)])
    V, F = prism(poly, -width / 2, width / 2)
    order = {0: [2, 0, 1], 1: [0, 2, 1], 2: [0, 1, 2]}[axis]
    W = V[:, order]
    if np.linalg.det(np.eye(3)[order]) < 0:
        F = F[:, ::-1]  # an odd permutation of the axes mirrors: keep the faces outward
    return W + np.asarray(centre, dtype=np.float64), F


def box(lo, hi) -> tuple[np.ndarray, np.ndarray]:
    """A closed axis-aligned box."""
    lo, hi = np.asarray(lo, dtype=np.float64), np.asarray(hi, dtype=np.float64)
    square = np.array([[lo[0], lo[1]], [hi[0], lo[1]], [hi[0], hi[1]], [lo[0], hi[1]]])
    return prism(square, lo[2], hi[2])


# ----------------------------------------------------------------------------
# The shapes


_POT_PROFILE = np.array([[0.0, 0.0], [0.3, 0.0], [0.55, 0.0], [0.7, 0.06], [0.78, 0.18], [0.84, 0.32],
                         [0.86, 0.45], [0.83, 0.6], [0.75, 0.72], [0.65, 0.82], [0.58, 0.88], [0.55, 0.9]])


def teapot_touching() -> list[tuple[str, np.ndarray, np.ndarray]]:
    """A closed teapot as games ship it: a closed pot and a closed lid touching along its rim (the lid's flat
    underside on the pot's flat top: edges of four faces), and a closed spout and handle sunk into the pot."""
    top = np.array([[0.4, 0.9], [0.25, 0.9], [0.0, 0.9]])
    pot = revolve(np.vstack([_POT_PROFILE, top]), 32)
    lid_profile = np.array([[0.0, 0.9], [0.25, 0.9], [0.4, 0.9], [0.55, 0.9], [0.5, 0.97], [0.3, 1.03],
                            [0.1, 1.06], [0.08, 1.13], [0.0, 1.15]])
    lid = revolve(lid_profile, 32)
    s = np.linspace(0, 1, 10)[:, None]
    spout_path = (1 - s) * (1 - s) * np.array([0.6, 0, 0.3]) + 2 * s * (1 - s) * np.array([1.1, 0, 0.35]) \
        + s * s * np.array([1.3, 0, 0.85])
    spout = closed_tube(spout_path, np.linspace(0.15, 0.06, 10), 12)
    u = np.linspace(0, np.pi, 12)
    handle_path = np.column_stack([-0.7 - 0.5 * _sin(u), np.zeros(12), 0.45 + 0.27 * _cos(u)])
    handle = closed_tube(handle_path, np.full(12, 0.065), 10)
    return [("pot", *pot), ("lid", *lid), ("spout", *spout), ("handle", *handle)]


def open_pot() -> tuple[np.ndarray, np.ndarray]:
    """A pot without its lid: one surface of revolution, closed at the bottom, open at the rim (no thickness)."""
    return revolve(_POT_PROFILE, 40)


def bust_with_hole() -> tuple[tuple[np.ndarray, np.ndarray], tuple[np.ndarray, np.ndarray]]:
    """A bust (head on a neck on a thin stem on a round plinth), closed, and the same with one small hole eaten
    into the stem: the hole wraps about 280 degrees around it, so its outline folds over itself in any plane and
    has no flat patch (as a hole in an ear or a nostril of a scanned bust). Returns (closed, with the hole)."""
    head = [(0.45 * _sin(t), 1.05 - 0.5 * _cos(t)) for t in np.linspace(0.35, np.pi, 12)]
    stem = [(0.03, z) for z in np.linspace(0.1, 0.35, 11)]
    profile = np.array([[0.0, 0.0], [0.3, 0.0], [0.5, 0.0], [0.6, 0.0], [0.62, 0.015], [0.63, 0.04],
                        [0.62, 0.065], [0.6, 0.08], [0.4, 0.08], [0.2, 0.08], [0.07, 0.085]] + stem
                       + [[0.07, 0.37], [0.14, 0.4], [0.2, 0.45], [0.2, 0.5]] + head[:-1] + [[0.0, 1.55]])
    V, F = revolve(profile, 48)
    V = V * np.array([1.0, 0.85, 1.0])
    near = np.linalg.norm(V - np.array([0.03, 0.0, 0.225]), axis=1) < 0.05
    hole = near[F].any(axis=1)
    used, local = np.unique(F[~hole], return_inverse=True)
    return (V, F), (V[used], local.reshape(-1, 3))


def gear_thin_teeth(teeth: int = 24) -> list[tuple[str, np.ndarray, np.ndarray]]:
    """A round hub and many thin box teeth sunk into it, each a separate closed body (a game-style gear)."""
    angles = 2 * np.pi * np.arange(48) / 48
    hub = prism(np.column_stack([_cos(angles), _sin(angles)]), -0.12, 0.12)
    bodies = [("hub", *hub)]
    for i in range(teeth):
        a = 2 * np.pi * (i + 0.25) / teeth
        radial, tangent = np.array([_cos(a), _sin(a)]), np.array([-_sin(a), _cos(a)])
        half = 0.012
        quad = np.array([0.96 * radial - half * tangent, 1.3 * radial - half * tangent,
                         1.3 * radial + half * tangent, 0.96 * radial + half * tangent])
        bodies.append((f"tooth_{i:02d}", *prism(quad, -0.1, 0.1)))
    return bodies


def vehicle() -> list[tuple[str, np.ndarray, np.ndarray]]:
    """A toy truck of separate closed bodies that only touch: chassis, cab on it, four wheels against its
    sides, and small parts (lights, mirrors, exhaust, bumper) against it."""
    bodies = [("chassis", *box((0.0, 0.0, 0.35), (4.0, 1.8, 1.1))),
              ("cab", *box((0.2, 0.15, 1.1), (1.6, 1.65, 1.9)))]
    for i, (x, y) in enumerate([(0.8, -0.15), (3.2, -0.15), (0.8, 1.95), (3.2, 1.95)]):
        bodies.append((f"wheel_{i}", *cylinder((x, y, 0.45), 1, 0.45, 0.3, 24)))
    bodies += [("light_l", *box((-0.06, 0.2, 0.8), (0.0, 0.45, 0.95))),
               ("light_r", *box((-0.06, 1.35, 0.8), (0.0, 1.6, 0.95))),
               ("mirror_l", *box((1.3, -0.12, 1.5), (1.4, 0.15, 1.6))),
               ("mirror_r", *box((1.3, 1.65, 1.5), (1.4, 1.92, 1.6))),
               ("bumper", *box((-0.12, 0.1, 0.4), (0.0, 1.7, 0.55))),
               ("exhaust", *cylinder((3.0, 0.1, 1.45), 2, 0.05, 0.7, 8)),
               ("beacon", *box((0.8, 0.8, 1.9), (1.0, 1.0, 2.0))),
               ("hitch", *box((4.0, 0.8, 0.5), (4.2, 1.0, 0.6)))]
    return bodies


def overlapping_edges() -> list[tuple[str, np.ndarray, np.ndarray]]:
    """Overlapping boxes sharing face planes and edge lines, one more touching only along an edge and one only
    at a corner (a kit-bashed prop)."""
    return [("a", *box((0.0, 0.0, 0.0), (1.0, 1.0, 1.0))),
            ("b", *box((0.5, 0.0, 0.0), (1.5, 1.0, 1.0))),          # overlaps a; shares its planes and edge lines
            ("c", *box((0.25, 0.25, 0.5), (0.75, 0.75, 1.4))),      # overlaps a through its top face
            ("d", *box((-1.0, -1.0, 0.0), (0.0, 0.0, 1.0))),        # touches a along its vertical edge only
            ("e", *box((1.5, 1.0, 1.0), (2.0, 1.5, 1.5)))]          # touches b at one corner only


def fins_on_solid() -> tuple[np.ndarray, np.ndarray]:
    """A box with two zero-thickness fins hinged on its edges (three faces at each hinge edge) and a card of two
    back-to-back copies of a triangle hinged on a third edge (no volume at all): one mesh, welded."""
    V, F = box((0.0, 0.0, 0.0), (1.0, 1.0, 1.0))
    # prism() vertices: bottom 0..3 (lo, (hi, lo), hi, (lo, hi)) at z=0, top 4..7 at z=1.
    V = np.vstack([V, [[0.0, 1.35, 1.35], [1.0, 1.35, 1.35], [1.3, -0.3, 0.3], [1.3, -0.3, 0.7], [-0.3, -0.3, 0.5]]])
    top_back_left, top_back_right = 7, 6  # (0, 1, 1), (1, 1, 1): the fin hinges on this top edge
    fin = [[top_back_left, top_back_right, 9], [top_back_left, 9, 8]]
    fin2 = [[1, 5, 11], [1, 11, 10]]  # on the vertical edge (1, 0, 0)-(1, 0, 1)
    card = [[0, 4, 12], [0, 12, 4]]  # both sides of one triangle on the vertical edge at the origin
    return V, np.vstack([F, np.array(fin + fin2 + card, dtype=np.int64)])


def wall_with_hole(origin=(1000.0, 0.0, 500.0), size=(400.0, 300.0, 12.0),
                   hole=((150.0, 100.0), (250.0, 220.0))) -> tuple[np.ndarray, np.ndarray]:
    """A thin wall with a window through it, far from the origin (a level piece in world units): one closed
    genus-1 surface."""
    xs = np.array([0.0, hole[0][0], hole[1][0], size[0]])
    ys = np.array([0.0, hole[0][1], hole[1][1], size[1]])
    V, index = [], {}
    for side, z in enumerate((0.0, size[2])):
        for i, x in enumerate(xs):
            for j, y in enumerate(ys):
                index[side, i, j] = len(V)
                V.append([x, y, z])
    F = []
    for side in (0, 1):
        for i in range(3):
            for j in range(3):
                if (i, j) == (1, 1):
                    continue  # the window
                a, b = index[side, i, j], index[side, i + 1, j]
                c, d = index[side, i + 1, j + 1], index[side, i, j + 1]
                quad = [[a, c, b], [a, d, c]] if side == 0 else [[a, b, c], [a, c, d]]
                F += quad

    def ring(corners):
        for (i0, j0), (i1, j1) in zip(corners, corners[1:] + corners[:1]):
            a, b = index[0, i0, j0], index[0, i1, j1]
            c, d = index[1, i1, j1], index[1, i0, j0]
            F.extend([[a, b, c], [a, c, d]])

    ring([(0, 0), (1, 0), (2, 0), (3, 0), (3, 1), (3, 2), (3, 3), (2, 3), (1, 3), (0, 3), (0, 2), (0, 1)])
    ring([(1, 1), (1, 2), (2, 2), (2, 1)])  # the window's sides, facing into the opening
    return np.array(V) + np.asarray(origin), np.array(F, dtype=np.int64)


def debris_soup(seed: int = 21) -> np.ndarray:
    """A pile of rocks as an STL triangle soup: overlapping, touching and separate small closed blobs, every
    triangle unwelded with random winding. Returns triangles (m, 3, 3)."""
    rng = np.random.default_rng(seed)
    S, F = icosphere(1)
    parts = []
    for i in range(14):
        centre = rng.uniform([-1.0, -1.0, 0.0], [1.0, 1.0, 0.6])
        radius = rng.uniform(0.15, 0.4)
        parts.append((bumpy(S, 0.3, 100 + i) * radius * rng.uniform(0.7, 1.3, size=3) + centre, F))
    V, G = concat(*parts)
    flip = rng.random(len(G)) < 0.5
    G[flip] = G[flip][:, ::-1]
    return V[G[rng.permutation(len(G))]]


def unpadded_glb(data: bytes) -> bytes:
    """The same GLB with its JSON chunk not padded to a multiple of 4 bytes (as some exporters write it): the
    chunk's length is the JSON's own, and the binary chunk follows right after it."""
    _, version, _ = struct.unpack_from("<4sII", data, 0)
    length, _ = struct.unpack_from("<II", data, 12)
    doc = json.loads(data[20:20 + length].decode("utf-8"))
    rest = data[20 + length:]
    text = json.dumps(doc, separators=(",", ":")).encode("utf-8")
    if len(text) % 4 == 0:
        text += b" "  # still not a multiple of 4
    body = struct.pack("<II", len(text), 0x4E4F534A) + text + rest
    return struct.pack("<4sII", b"glTF", version, 12 + len(body)) + body
