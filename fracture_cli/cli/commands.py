"""Every command of ``fracture``: importing this module registers them all on the group.

The group and the chain's stage commands are in :mod:`fracture_cli.cli.group`; each
module below adds its commands to that group when it is imported (``@cli.command``),
so a new command is one new module and one line here.
"""

from fracture_cli.cli import atlas, batch, tools
from fracture_cli.cli.group import cli

COMMAND_MODULES = (tools, batch, atlas)  # what registered the terminal commands (bake, recipes, impact, view, batch,
# atlas, ...)

__all__ = ["COMMAND_MODULES", "cli"]
