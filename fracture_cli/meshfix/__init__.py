"""Standalone mesh repairs and checks on welded triangle meshes (issue 15).

Each module is one concern, works on plain arrays (positions and faces over
vertices welded by position) and returns a small frozen dataclass with
:class:`~fracture_cli.meshfix.records.RepairRecord` entries for report.json's
``repairs`` list:

* :mod:`~fracture_cli.meshfix.weld_check`: closed / manifold / oriented /
  one-body / volume check of a mesh as written (welded by exact position);
* :mod:`~fracture_cli.meshfix.faces`: repeated faces (a soup's copies, walls
  between touching solids, double-sided cards) and consistent winding;
* :mod:`~fracture_cli.meshfix.nonmanifold`: split edges with more than two
  faces, and vertices with several fans, into closed edge-manifold bodies;
* :mod:`~fracture_cli.meshfix.holes`: boundary loops, the fill-or-thicken
  decision from the mesh itself, and hole filling;
* :mod:`~fracture_cli.meshfix.thicken`: inward thickening of sheets, inside
  the input's bounding box.

The repair stage (:mod:`fracture_cli.stages.repair`) chains them; the bake's
checks (:mod:`fracture_cli.checks`) use :mod:`~fracture_cli.meshfix.weld_check`.
"""

from fracture_cli.meshfix.records import RepairRecord

__all__ = ["RepairRecord"]
