"""Import open3d, supplying libusb when the system lacks it.

open3d's Linux wheels link against ``libusb-1.0.so.0``, a system library that
minimal machines (containers, CI images) do not have, and then fail to import.
The ``libusb-package`` wheel ships that library; loading it globally before
open3d lets the dynamic linker resolve the dependency without root or apt.

``import open3d`` also imports its plotly viewer, and with it dash and plotly
(about 0.5 s, a third of the import), which this tool never uses: a stand-in
module takes its place (its functions raise ImportError if called).
"""

from __future__ import annotations

import ctypes
import functools
import sys
import types

_PLOTLY_VIEWER = "open3d.visualization.draw_plotly"


@functools.lru_cache(maxsize=1)
def open3d():
    """Return the imported ``open3d`` module."""
    if "open3d" not in sys.modules and _PLOTLY_VIEWER not in sys.modules:
        sys.modules[_PLOTLY_VIEWER] = _without_plotly_viewer()
    try:
        import open3d as o3d
    except ImportError as exc:
        if "libusb" not in str(exc):
            raise
        import libusb_package

        ctypes.CDLL(str(libusb_package.get_library_path()), mode=ctypes.RTLD_GLOBAL)
        import open3d as o3d
    return o3d


def _without_plotly_viewer() -> types.ModuleType:
    """A stand-in for open3d's plotly viewer module (what ``open3d.visualization`` imports from it)."""
    module = types.ModuleType(_PLOTLY_VIEWER)

    def unavailable(*args: object, **kwargs: object) -> None:
        raise ImportError("open3d's plotly viewer is not loaded by fracture (fracture_cli/geometry/open3d_bridge.py)")

    module.get_plotly_fig = module.draw_plotly = module.draw_plotly_server = unavailable  # type: ignore[attr-defined]
    return module
