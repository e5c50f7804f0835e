"""Free space in an output folder, and byte counts as people read them."""

from __future__ import annotations

import shutil


def free_bytes(out_dir: str) -> int:
    """Bytes available to this user in ``out_dir``'s file system."""
    return shutil.disk_usage(out_dir).free


def human_size(n: float) -> str:
    """``n`` bytes as "512 bytes", "3.4 MiB" ... (binary units)."""
    for unit in ("bytes", "KiB", "MiB", "GiB"):
        if n < 1024 or unit == "GiB":
            return f"{n:.0f} {unit}" if unit == "bytes" else f"{n:.1f} {unit}"
        n /= 1024
    return f"{n:.1f} TiB"  # pragma: no cover
