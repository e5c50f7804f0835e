"""Damaged and unusual version-2 runtime files (docs/FORMAT.md section 11) through every reader.

The conformance set's ``corrupt/`` files are all version 1; these cases are edits of
``stress_dyadic`` (header keys, the four stress arrays; CRC recomputed) written to a
temporary folder. Each reader must reject exactly the cases the Python reference rejects,
and name an unknown feature or criterion in its message. Readers whose tools are missing
are skipped, as in the other engine tests.
"""

from __future__ import annotations

import json
import os
import struct
import subprocess
import zlib

import pytest
from engine_support import CONFORMANCE, JS_DRIVER, NODE, REPO, require_tool
from godot_harness import GodotProject

from fracture_cli.errors import InputError
from fracture_cli.runtime.format import load_runtime

BASE = os.path.join(CONFORMANCE, "stress_dyadic")


def _edit_header(header: dict, **keys) -> dict:
    out = json.loads(json.dumps(header))
    for key, value in keys.items():
        if value is None:
            out.pop(key, None)
        else:
            out[key] = value
    return out


def _cases(header: dict, binary: bytes) -> list[tuple[str, dict, bytes, str]]:
    """(name, header, binary, expected message fragment or "" for a file that loads)."""

    def poke(array: str, index: int, fmt: str, value) -> bytes:
        out = bytearray(binary)
        at = header["arrays"][array]["byte_offset"] + 4 * index
        out[at: at + 4] = struct.pack("<" + fmt, value)
        return bytes(out)

    def counts(**change) -> dict:
        out = {k: v for k, v in header["counts"].items() if change.get(k, 0) is not None}
        out.update({k: v for k, v in change.items() if v is not None})
        return _edit_header(header, counts=out)

    def without_array(name: str) -> dict:
        return _edit_header(header, arrays={k: v for k, v in header["arrays"].items() if k != name})

    def dtype(name: str, value: str) -> dict:
        arrays = json.loads(json.dumps(header["arrays"]))
        arrays[name]["dtype"] = value
        return _edit_header(header, arrays=arrays)

    ptr = struct.unpack_from("<4i", binary, header["arrays"]["site_bonds_ptr"]["byte_offset"])
    first_of_site_1 = struct.unpack_from("<i", binary, header["arrays"]["site_bonds"]["byte_offset"] + 4 * ptr[1])[0]
    h = header
    return [
        ("ok", h, binary, ""),
        ("feature_unknown", _edit_header(h, features=["stress", "teleport"]), binary, "'teleport'"),  # no reader has it
        ("features_empty", _edit_header(h, features=[]), binary, "no features"),
        ("features_missing", _edit_header(h, features=None), binary, "no features"),
        ("features_not_list", _edit_header(h, features="stress"), binary, "features"),
        ("features_not_strings", _edit_header(h, features=["stress", 3]), binary, "features"),
        ("criterion_unknown", _edit_header(h, criterion="rankine"), binary, "'rankine'"),
        ("criterion_not_string", _edit_header(h, criterion=1), binary, "criterion"),
        ("criterion_missing", _edit_header(h, criterion=None), binary, "stress"),  # "modes" with the stress arrays
        ("criterion_modes", _edit_header(h, criterion="modes"), binary, "stress"),
        ("count_site_bonds_wrong", counts(site_bonds=8), binary, "site_bonds"),
        ("count_site_bonds_missing", counts(site_bonds=None), binary, "site_bonds"),
        ("array_strength_missing", without_array("bond_strength"), binary, "bond_strength"),
        ("gain_dtype", dtype("site_bond_gain", "int32"), binary, "site_bond_gain"),
        ("ptr_start", h, poke("site_bonds_ptr", 0, "i", 1), "site_bonds_ptr"),
        ("ptr_end", h, poke("site_bonds_ptr", 3, "i", 8), "site_bonds_ptr"),
        ("ptr_decreasing", h, poke("site_bonds_ptr", 1, "i", 10), "site_bonds_ptr"),
        ("ptr_negative", h, poke("site_bonds_ptr", 1, "i", -1), "site_bonds_ptr"),
        ("bond_out_of_range", h, poke("site_bonds", 8, "i", 4), "site_bonds"),
        ("bond_negative", h, poke("site_bonds", 0, "i", -1), "site_bonds"),
        ("bond_not_ascending", h, poke("site_bonds", ptr[1] + 1, "i", first_of_site_1), "ascending"),
        ("gain_nan", h, poke("site_bond_gain", 4, "f", float("nan")), "site_bond_gain"),
        ("strength_inf", h, poke("bond_strength", 1, "f", float("inf")), "bond_strength"),
        ("strength_negative", h, poke("bond_strength", 2, "f", -0.5), "bond_strength"),
        ("strength_minus_zero", h, poke("bond_strength", 2, "f", -0.0), ""),
        ("version_1_ignores_v2_keys", _edit_header(h, version=1, features=["levels"], criterion="rankine"), binary,
         ""),
        ("version_3", _edit_header(h, version=3), binary, "version"),
    ]


@pytest.fixture(scope="module")
def cases(tmp_path_factory) -> list[dict]:
    """The cases written to a folder: name, header and binary paths, expected message fragment ("" = loads)."""
    folder = tmp_path_factory.mktemp("stress_files")
    with open(BASE + ".fracture.json", encoding="utf-8") as fh:
        header = json.load(fh)
    with open(BASE + ".fracture.bin", "rb") as fh:
        binary = fh.read()
    out = []
    for name, h, b, message in _cases(header, binary):
        h = json.loads(json.dumps(h))
        h["buffer"] = {"uri": f"{name}.fracture.bin", "byte_length": len(b), "crc32": zlib.crc32(b)}
        paths = (str(folder / f"{name}.fracture.json"), str(folder / f"{name}.fracture.bin"))
        with open(paths[0], "w", encoding="utf-8") as fh:
            json.dump(h, fh, indent=1)
        with open(paths[1], "wb") as fh:
            fh.write(b)
        out.append({"name": name, "header": paths[0], "binary": paths[1], "message": message})
    return out


def _check(cases: list[dict], outcome) -> None:
    """``outcome(case)`` is None (loaded) or the load error's message; compare with the expectations."""
    problems = []
    for case in cases:
        message = outcome(case)
        if case["message"] == "" and message is not None:
            problems.append(f"{case['name']}: rejected ({message})")
        elif case["message"] != "" and (message is None or case["message"] not in message):
            problems.append(f"{case['name']}: expected an error naming {case['message']!r}, got {message!r}")
    assert not problems, problems


def test_python_reference_on_stress_files(cases):
    def outcome(case):
        try:
            load_runtime(case["header"])
        except InputError as exc:
            return str(exc)
        return None

    _check(cases, outcome)


def _driver_outcome(command: list[str]):
    def outcome(case):
        result = subprocess.run([*command(case["header"], case["binary"])], input="", capture_output=True, text=True,
                                timeout=120, check=False)
        if result.returncode == 0:
            return None
        assert result.returncode == 2 and result.stdout.startswith("load-error "), result.stdout + result.stderr
        return result.stdout[len("load-error "):].strip()

    return outcome


def test_c_reader_on_stress_files(cases, tmp_path):
    compiler = require_tool("cc", "gcc (build-essential)")
    exe = str(tmp_path / "fracture_check")
    c_dir = os.path.join(REPO, "engines", "c")
    sources = [os.path.join(c_dir, "fracture_runtime.c"), os.path.join(c_dir, "tools", "fracture_check.c")]
    subprocess.run([compiler, "-std=c99", "-O1", *sources, "-o", exe, "-lm"], check=True, capture_output=True)
    _check(cases, _driver_outcome(lambda h, b: [exe, h, b]))


def test_csharp_reader_on_stress_files(cases, tmp_path):
    mcs = require_tool("mcs", "mono-mcs")
    mono = require_tool("mono", "mono-runtime")
    exe = str(tmp_path / "FractureCheck.exe")
    cs_dir = os.path.join(REPO, "engines", "csharp")
    subprocess.run([mcs, "-langversion:7.2", "-warnaserror", "-checked-", "-out:" + exe,
                    os.path.join(cs_dir, "FractureRuntime.cs"), os.path.join(cs_dir, "tools", "FractureCheck.cs")],
                   check=True, capture_output=True)
    _check(cases, _driver_outcome(lambda h, b: [mono, exe, h, b]))


def test_js_reader_on_stress_files(cases):
    if NODE is None:
        pytest.skip("node (Node.js) is not installed")
    _check(cases, _driver_outcome(lambda h, b: [NODE, JS_DRIVER, h, b]))


def test_gdscript_reader_on_stress_files(cases, tmp_path):
    project = GodotProject(tmp_path / "project")
    jobs = "".join(f"{c['name']}\t{c['header']}\t{c['binary']}\t-\t\n" for c in cases)
    (tmp_path / "jobs.txt").write_text(jobs)
    with open(os.path.join(REPO, "engines", "godot", "tests", "fracture_check.gd"), encoding="utf-8") as fh:
        run = project.run_script(fh.read(), str(tmp_path / "jobs.txt"), name="fracture_check.gd")
    output: dict[str, list[str]] = {}
    current = None
    for line in run.stdout.splitlines():
        if line.startswith("job "):
            current = output.setdefault(line[4:], [])
        elif line == "end":
            current = None
        elif current is not None:
            current.append(line)

    def outcome(case):
        lines = output[case["name"]]
        return lines[0][len("load-error "):] if lines and lines[0].startswith("load-error ") else None

    _check(cases, outcome)
