"""The runtime file's JSON header, parsed strictly (docs/FORMAT.md section 1)."""

from __future__ import annotations

import json
from typing import Any

MAX_JSON_DEPTH = 64


def _reject_constant(name: str) -> None:
    raise ValueError(f"{name} is not JSON")


def parse_header(header_bytes: bytes) -> Any:
    """The header's JSON value, parsed strictly (docs/FORMAT.md section 1).

    UTF-8, standard JSON only (``NaN``, ``Infinity`` rejected), nesting at most
    :data:`MAX_JSON_DEPTH` levels (checked before parsing, so a hostile file
    cannot make the parser recurse without bound).

    Raises
    ------
    ValueError
        With the reason (``UnicodeDecodeError`` and ``json.JSONDecodeError`` are ValueErrors).
    """
    text = header_bytes.decode("utf-8")
    depth, in_string, escaped = 0, False, False
    for char in text:
        if in_string:
            if escaped:
                escaped = False
            elif char == "\\":
                escaped = True
            elif char == '"':
                in_string = False
        elif char == '"':
            in_string = True
        elif char in "[{":
            depth += 1
            if depth > MAX_JSON_DEPTH:
                raise ValueError(f"nested deeper than {MAX_JSON_DEPTH} levels")
        elif char in "]}":
            depth -= 1
    return json.loads(text, parse_constant=_reject_constant)
