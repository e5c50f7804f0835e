"""fracture: prefractured fragments and a realtime impact file from a game asset.

Implements "Breaking Good: Fracture Modes for Realtime Destruction" (Sellan et al.,
ACM TOG 2023). Each stage is a plain function ``stage(data, options) -> data``
living in :mod:`fracture_cli.stages`; :mod:`fracture_cli.pipeline` lists them in
one table that ``bake``, the recipes and the CLI (:mod:`fracture_cli.cli`, which
only parses options) are generated from.
"""

__version__ = "0.1.0"

# Before anything imports numpy: the numeric kernels that give the same bits on every CPU (numeric_env.py).
from fracture_cli.system.numeric_env import pin_environment  # noqa: E402

pin_environment()

from fracture_cli.errors import FractureError, InputError, StageError  # noqa: E402

__all__ = ["__version__", "FractureError", "InputError", "StageError"]
