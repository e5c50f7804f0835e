"""Mass properties of closed triangle meshes: volume, centre of mass, inertia tensor (unit density).

The integrals are exact for a closed, consistently oriented mesh (divergence
theorem): the solid is the signed sum of the tetrahedra ``(o, a, b, c)`` from a
local origin ``o`` to every triangle. ``o`` is the bounding-box centre of the
mesh, so the products stay small and the result does not depend on where the
asset sits in its file.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from fracture_cli.geometry import tolerances as tol
from fracture_cli.geometry.trigeom import cross3


@dataclass(frozen=True)
class MassProperties:
    """Unit-density mass properties of one closed body.

    Attributes
    ----------
    volume : float
        Signed volume (> 0 for an outward-oriented mesh); the mass at unit density.
    center : (3,) float64
        Centre of mass.
    inertia : (3, 3) float64
        Inertia tensor about the centre of mass, axes of the input:
        ``I = integral (|r|^2 Id - r r^T) dV`` with ``r = x - center``; the
        off-diagonal entries are the (negative) products of inertia
        ``I[0, 1] = -integral r_x r_y dV``. Units: length^5 (multiply by a
        density for mass * length^2).
    """

    volume: float
    center: np.ndarray
    inertia: np.ndarray

    def to_world(self, normalization) -> MassProperties:
        """The same body in the input's units: volume * s^3, centre mapped, inertia * s^5 (``s`` the scale).

        Parameters
        ----------
        normalization : Normalization
            The bake's map from normalized coordinates (a similarity: no rotation).
        """
        s = float(normalization.scale)
        return MassProperties(self.volume * (s * s * s), normalization.to_world(self.center[None, :])[0],
                              self.inertia * (s * s * s * s * s))

    def inertia6(self) -> np.ndarray:
        """The tensor's six distinct entries (6,) ``[Ixx, Iyy, Izz, Ixy, Ixz, Iyz]`` (entries, sign included)."""
        return inertia6(self.inertia)

    def principal(self) -> tuple[np.ndarray, np.ndarray]:
        """Principal moments (3,) and the rotation (3, 3) whose columns are the principal axes.

        See :func:`principal_axes`: ``inertia = R diag(moments) R^T``, ``det R = +1``.
        """
        return principal_axes(self.inertia)


def mass_properties(vertices: np.ndarray, faces: np.ndarray) -> MassProperties:
    """Volume, centre of mass and inertia tensor (about the centre of mass) of a closed mesh.

    Parameters
    ----------
    vertices : (n, 3) float
        Positions.
    faces : (m, 3) int
        Triangles of a closed surface, counter-clockwise seen from outside.
        Cavities (inner shells oriented inward) subtract, as they should.

    Returns
    -------
    MassProperties
        At unit density. A mesh without volume gets volume 0, the mean of its
        vertices as centre and a zero tensor.

    Notes
    -----
    For the tetrahedron ``(0, a, b, c)`` with signed volume
    ``v = a . (b x c) / 6``, the first moment is ``v (a + b + c) / 4`` and the
    second moment ``integral x x^T dV = v / 20 (a a^T + b b^T + c c^T + s s^T)``
    with ``s = a + b + c``. Summing over all triangles gives the integrals of
    the solid; the parallel-axis theorem moves the second moment to the centre
    of mass, and ``I = tr(C) Id - C``.
    """
    V = np.asarray(vertices, dtype=np.float64)
    F = np.asarray(faces, dtype=np.int64).reshape(-1, 3)
    if len(F) == 0:
        centre = V.mean(axis=0) if len(V) else np.zeros(3)
        return MassProperties(0.0, centre, np.zeros((3, 3)))
    # The vertices the faces use, in order (as V[np.unique(F)], without sorting every corner).
    mask = np.zeros(len(V), dtype=bool)
    mask[F.reshape(-1)] = True
    used = V[mask]
    origin = (used.min(axis=0) + used.max(axis=0)) / 2.0
    a, b, c = V[F[:, 0]] - origin, V[F[:, 1]] - origin, V[F[:, 2]] - origin
    v = np.einsum("ij,ij->i", a, cross3(b, c)) / 6.0  # np.cross's products, without its axis handling
    volume = float(v.sum())
    s = a + b + c
    if not abs(volume) > tol.SMALLEST_DIVISOR:
        return MassProperties(0.0, used.mean(axis=0), np.zeros((3, 3)))
    first = (v[:, None] * s).sum(axis=0) / 4.0
    centre_local = first / volume
    second = np.einsum("t,tij->ij", v / 20.0, _outer(a) + _outer(b) + _outer(c) + _outer(s))
    # Parallel axis: second moment about the centre of mass.
    second -= volume * np.outer(centre_local, centre_local)
    second = (second + second.T) / 2.0
    inertia = np.trace(second) * np.eye(3) - second
    return MassProperties(volume, origin + centre_local, inertia)


def _outer(x: np.ndarray) -> np.ndarray:
    """Outer products (t, 3, 3) of row vectors (t, 3)."""
    return x[:, :, None] * x[:, None, :]


def inertia6(inertia: np.ndarray) -> np.ndarray:
    """The six distinct entries (6,) ``[Ixx, Iyy, Izz, Ixy, Ixz, Iyz]`` of a symmetric (3, 3) tensor."""
    tensor = np.asarray(inertia, dtype=np.float64)
    return tensor[[0, 1, 2, 0, 0, 1], [0, 1, 2, 1, 2, 2]]


def principal_axes(inertia: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Principal moments (3,) and a proper rotation (3, 3) whose columns are the principal axes.

    ``inertia = R diag(moments) R^T``. The axes are ordered and signed to
    follow the coordinate axes as closely as possible (column ``c`` is the
    principal axis nearest to axis ``c``, pointing its way), so a body aligned
    with its model axes gets the identity; the last column is flipped if
    needed for ``det R = +1``. Entries below ``tol.ROUNDOFF`` of the tensor's largest are
    rounding and are zeroed first, so equal moments (a cube) keep the
    identity.
    """
    tensor = np.asarray(inertia, dtype=np.float64)
    tensor = (tensor + tensor.T) / 2.0
    largest = max(float(np.abs(tensor).max()), tol.SMALLEST_DIVISOR)
    tensor = np.where(np.abs(tensor) > tol.ROUNDOFF * largest, tensor, 0.0)
    moments, axes = np.linalg.eigh(tensor)
    # Scored with Python floats: the sum numpy forms of three entries, ((a + b) + c), without six array
    # round trips per call (the collision stage asks for thousands of overlaps' axes).
    size = np.abs(axes).tolist()
    best = max(_PERMUTATIONS, key=lambda perm: ((size[0][perm[0]] + size[1][perm[1]]) + size[2][perm[2]], perm))
    axes, moments = axes[:, list(best)], moments[list(best)]
    axes = axes * np.where(np.diag(axes) < 0, -1.0, 1.0)[None, :]
    if np.linalg.det(axes) < 0:
        axes[:, 2] = -axes[:, 2]
    return moments, axes


_PERMUTATIONS = ((0, 1, 2), (0, 2, 1), (1, 0, 2), (1, 2, 0), (2, 0, 1), (2, 1, 0))


def quaternion_xyzw(rotation: np.ndarray) -> np.ndarray:
    """Unit quaternion (4,) ``[x, y, z, w]`` (glTF order, ``w >= 0``) of a proper rotation matrix (3, 3)."""
    R = np.asarray(rotation, dtype=np.float64)
    trace = np.trace(R)
    # Shepperd's method: branch on the largest of w, x, y, z for accuracy.
    candidates = np.array([trace, R[0, 0], R[1, 1], R[2, 2]])
    k = int(np.argmax(candidates))
    if k == 0:
        w = np.sqrt(max(1.0 + trace, 0.0)) / 2.0
        q = np.array([(R[2, 1] - R[1, 2]) / (4 * w), (R[0, 2] - R[2, 0]) / (4 * w), (R[1, 0] - R[0, 1]) / (4 * w), w])
    else:
        i = k - 1
        j, m = (i + 1) % 3, (i + 2) % 3
        r = np.sqrt(max(1.0 + R[i, i] - R[j, j] - R[m, m], 0.0))
        q = np.zeros(4)
        q[i] = r / 2.0
        q[j] = (R[j, i] + R[i, j]) / (2 * r)
        q[m] = (R[m, i] + R[i, m]) / (2 * r)
        q[3] = (R[m, j] - R[j, m]) / (2 * r)
    q /= np.linalg.norm(q)
    return -q if q[3] < 0 else q
