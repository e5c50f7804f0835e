"""``numba.njit`` with an on-disk cache, for the project's compiled kernels.

Compiled code is cached (``cache=True``: beside the module, or in the user's
cache directory when that is read-only) so that only the first run compiles.
Where no cache directory is writable at all, numba refuses ``cache=True``;
the kernels are then compiled without it, in every process, with one warning.
This module imports numba: only the kernel modules import it.
"""

from __future__ import annotations

import logging
from collections.abc import Callable
from typing import Any

import numba

log = logging.getLogger(__name__)
_UNCACHED: list[str] = []


def njit(cache: bool = True, **options: Any) -> Callable[[Callable], Any]:
    """``numba.njit`` with ``cache``, or without it where no cache directory is writable (a read-only install
    and home: numba then has nowhere to put it, and every process compiles again, some seconds)."""

    def wrap(function: Callable) -> Any:
        try:
            return numba.njit(cache=cache, **options)(function)
        except RuntimeError:
            if not _UNCACHED:
                log.warning("numba cannot cache the compiled kernels here (set NUMBA_CACHE_DIR to a writable "
                            "folder): each bake compiles them again")
            _UNCACHED.append(function.__name__)
            return numba.njit(**options)(function)

    return wrap
