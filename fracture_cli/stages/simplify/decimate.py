"""Half-edge collapses on the shared surface complex of all fragments (see :mod:`.simplify`).

The complex holds every face of every fragment once: a fault face shared by two
fragments is one face of both, an outer face belongs to one. Each face carries
the fragments whose surface it is part of and, for an outer face, the input
polygon (connected coplanar input triangles) it lies in. A collapse merges a
vertex ``u`` into a neighbour ``v`` (no new positions) when

* ``u`` is free (not an input vertex) and, for every input polygon (coplanar
  input triangles) ``u`` lies on, ``v`` is a corner of a face in that polygon
  next to ``u``: outer faces stay in their polygon, and a point where a fault
  curve crosses an input edge can only slide along that edge, so the curve
  snaps to input vertices. Outer corners keep the input's UVs and normals;
* in the surface of every fragment that has both ``u`` and ``v`` the edge has
  exactly two faces and the link condition holds (the collapse pinches no
  fragment); for a fragment without ``v``, ``u`` only moves;
* no face turns by more than 30 degrees (60 around a vertex on the outer
  surface) or becomes degenerate;
* every fault vertex removed so far stays within the tolerance of the new fault
  faces, and the new fault faces (centroids, edge midpoints) within the
  tolerance of the cut fault.

After the collapses, :meth:`SurfaceComplex.flip_needles` flips away the needles
the booleans left (a corner ~1e-10 from the opposite edge), which float32 would
turn over differently on the two sides of a fault.
"""

from __future__ import annotations

import copy
import heapq
from types import ModuleType

import numpy as np

from fracture_cli.stages.simplify.decimate_faces import (
    MIN_NORMAL_COS,
    MIN_NORMAL_COS_OUTER,
    MIN_SHAPE,
    Fan,
    merged,
    moved,
    turns_little,
)

# Cut fault faces (nearest centroids) a point of a new fault face is measured against.
_REFERENCE_CANDIDATES = 8


class SurfaceComplex:
    """Mutable faces of all fragments with their input polygons, for collapses (global vertex ids, fixed positions).

    Parameters
    ----------
    V : (g, 3) float
        Welded vertex positions.
    faces : (m, 3) int
        Faces, each in the orientation of its first fragment.
    groups : (m,) int
        The input polygon every outer face lies in; -1 for a fault face.
    owners : list of tuple of int
        Fragments each face bounds (one for an outer face, two for a fault face).
    fault : (m,) bool
        Which faces are on a fault (their vertices are held to the tolerance).
    locked : set of int
        Vertices that never move.
    damp : dict of int -> float, optional
        Factor on the tolerance of some vertices (where an earlier try made a fragment intersect itself).
    """

    def __init__(self, V: np.ndarray, faces: np.ndarray, groups: np.ndarray, owners: list[tuple[int, ...]],
                 fault: np.ndarray, locked: set[int], damp: dict[int, float] | None = None):
        self.V = V
        self.points = [tuple(p) for p in np.asarray(V, dtype=float).tolist()]
        self._homogeneous = np.column_stack([np.asarray(V, dtype=float), np.ones(len(V))])  # (g, 4)
        self.faces = {t: (int(a), int(b), int(c)) for t, (a, b, c) in enumerate(np.asarray(faces).tolist())}
        self.groups = [int(x) for x in groups]
        self.owners = owners
        self.fault = [bool(x) for x in fault]
        self.locked = locked
        self.damp = damp or {}
        self.vertex_faces: dict[int, set[int]] = {}
        for t, f in self.faces.items():
            for x in f:
                self.vertex_faces.setdefault(x, set()).add(t)
        self.stamp: dict[int, int] = {}
        # The (targets, costs) computed when a vertex was last queued: still true when its entry is popped with
        # the same stamp (any change to its neighbourhood or quadric queues it again with a new stamp).
        self._queued: dict[int, tuple[list[int], list[float]]] = {}
        # The collapses made, in order: (u, v, tolerance, points, nearest) as :meth:`_apply` took them.
        self.done: list[tuple[int, int, float, list[int], list[int]]] = []
        # Collapses applied so far, and the count when each face last changed (or went).
        self.clock = 0
        self.modified: dict[int, int] = {}
        # Per vertex, its last refusal: (clock, tolerance, the faces its collapses looked at).
        self.refused: dict[int, tuple[int, float, frozenset[int]]] = {}
        # Refusals of an earlier try that hold again while those faces are as they were (see :meth:`replay`).
        self._refusals: dict[int, tuple[float, frozenset[int]]] = {}
        self._changed: set[int] = set()
        self._replayed = 0
        # Original fault vertices removed so far, kept with the face nearest to them (for the error bound).
        self.assigned: dict[int, list[int]] = {t: [] for t in self.faces}
        # Vertices whose collapse changed each face (to lock them when the face ends up in an invalid fragment),
        # as a graph of collapses shared between faces (see :meth:`behind`): copying sets cost more than the rest
        # of a collapse.
        self.history: dict[int, tuple] = {t: () for t in self.faces}
        self._kernels = _kernels()
        self.quadric = self._kernels.quadrics(V, faces, fault, len(V))
        # The cut fault faces, to measure how far new faces stray from them.
        F = np.asarray(faces, dtype=np.int64).reshape(-1, 3)[np.asarray(fault, dtype=bool)]
        self.reference = np.ascontiguousarray(V[F], dtype=np.float64) if len(F) else np.zeros((1, 3, 3))
        self._candidates = min(_REFERENCE_CANDIDATES, len(self.reference))
        self._positions = np.ascontiguousarray(V, dtype=np.float64)
        # Their centroids in a grid, for the nearest ones to a new face (:func:`.collapse_kernels.nearest`).
        self._centroids = np.ascontiguousarray(self.reference.mean(axis=1))
        self._cell = self._kernels.grid_cell(self.reference)
        self._grid = self._kernels.grid_index(self._centroids, self._cell)
        self._finite = bool(np.isfinite(self.quadric).all() and np.isfinite(self._positions).all())
        self.static = _collapse_pack().static_arrays(self)  # what the compiled loop reads and never changes

    def copy(self) -> SurfaceComplex:
        """An independent copy, to go on from (positions, input polygons and the cut fault are shared: they
        never change)."""
        new = copy.copy(self)
        new.faces = dict(self.faces)
        new.locked = set(self.locked)
        new.damp = dict(self.damp)
        new.vertex_faces = {x: set(f) for x, f in self.vertex_faces.items()}
        new.stamp = dict(self.stamp)
        new._queued = dict(self._queued)
        new.done = list(self.done)
        new.modified = dict(self.modified)
        new.refused = dict(self.refused)
        new._refusals = dict(self._refusals)
        new._changed = set(self._changed)
        new.assigned = {t: list(p) for t, p in self.assigned.items()}
        new.history = dict(self.history)  # its nodes are replaced, never changed
        new.quadric = self.quadric.copy()
        return new

    def replay(self, collapses: list[tuple[int, int, float, list[int], list[int]]],
               tolerance: dict[int, float] | float,
               refusals: dict[int, tuple[float, frozenset[int]]] | None = None) -> None:
        """Redo the collapses of an earlier try (its :attr:`done`), in order, each only if still allowed.

        A retry with a few vertices held back repeats most of the first try: replaying its collapses first
        leaves :meth:`decimate` little to search for. A collapse whose surroundings (the faces around ``u``
        and ``v``, their corners and the removed vertices kept with them) are as they were in the earlier
        try, at the same tolerance, is allowed again and applied without checking. Where the tries part (a
        collapse not redone, or checked again), its surroundings are marked changed and later collapses
        there are checked in full. Likewise a vertex whose collapses were all refused at the end of the
        earlier try (``refusals``: its :meth:`final_refusals`) is not tried again by :meth:`decimate` while
        the faces they looked at are as they were, at the same tolerance.
        """
        self._refusals = dict(refusals or {})
        if self._finite:
            _collapse_pack().replay(self, collapses, tolerance)
        else:
            self.replay_python(collapses, tolerance)
        self._replayed = self.clock

    def replay_python(self, collapses: list[tuple[int, int, float, list[int], list[int]]],
                      tolerance: dict[int, float] | float) -> None:
        """The collapses of :meth:`replay` in Python: the reference the compiled one follows."""
        changed_faces = self._changed
        changed_vertices: set[int] = set()
        for u, v, was, points, nearest in collapses:
            if u in self.locked or u not in self.vertex_faces or v not in self.vertex_faces:
                self._mark_changed(u, v, changed_faces, changed_vertices)
                continue
            bound = self._tolerance(u, tolerance)
            fan, v_fan = self.vertex_faces[u], self.vertex_faces[v]
            if (bound == was and u not in changed_vertices and v not in changed_vertices
                    and changed_faces.isdisjoint(fan) and changed_faces.isdisjoint(v_fan)):
                removed = [t for t in fan if t in v_fan]
                kept = sorted(fan.difference(removed))
                new_faces = {t: moved(self.faces[t], u, v) for t in kept}
                self._apply(u, v, removed, kept, new_faces, points, nearest, bound)
                continue
            self._mark_changed(u, v, changed_faces, changed_vertices)
            self._collapse(u, v, bound)

    def final_refusals(self) -> dict[int, tuple[float, frozenset[int]]]:
        """The vertices whose last refusal saw the faces as they are now: (tolerance, faces looked at)."""
        return {u: (bound, region) for u, (clock, bound, region) in self.refused.items()
                if u in self.vertex_faces and all(self.modified.get(t, 0) <= clock for t in region)}

    def _region(self, u: int, targets: list[int]) -> frozenset[int]:
        """The faces the collapses of ``u`` into ``targets`` look at: around ``u`` and around each target."""
        return frozenset(self.vertex_faces[u]).union(*(self.vertex_faces[v] for v in targets))

    def _refused_again(self, u: int, bound: float, region: frozenset[int]) -> bool:
        """Whether an earlier try refused every collapse of ``u`` with these faces as they are now."""
        earlier = self._refusals.get(u)
        return (earlier is not None and earlier[0] == bound and earlier[1] == region
                and self._changed.isdisjoint(region) and all(self.modified.get(t, 0) <= self._replayed
                                                             for t in region))

    def _mark_changed(self, u: int, v: int, faces: set[int], vertices: set[int]) -> None:
        """Add the faces around ``u`` and ``v`` and their corners to ``faces`` and ``vertices``."""
        around = set(self.vertex_faces.get(u, ())) | set(self.vertex_faces.get(v, ()))
        faces |= around
        vertices.update(x for t in around for x in self.faces[t])
        vertices.update((u, v))

    def decimate(self, tolerance: dict[int, float] | float, vertices: list[int] | None = None) -> int:
        """Collapse, cheapest first, until no allowed collapse is left; returns how many were done.

        ``tolerance`` is one bound or a bound per fragment (a vertex takes the largest of its fragments'); with
        ``vertices``, only those are queued at first. The loop is compiled (:mod:`.collapse_loop`); it makes
        the collapses :meth:`decimate_python` makes, which runs instead when a quadric is not finite (its
        queue order then rests on how Python compares nan).
        """
        if self._finite:
            return _collapse_pack().decimate(self, tolerance, vertices)
        return self.decimate_python(tolerance, vertices)

    def decimate_python(self, tolerance: dict[int, float] | float, vertices: list[int] | None = None) -> int:
        """:meth:`decimate` in Python: the reference the compiled loop follows.

        Each vertex is queued once, at the cost of its cheapest collapse; when that one is refused the
        next cheapest are tried. A new stamp (a neighbour changed) makes its older entry obsolete.
        """
        heap: list = []
        for u in sorted(self.vertex_faces) if vertices is None else sorted(vertices):
            self._push(heap, u)
        done = 0
        while heap:
            _, u, stamp = heapq.heappop(heap)
            if self.stamp.get(u) != stamp or u not in self.vertex_faces:
                continue
            ctx = self._fan(u)
            bound = self._tolerance(u, tolerance, ctx.fragments)
            targets = self._targets(u, self._queued.pop(u))
            # (A refused collapse changes nothing: the region is the same before and after trying.)
            region = self._region(u, targets) if u in self._refusals else None
            if region is not None and self._refused_again(u, bound, region):
                continue  # as refused in the earlier try: same faces, same tolerance
            v = next((v for v in targets if self._collapse(u, v, bound, ctx)), None)
            if v is None:
                self.refused[u] = (self.clock, bound, region if region is not None else self._region(u, targets))
            else:
                done += 1
                for w in sorted(self._neighbours(v) | {v}):
                    self._push(heap, w)
        return done

    def _tolerance(self, u: int, tolerance: dict[int, float] | float, fragments: set[int] | None = None) -> float:
        """The bound of ``u``: the largest of its fragments' (``fragments``, when known), times its damp."""
        damp = self.damp.get(u, 1.0)
        if not isinstance(tolerance, dict):
            return tolerance * damp
        if fragments is None:
            fragments = {k for t in self.vertex_faces[u] for k in self.owners[t]}
        return damp * max([tolerance[k] for k in fragments])

    def _neighbours(self, u: int) -> set[int]:
        faces = self.faces
        found = set().union(*[faces[t] for t in self.vertex_faces.get(u, ())])
        found.discard(u)
        return found

    def _costs(self, u: int) -> tuple[list[int], list[float]]:
        """The neighbours of ``u`` and the quadric error of moving ``u`` onto each."""
        targets = sorted(self._neighbours(u))
        costs = self._kernels.quadric_costs(self._homogeneous, self.quadric, u, np.array(targets, dtype=np.int64))
        return targets, costs.tolist()

    def _targets(self, u: int, costs: tuple[list[int], list[float]] | None = None) -> list[int]:
        """The neighbours of ``u``, cheapest collapse first (``costs``: :meth:`_costs` if already known)."""
        targets, cost = costs if costs is not None else self._costs(u)
        return [v for _, v in sorted(zip(cost, targets))]

    def _push(self, heap: list, u: int) -> None:
        """Queue ``u`` at the cost of its cheapest collapse, if it may move."""
        if u in self.locked or u not in self.vertex_faces:
            return
        stamp = self.stamp[u] = self.stamp.get(u, 0) + 1
        targets, costs = self._queued[u] = self._costs(u)
        if costs:
            heapq.heappush(heap, (min(costs), u, stamp))

    def _fan(self, u: int) -> Fan:
        """What every collapse of ``u`` looks at around ``u`` (valid until a collapse changes the complex)."""
        fan = self.vertex_faces[u]
        polygons = {self.groups[t] for t in fan} - {-1}
        fragments = {k for t in fan for k in self.owners[t]}
        outer = any(not self.fault[t] for t in fan)
        owned = {self.owners[t] for t in fan}
        return Fan(fan, polygons, fragments, MIN_NORMAL_COS_OUTER if outer else MIN_NORMAL_COS,
                    any(self.fault[t] for t in fan), owned.pop() if len(owned) == 1 else None)

    def _around(self, around: dict[int, set[int]], fan: set[int], k: int) -> set[int]:
        """Corners of the faces of ``fan`` in fragment ``k`` (memoized in ``around``)."""
        if k not in around:
            around[k] = set().union(*[self.faces[t] for t in fan if k in self.owners[t]])
        return around[k]

    def _allowed(self, u: int, v: int, ctx: Fan) -> list[int] | None:
        """The faces a collapse of ``u`` into ``v`` removes, or None if polygons or topology forbid it."""
        fan, v_fan, faces, owners = ctx.fan, self.vertex_faces[v], self.faces, self.owners
        removed = [t for t in fan if t in v_fan]
        if ctx.polygons and not ctx.polygons.issubset([self.groups[t] for t in removed]):
            return None  # v is not on every input polygon u is on: outer faces would leave the input surface
        single = ctx.single
        if single is not None and all(owners[t] == single for t in v_fan):
            # Every face around u and v bounds the same fragments: one link condition holds for all of them.
            if len(removed) != 2:
                return None
            opposite = {*faces[removed[0]], *faces[removed[1]]} - {u, v}
            if ctx.corners is None:
                ctx.corners = set().union(*[faces[t] for t in fan])
            return removed if (ctx.corners & set().union(*[faces[t] for t in v_fan])) - {u, v} == opposite else None
        v_fragments = {k for t in v_fan for k in self.owners[t]}
        for k in ctx.fragments & v_fragments:
            mine = [t for t in removed if k in self.owners[t]]
            if len(mine) != 2:
                return None
            opposite = {x for t in mine for x in self.faces[t]} - {u, v}
            around_u = self._around(ctx.around, fan, k)
            around_v = set().union(*[self.faces[t] for t in v_fan if k in self.owners[t]])
            if (around_u & around_v) - {u, v} != opposite:
                return None  # link condition in fragment k: the collapse would pinch its surface
        return removed

    def _collapse(self, u: int, v: int, tolerance: float, ctx: Fan | None = None) -> bool:
        """Merge ``u`` into ``v`` if polygons, topology, orientation and the error bound allow; True if done.

        ``ctx``: :meth:`_fan` of ``u``, when several targets of one ``u`` are tried in a row.
        """
        ctx = ctx if ctx is not None else self._fan(u)
        removed = self._allowed(u, v, ctx)
        if removed is None:
            return False
        faces, positions, limit = self.faces, self.points, ctx.limit
        kept = sorted(self.vertex_faces[u].difference(removed))
        new_faces = {}
        for t in kept:
            f = faces[t]
            g = new_faces[t] = moved(f, u, v)
            if not turns_little(positions, f, g, limit):
                return False
        fault_kept = [t for t in kept if self.fault[t]]
        points: list[int] = []
        nearest: list[int] = []
        if ctx.on_fault:
            points = [u] + [p for t in self.vertex_faces[u] for p in self.assigned[t]]
            if not fault_kept:
                return False
            found = self._within(points, np.array([new_faces[t] for t in fault_kept], dtype=np.int64), tolerance)
            if found is None:
                return False
            nearest = [fault_kept[i] for i in found]
        self._apply(u, v, removed, kept, new_faces, points, nearest, tolerance)
        return True

    def _within(self, points: list[int], triangles: np.ndarray, tolerance: float) -> list[int] | None:
        """The new fault face (index into ``triangles`` (k, 3)) nearest each removed fault point, if every one
        lies within ``tolerance`` of the new fault faces and the new faces (centroids, edge midpoints) within
        ``tolerance`` of their nearest cut fault faces (the other side of the bound, as points near the new
        faces would let a fold between them pass); else None. The arithmetic is compiled
        (:mod:`.collapse_kernels`): numpy's overhead dominated on so few points.
        """
        found = self._kernels.fault_bound(self._positions, np.array(points, dtype=np.int64), triangles, self.reference,
                                          self._centroids, *self._grid, self._cell, self._candidates, tolerance)
        return found.tolist() if len(found) else None

    def _apply(self, u: int, v: int, removed: list[int], kept: list[int], new_faces: dict, points: list[int],
               nearest: list[int], tolerance: float) -> None:
        touched = (u, tuple(h for t in removed if (h := self.history[t])))
        self.clock += 1
        self.modified.update((t, self.clock) for t in removed)
        self.modified.update((t, self.clock) for t in kept)
        for t in removed:
            for x in self.faces[t]:
                self.vertex_faces[x].discard(t)
            del self.faces[t], self.assigned[t], self.history[t]
        for t in kept:
            self.faces[t] = new_faces[t]
            self.history[t] = merged(self.history[t], touched)
            if self.fault[t]:
                self.assigned[t] = []
        for point, t in zip(points, nearest):
            self.assigned[t].append(point)
        self.vertex_faces[v].update(kept)
        del self.vertex_faces[u]
        self.done.append((u, v, tolerance, points, nearest))
        self.quadric[v] = self.quadric[v] + self.quadric[u]

    def flip_needles(self, frozen: set[int]) -> int:
        """Flip the long edge of every cap needle with the face across it; returns how many flips were made.

        The booleans leave needles: faces whose corner lies within ~1e-10 of their opposite (long) edge, their
        height below :data:`MIN_SHAPE` of that edge. Written as float32 about each fragment's own pivot,
        such a corner moves by more than the height, so the needle turns over differently in the two
        fragments sharing it, and the written fault folds where the fragments should meet exactly. The
        long edge (b, c) of needle (a, b, c) is replaced by (a, d), d the far corner of the face across it,
        when that face bounds the same fragments (and lies in the same input polygon) and both new faces
        are well shaped and face the way it does: (a, b, d) and (a, d, c) cover the same quad, so the
        surface moves by the needle's height only. Faces of the ``frozen`` fragments (kept as cut) stay.
        Faces in ascending ids, again until none flips: deterministic.
        """
        flips = 0
        again = True
        # Faces found well shaped, as they were then: the points do not move here, so such a face is no
        # needle in a later pass either unless a flip changed it (skipping it skips a no-op: same flips).
        shaped: dict[int, tuple[int, ...]] = {}
        while again:
            again = False
            for t in sorted(self.faces):
                if t not in self.faces or not frozen.isdisjoint(self.owners[t]) or shaped.get(t) == self.faces[t]:
                    continue
                i = self._needle_edge(self.faces[t])
                if i < 0:
                    shaped[t] = self.faces[t]
                elif self._flip(t, i):
                    flips += 1
                    again = True
        return flips

    def _needle_edge(self, f: tuple[int, ...]) -> int:
        """The corner (0-2) starting the long edge of face ``f`` if it is a cap needle, else -1."""
        (ax, ay, az), (bx, by, bz), (cx, cy, cz) = self.points[f[0]], self.points[f[1]], self.points[f[2]]
        # Written out (most faces are no needles): squared edge lengths as sum() adds them, and the normal.
        lengths = ((bx - ax) * (bx - ax) + (by - ay) * (by - ay) + (bz - az) * (bz - az),
                   (cx - bx) * (cx - bx) + (cy - by) * (cy - by) + (cz - bz) * (cz - bz),
                   (ax - cx) * (ax - cx) + (ay - cy) * (ay - cy) + (az - cz) * (az - cz))
        i = 0 if lengths[0] >= lengths[1] and lengths[0] >= lengths[2] else 1 if lengths[1] >= lengths[2] else 2
        ux, uy, uz, vx, vy, vz = bx - ax, by - ay, bz - az, cx - ax, cy - ay, cz - az
        nx, ny, nz = uy * vz - uz * vy, uz * vx - ux * vz, ux * vy - uy * vx
        if nx * nx + ny * ny + nz * nz > (MIN_SHAPE * lengths[i]) * (MIN_SHAPE * lengths[i]):
            return -1
        return i

    def _flip(self, t: int, i: int) -> bool:
        """Flip the long edge (from corner ``i``) of needle face ``t`` if allowed (see :meth:`flip_needles`)."""
        f = self.faces[t]
        a, b, c = f[(i + 2) % 3], f[i], f[(i + 1) % 3]
        across = [s for s in self.vertex_faces[b] & self.vertex_faces[c] if s != t]
        if len(across) != 1:
            return False
        s = across[0]
        g = self.faces[s]
        d = next(x for x in g if x != b and x != c)
        if (self.owners[s] != self.owners[t] or self.fault[s] != self.fault[t] or self.groups[s] != self.groups[t]
                or g[(g.index(c) + 1) % 3] != b or self.vertex_faces[a] & self.vertex_faces[d]):
            return False  # another surface, misoriented, or an edge a-d already there (the flip would pinch)
        new_t, new_s = (a, b, d), (a, d, c)
        if not (turns_little(self.points, g, new_t, 0.0) and turns_little(self.points, g, new_s, 0.0)):
            return False
        self.clock += 1
        self.vertex_faces[b].discard(s)
        self.vertex_faces[c].discard(t)
        self.vertex_faces[a].add(s)
        self.vertex_faces[d].add(t)
        self.faces[t], self.faces[s] = new_t, new_s
        self.history[t] = self.history[s] = merged(self.history[t], self.history[s])
        self.modified[t] = self.modified[s] = self.clock
        return True

    def behind(self, faces: list[int]) -> set[int]:
        """The vertices whose collapses changed any of ``faces`` (or the faces they were made from).

        A face's :attr:`history` is () when no collapse changed it, else a node ``(u, parents)``: the collapse of
        ``u`` (-1 for a mere union) after those of the ``parents`` nodes.
        """
        found: set[int] = set()
        seen: set[int] = set()
        stack = [self.history[t] for t in faces]
        while stack:
            node = stack.pop()
            if not node or id(node) in seen:
                continue
            seen.add(id(node))
            if node[0] >= 0:
                found.add(node[0])
            stack.extend(node[1])
        return found

    def face_arrays(self) -> tuple[np.ndarray, np.ndarray]:
        """Ids (m',) of the faces left, ascending, and their corners (m', 3)."""
        ids = np.array(sorted(self.faces), dtype=np.int64)
        return ids, np.array([self.faces[t] for t in ids.tolist()], dtype=np.int64).reshape(-1, 3)


def _kernels() -> ModuleType:
    """:mod:`.collapse_kernels`, imported on first use: numba loads only when the simplify stage runs."""
    # numba loads only when the simplify stage runs
    from fracture_cli.stages.simplify import collapse_kernels

    return collapse_kernels


def _collapse_pack() -> ModuleType:
    """:mod:`.collapse_pack` (and the compiled loop), imported on first use as :func:`_kernels`."""
    # numba loads only when the simplify stage runs
    from fracture_cli.stages.simplify import collapse_pack

    return collapse_pack
