"""Incremental state: one small hidden file per asset, next to its outputs.

``OUTDIR/<folder>/.<stem>.batch-state.json`` holds the asset's key (a hash of
the tool version, the resolved recipe and the bytes of every input file) and
the size and modification time of each published output. It is written only
after the outputs were published, so it never vouches for a set that is not
there; an asset is up to date when the key matches and every output is still
exactly the file that was published. Deleting the file forces a re-bake.
Engines skip dot files on import (Godot, Unity), so the state can ship with the
outputs unnoticed.
"""

from __future__ import annotations

import contextlib
import json
import logging
import os
import time

from fracture_cli.batch.inputs import InputFile
from fracture_cli.io.atomic import write_bytes_atomic
from fracture_cli.pipeline.cache import cache_key
from fracture_cli.pipeline.recipe import Recipe

log = logging.getLogger(__name__)

STATE_FORMAT = 1
STATE_SUFFIX = ".batch-state.json"
# A hash taken this soon after a file's mtime may predate an edit in the same timestamp tick.
_RACY_NS = 2_000_000_000


def state_path(out_dir: str, stem: str) -> str:
    """Path of an asset's state file."""
    return os.path.join(out_dir, f".{stem}{STATE_SUFFIX}")


def asset_key(inputs: tuple[InputFile, ...], recipe: Recipe) -> str:
    """Hex key of everything a bake's output depends on (tool version included by ``cache_key``)."""
    return cache_key("batch", [(f.name, f.sha256) for f in inputs], recipe.name, recipe.description,
                     list(recipe.chain), recipe.options)


def content_seed(inputs: tuple[InputFile, ...]) -> int:
    """A 63-bit seed from the inputs' bytes only (not the recipe), so every recipe sees the same hits."""
    return int(cache_key("content", [(f.name, f.sha256) for f in inputs])[:15], 16)


def read_state(path: str) -> dict | None:
    """The state at ``path``, or None when missing or unreadable (then the asset is re-baked)."""
    try:
        with open(path, encoding="utf-8") as fh:
            state = json.load(fh)
    except FileNotFoundError:
        return None
    except (OSError, ValueError) as exc:
        log.warning("batch: ignoring unreadable state %s (%s); the asset is re-baked", path, exc)
        return None
    if not isinstance(state, dict) or state.get("format") != STATE_FORMAT:
        return None
    return state


def reusable_hashes(state: dict | None) -> dict[str, InputFile]:
    """Input hashes of a previous state that may be trusted when size and mtime still match."""
    if not state:
        return {}
    hashed_at = int(state.get("hashed_at_ns", 0))
    out = {}
    for name, (size, mtime_ns, sha) in (state.get("inputs") or {}).items():
        if mtime_ns + _RACY_NS < hashed_at:
            out[name] = InputFile(name=name, size=size, mtime_ns=mtime_ns, sha256=sha)
    return out


def _stat_outputs(paths: tuple[str, ...]) -> dict[str, list[int]]:
    out = {}
    for path in paths:
        st = os.stat(path)
        out[os.path.basename(path)] = [st.st_size, st.st_mtime_ns]
    return out


def is_up_to_date(state: dict | None, key: str, out_dir: str) -> bool:
    """True when ``state`` has ``key`` and every output it lists is unchanged on disk."""
    if not state or state.get("key") != key or not state.get("outputs"):
        return False
    try:
        current = _stat_outputs(tuple(os.path.join(out_dir, name) for name in state["outputs"]))
    except OSError:
        return False
    return current == state["outputs"]


def write_state(path: str, key: str, inputs: tuple[InputFile, ...], outputs: tuple[str, ...],
                hashed_at_ns: int, report: dict) -> None:
    """Record a successful publish (call only after the outputs are in place).

    The state is written after the bake released its output lock, so another
    bake of the same stem (a plain ``fracture bake``, a second batch) may have
    published in between. The outputs are stat-ed first and the report on disk
    compared with ``report`` (this bake's: the ``files`` block, the hashes of
    the set it published) afterwards; when they differ, the
    set on disk is not the one this key describes, and the state file is
    removed instead of vouching for it (the next run bakes again).
    """
    outputs_now = _stat_outputs(outputs)
    if not _report_is(os.path.join(os.path.dirname(path), _report_name(outputs)), report):
        log.warning("%s: another bake replaced the outputs while this one finished; not recorded as up to date",
                    os.path.dirname(path))
        with contextlib.suppress(FileNotFoundError):
            os.unlink(path)
        return
    state = {
        "format": STATE_FORMAT,
        "key": key,
        "hashed_at_ns": hashed_at_ns,
        "written_at": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()),
        "inputs": {f.name: [f.size, f.mtime_ns, f.sha256] for f in inputs},
        "outputs": outputs_now,
    }
    write_bytes_atomic(path, (json.dumps(state, indent=1, sort_keys=True) + "\n").encode())


def _report_name(outputs: tuple[str, ...]) -> str:
    return next(os.path.basename(p) for p in outputs if p.endswith(".report.json"))


def _report_is(path: str, report: dict) -> bool:
    """True when the report at ``path`` lists the same files as ``report`` (the hashes of the set it published)."""
    try:
        with open(path, encoding="utf-8") as fh:
            return bool(json.load(fh).get("files") == json.loads(json.dumps(report.get("files"))))
    except (OSError, ValueError, AttributeError):
        return False
