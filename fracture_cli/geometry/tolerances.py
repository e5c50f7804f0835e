"""The shared tolerances of the bake: every threshold more than one algorithm uses, with one name each.

Use it as ``from fracture_cli.geometry import tolerances as tol`` and write ``tol.SAME_POINT``, as
trimesh's ``tol.merge``.

Units
-----
The bake works in *normalized coordinates*: the input is centred on its bounding box and scaled so
that the box's diagonal is 1 (:class:`fracture_cli.types.Normalization`). So

* a **length** is a fraction of the bounding-box diagonal (an area, of the diagonal squared);
* a **volume** is a fraction of a reference volume that its sentence names: the input solid's, or
  the smaller body's where two are compared;
* a **relative** tolerance is a fraction of the quantity it is compared with (a ratio, no unit);
* an **absolute guard** has no unit: it keeps arithmetic finite and decides nothing.

How the values were chosen
--------------------------
One float64 operation on numbers of size 1 rounds by at most 1.1e-16 (2**-53); a computed result
(a sum over a mesh, an exact boolean's corner rounded to doubles, a clipped polygon's corner) carries
the rounding of every step, up to ~1e-13 of its scale. float32 storage of a coordinate of the unit
box moves it by up to 6e-8. Each threshold sits far above the rounding it absorbs and far below any
feature a model can have (float32 cannot hold a model finer than ~1e-7 of its size), so that no
output depends on where inside that gap it lies.

What belongs here
-----------------
A threshold that several algorithms use with one meaning. A value that belongs to one algorithm (a
solver's convergence option, a series' term count, the sampling of a search) stays beside that
algorithm with its comment; so do the runtime format's constants (docs/FORMAT.md fixes them for every
engine's reader). A module-level constant elsewhere whose value equals one of these says, in its
comment, why it is not this module's (``tests/test_tolerances.py`` checks that).

Compiled kernels (numba) read these as constants when they compile: after changing a value, delete
the kernels' cache (``make clean``) so that none runs with the old one.

Every value here is part of the bake's output: changing one changes bytes (``make goldens``).
"""

from __future__ import annotations

# --- Absolute guards (no unit) -------------------------------------------------------------------------------

# The smallest positive divisor: ``x / max(d, SMALLEST_DIVISOR)`` is ``x / d`` for every length, area, volume or
# norm a mesh can have, and finite (0 for x = 0) where d is 0; ``abs(d) > SMALLEST_DIVISOR`` asks "can I divide
# by d?".
SMALLEST_DIVISOR = 1e-300

# --- Relative (a fraction of the quantity compared with; no unit) -------------------------------------------

# A computed value at most this fraction of its scale is zero up to float64 rounding: a determinant beside the
# product of its rows' lengths, a product of inertia beside the largest entry, a point's height above a hull face
# beside the hull's size, a sum of normals beside its faces' area, a field value of order 1.
ROUNDOFF = 1e-12
# Two computed values within this fraction of each other are a tie: a bound is widened by it
# (``x <= bound * (1 + TIE)``) so that rounding cannot cut off a value on the bound, an improvement must beat it
# (``cost < best * (1 - TIE)``) so that rounding cannot count as one, and sums that must agree agree within it.
# Angles (radians) within it are one angle.
TIE = 1e-9

# --- Lengths (fractions of the bounding-box diagonal) -------------------------------------------------------

# A length at most this is zero: triangles separated by less touch (the separating-axis test's allowance), and a
# span or a grid cell that may be empty is at least this long.
ZERO_LENGTH = 1e-12
# The rounding allowance of a position computed in float64: positions closer than this are one point (corners
# shared by two fragments, a fault's vertices), and a box or plane test is widened by it so that rounding never
# drops a point on its boundary.
SAME_POINT = 1e-9
# A constructed point (a corner of an exact boolean rounded to doubles, of a clip, a face's centroid) lies on a
# plane or a surface when it is this close to it: faces on one interface, outer faces on the input's surface,
# the depth of a point inside clipped parts.
ON_SURFACE = 1e-7
# Points closer than this may be one point stored twice in float32 (a baked GLB read back, float32 distances):
# fragments' vertices closer are welded, the cage keeps at least this clearance from the input, and a point on
# the surface finds its triangle within it.
WELD = 1e-6

# --- Volumes (fractions of a reference volume, named in each sentence) --------------------------------------

# A body or an intersection holding less than this fraction of its reference volume is rounding, not material:
# a zero-volume shell where faces of an exact boolean coincide, two bodies touching along a face, a piece that
# sampled none of the asset. The reference is the input solid's volume, the smaller body's where two are
# compared, or the cube of the bounding-box diagonal where no volume is known yet (repair's bodies, the patches of
# a fragment).
SLIVER_VOLUME = 1e-9
