"""The realtime side of fracture modes: the projection file and impact projection.

Everything in this package depends on numpy and the standard library only, so a
game server or a tool can import it without scipy, trimesh or the bake stages:

* :mod:`fracture_cli.runtime.format` reads and writes ``<stem>.fracture.json`` +
  ``<stem>.fracture.bin`` (documented in ``docs/FORMAT.md``);
* :mod:`fracture_cli.runtime.impact` turns an impact into groups of fragments.

This ``__init__`` deliberately imports nothing, so importing one of the two
modules does not pull in the other's dependencies.
"""
