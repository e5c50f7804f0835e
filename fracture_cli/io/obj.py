"""OBJ face indices as the format defines them, before trimesh parses the file.

In an OBJ ``f`` line, index ``i > 0`` is the ``i``-th ``v`` (``vt``, ``vn``)
line of the file and ``i < 0`` counts back from the *current* end of that
list: ``-1`` is the most recent ``v`` line *above* this face (Wavefront OBJ
specification, "Referencing groups of vertices"). Index 0 does not exist.
trimesh resolves negative indices against the whole file's list, so a file
that defines a second object's vertices after the first object's faces would
be scrambled; :func:`absolute_indices` rewrites them first.

Words are separated by any white space, tabs included, and a statement may be
indented; trimesh's parser only knows single spaces at the start of a line, so
:func:`plain_whitespace` rewrites tabs and indentation first (a valid file
exported with tabs would otherwise read as empty).
"""

from __future__ import annotations

import re

from fracture_cli.errors import InputError

# A face line with a negative or a zero index somewhere (only such files are rewritten).
_NEEDS_REWRITE = re.compile(rb"(?m)^[ \t]*f[ \t][^\n]*?(?:(?<=[ \t/])-|(?<=[ \t/])0+(?=[ \t/\r\n]|$))")
_KINDS = {b"v": 0, b"vt": 1, b"vn": 2}
_ODD_WHITESPACE = re.compile(rb"(?m)\t|^[ ]+(?=\S)")
_INDENT = re.compile(rb"(?m)^[ \t]+")


def plain_whitespace(data: bytes) -> bytes:
    """``data`` with tabs made spaces and lines unindented (the same statements), or ``data`` itself if none."""
    if not _ODD_WHITESPACE.search(data):
        return data
    return _INDENT.sub(b"", data.replace(b"\t", b" "))


def absolute_indices(data: bytes, path: str) -> bytes | None:
    """``data`` with every relative face index made absolute, or None if it has none.

    Raises
    ------
    InputError
        An index 0, or a relative index reaching before the first vertex;
        the message gives the line number.
    """
    if not _NEEDS_REWRITE.search(data):
        return None
    counts = [0, 0, 0]
    lines = data.split(b"\n")
    for number, line in enumerate(lines, start=1):
        words = line.split()
        if not words:
            continue
        kind = _KINDS.get(words[0])
        if kind is not None:
            counts[kind] += 1
        elif words[0] == b"f":
            lines[number - 1] = b"f " + b" ".join(_corner(w, counts, number, path) for w in words[1:])
    return b"\n".join(lines)


def _corner(word: bytes, counts: list[int], number: int, path: str) -> bytes:
    parts = word.split(b"/")
    out: list[bytes] = []
    for kind, part in enumerate(parts[:3]):
        if not part:
            out.append(part)
            continue
        try:
            index = int(part)
        except ValueError:
            raise InputError(f"line {number}: face index '{part.decode('latin-1')}' is not a number",
                             path=path) from None
        if index == 0:
            raise InputError(f"line {number}: face index 0 (OBJ indices start at 1; -1 is the last vertex above)",
                             path=path)
        if index < 0:
            index += counts[kind] + 1
            if index < 1:
                raise InputError(f"line {number}: relative face index {part.decode()} reaches before the first "
                                 "vertex", path=path)
        out.append(str(index).encode())
    return b"/".join(out)
