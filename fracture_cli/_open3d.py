"""Import open3d, supplying libusb when the system lacks it.

open3d's Linux wheels link against ``libusb-1.0.so.0``, a system library that
minimal machines (containers, CI images) do not have, and then fail to import.
The ``libusb-package`` wheel ships that library; loading it globally before
open3d lets the dynamic linker resolve the dependency without root or apt.
"""

from __future__ import annotations

import ctypes
import functools


@functools.lru_cache(maxsize=1)
def open3d():
    """Return the imported ``open3d`` module."""
    try:
        import open3d as o3d
    except ImportError as exc:
        if "libusb" not in str(exc):
            raise
        import libusb_package

        ctypes.CDLL(str(libusb_package.get_library_path()), mode=ctypes.RTLD_GLOBAL)
        import open3d as o3d
    return o3d
