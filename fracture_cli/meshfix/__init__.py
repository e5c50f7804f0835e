"""Standalone mesh repairs and checks on welded triangle meshes (issue 15).

Each module is one concern, works on plain arrays (positions and faces over
vertices welded by position) and returns a small frozen dataclass with
:class:`~fracture_cli.meshfix.records.RepairRecord` entries for report.json's
``repairs`` list:

* :mod:`~fracture_cli.meshfix.weld_check`: closed / manifold / oriented /
  one-body / volume check of a mesh as written (welded by exact position);
* :mod:`~fracture_cli.meshfix.nonmanifold`: split edges with more than two
  faces, and vertices with several fans, into closed edge-manifold bodies;
* :mod:`~fracture_cli.meshfix.holes`: boundary loops, the fill-or-thicken
  decision from the mesh itself, hole filling, and inward thickening of sheets.
"""

from fracture_cli.meshfix.records import RepairRecord

__all__ = ["RepairRecord"]
