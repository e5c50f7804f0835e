"""Shared by the engine reader tests: the levels vectors (docs/FORMAT.md section 14.7) in the drivers' protocol.

Every engine driver (C, C#, JavaScript, GDScript) answers, besides the impacts of
engine_support, three more kinds of line on a runtime file with levels:

* ``body <b> <impact>``: a stateless impact on body ``b``'s view, answered as an impact
  (``ok ...`` / ``error ...``, local indices), followed by its ``structure`` line when the
  driver prints those;
* ``object new`` or ``object <health bits...>``: the object state the next hits use
  (``object-error <reason>`` when refused; the previous state stays);
* ``hit <struck> <impact>``: a hit on the piece holding fragment ``struck``::

      piece ok <body> <site> <child_body> <child_site> <split 0/1> b <broken...> c <child broken...>
        p <fragments of each piece, comma-separated...> y <anchored flag of each piece...> h <health bits...>
      piece error <reason> h <health bits...>

  where ``p`` and ``y`` list every piece of the object after the hit (section 14.4 order).

``--children`` prints ``children <hex of each child name...>`` (fragments ``p .. p_all - 1``).
"""

from __future__ import annotations

from engine_support import bits_to_float, compare, hex_names, load_vectors, parse_answer, vector_names

HEALTH_TOLERANCE = 1e-9  # docs/FORMAT.md section 14.7: healths within 1e-9 absolute, everything else equal


def levels_files(features) -> list[str]:
    """The vector files with levels a reader implementing ``features`` runs."""
    return [name for name in vector_names(features) if "levels" in load_vectors(name).get("features", ())]


def _impact_line(prefix: str, impact: dict) -> str:
    bits = impact["bits"]
    return " ".join([prefix, *bits["point"], *bits["impulse"], bits["threshold"] or "-"])


def body_input(vectors: dict) -> str:
    """Driver input for every body's stateless impacts (bodies ``b >= 1``)."""
    return "".join(_impact_line(f"body {body['body']}", impact) + "\n"
                   for body in vectors["bodies"] for impact in body["impacts"])


def sequence_input(vectors: dict) -> str:
    """Driver input for the ``level_sequences``: an ``object`` line, then the hits."""
    lines = []
    for seq in vectors["level_sequences"]:
        lines.append("object new" if seq["start"] is None else "object " + " ".join(seq["start"]))
        lines += [_impact_line(f"hit {h['struck']}", h) for h in seq["hits"]]
    return "\n".join(lines) + "\n"


def check_bodies(vectors: dict, output: str, structure: bool = True) -> list[str]:
    """Every mismatch between a driver's answers to :func:`body_input` and the bodies' impacts."""
    answers: list[list] = []
    for line in output.splitlines():
        if line.startswith(("ok", "error")):
            answers.append([line, None])
        elif line.startswith(("structure", "more")) and answers:  # C, C#: "structure c .. y ..", JS: "more c .. n .."
            tokens, key = line.replace(" n ", " y ").split()[1:], "c"
            sections: dict[str, list[int]] = {}
            for token in tokens:
                if token in ("c", "y", "h"):
                    key = token
                    sections[key] = []
                else:
                    sections[key].append(int(token))
            answers[-1][1] = sections
    impacts = [(body["body"], impact) for body in vectors["bodies"] for impact in body["impacts"]]
    if len(answers) != len(impacts):
        return [f"driver answered {len(answers)} body impacts of {len(impacts)}"]
    problems = []
    for (body, impact), (line, more) in zip(impacts, answers):
        why = compare(impact, parse_answer(line))
        if why is None and structure and impact["expect"] == "ok" and "cracked" in impact:
            if more is None or (more.get("c", []), more.get("y", [])) != (impact["cracked"], impact["anchored"]):
                why = f"cracked/anchored {more}, expected {impact['cracked']}, {impact['anchored']}"
        if why:
            problems.append(f"body {body}: {impact['name']}: {why}")
    return problems


def parse_piece(line: str) -> dict:
    """One ``piece`` line as a dict."""
    tokens = line.split()
    assert tokens[0] == "piece", line
    h = tokens.index("h")
    health = tokens[h + 1:]
    if tokens[1] == "error":
        return {"expect": "error", "reason": " ".join(tokens[2:h]), "health": health}
    sections: dict[str, list[str]] = {}
    key = "b"
    for token in tokens[7:h]:
        if token in ("b", "c", "p", "y"):
            key = token
            sections[key] = []
        else:
            sections[key].append(token)
    return {"expect": "ok", "body": int(tokens[2]), "site": int(tokens[3]), "child_body": int(tokens[4]),
            "child_site": int(tokens[5]), "split": tokens[6] == "1",
            "broken": [int(t) for t in sections.get("b", [])], "child_broken": [int(t) for t in sections.get("c", [])],
            "pieces": [[int(f) for f in t.split(",")] for t in sections.get("p", [])],
            "anchored": [t == "1" for t in sections.get("y", [])], "health": health}


KEYS = ("body", "site", "child_body", "child_site", "split", "broken", "child_broken", "pieces", "anchored")


def check_sequences(vectors: dict, output: str) -> list[str]:
    """Every mismatch between a driver's answers to :func:`sequence_input` and the ``level_sequences``.

    A refused hit must leave the state bit for bit as the previous answer printed it.
    """
    lines = [line for line in output.splitlines() if line.startswith(("piece", "object-error"))]
    hits = [(seq, h) for seq in vectors["level_sequences"] for h in seq["hits"]]
    if len(lines) != len(hits) or any(not line.startswith("piece") for line in lines):
        return [f"driver answered {len(lines)} hits of {len(hits)}: {output[-2000:]}"]
    problems, previous = [], None
    for (seq, want), line in zip(hits, lines):
        where = f"{seq['name']} / {want['name']}"
        got = parse_piece(line)
        if got["expect"] != want["expect"]:
            problems.append(f"{where}: expected {want['expect']}, got {line[:200]}")
            continue
        if got["expect"] == "ok":
            for key in KEYS:
                if got[key] != want[key]:
                    problems.append(f"{where}: {key}: got {got[key]}, expected {want[key]}")
        health = [bits_to_float(b) for b in got["health"]]
        expected = [bits_to_float(b) for b in want["health"]]
        if len(health) != len(expected) or any(abs(a - b) > HEALTH_TOLERANCE for a, b in zip(health, expected)):
            problems.append(f"{where}: health {health}, expected {expected}")
        if want["expect"] == "error" and want is not seq["hits"][0] and got["health"] != previous:
            problems.append(f"{where}: the refused hit changed the state")
        previous = got["health"]
    return problems


def check_children(header: str, output: str) -> list[str]:
    """The ``children`` line against the header's ``child_names``."""
    import json

    with open(header, encoding="utf-8") as fh:
        names = json.load(fh).get("child_names", [])
    line = next((line for line in output.splitlines() if line.startswith("children")), "children")
    return [] if line.split()[1:] == hex_names(names) else [f"children {line[:200]}, expected {names}"]
