"""Game-ready output: one body per fragment, mass properties, collision shapes, lean faults.

Library modules, one concern each, wired into the bake: the ``fragments`` stage splits
every cut into its bodies (``components``), the ``collision`` stage (``stage``) computes the
convex parts, the runtime stage bonds fragments through shared faces and writes mass and
parts into the runtime file, and the GLB writer puts pivots, extras and parts in the GLB.

* :mod:`~fracture_cli.gameready.stage`: the ``collision`` stage, pivots and the data both files share;
* :mod:`~fracture_cli.gameready.mass`: volume, centre of mass and inertia tensor of closed meshes;
* :mod:`~fracture_cli.gameready.components`: connected bodies of a fragment, tiny-body merging, the
  fragment graph recomputed from the meshes;
* :mod:`~fracture_cli.gameready.collision`: non-overlapping convex collision parts per fragment, from
  :mod:`~fracture_cli.gameready.decompose` (convex decomposition by plane cuts),
  :mod:`~fracture_cli.gameready.separate` (one separating plane per overlapping pair) and
  :mod:`~fracture_cli.gameready.hulls` (hulls, the vertex cap);
* :mod:`~fracture_cli.gameready.export_shapes`: collision parts and mass properties in the GLB
  (OMI_physics_shape/OMI_physics_body, Godot ``-convcolonly`` nodes, Unreal ``UCX_`` nodes);
* :mod:`~fracture_cli.gameready.simplify`: prototype simplification of the fault (interior) faces.
"""
