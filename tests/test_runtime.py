"""Runtime precomputation, the projection file and impact projection (ALGORITHM.md section 4)."""

from __future__ import annotations

import json
import math
import os
import re
import struct
import subprocess
import sys

import numpy as np
import pytest

from fracture_cli.errors import ImpactArgumentError, InputError, RuntimeFileError
from fracture_cli.runtime.format import RuntimeData, encode, load_runtime, write_runtime
from fracture_cli.runtime.impact import _SpanningForest, components, project_impact
from fracture_cli.stages.runtime import RuntimeOptions, runtime
from fracture_cli.testing import grid_tetmesh
from fracture_cli.types import Modes, Normalization, Pieces, TetMesh

REPO = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
FORMAT_DOC = os.path.join(REPO, "docs", "FORMAT.md")


# ---------------------------------------------------------------- fixtures


def slab_bar(shape=(6, 2, 2), k=4, d=1, scale=1.0, center=(0.0, 0.0, 0.0)):
    """A voxel bar whose pieces are unit slabs along x and whose modes are M-orthonormal steps."""
    grid = grid_tetmesh(shape)
    norm = Normalization.from_points(grid.vertices)
    tet_mesh = TetMesh(vertices=norm.to_normalized(grid.vertices), tets=grid.tets,
                       normalization=Normalization(center=np.asarray(center, dtype=float), scale=scale))
    slab = np.floor(grid.tet_centroids[:, 0]).astype(np.int64)
    p = shape[0]
    vol = tet_mesh.tet_volumes
    basis = [np.ones(len(vol))]
    for j in range(k):
        f = (slab > j % (p - 1)).astype(float) if d == 1 else (slab > j // 3).astype(float)
        for b in basis:
            f = f - (b @ (vol * f)) / (b @ (vol * b)) * b
        basis.append(f / np.sqrt(f @ (vol * f)))
    scalar = np.stack(basis[1:])  # (k, t)
    if d == 1:
        U = scalar[:, :, None]
    else:  # scalar steps times a direction per mode: x, y, z, x, ...
        U = scalar[:, :, None] * np.eye(3)[np.arange(k) % 3][:, None, :]
    W = np.stack([[U[i, slab == j].mean(axis=0) for j in range(p)] for i in range(k)])
    modes = Modes(U=U, labels=np.zeros((k, len(vol)), np.int32), cut=np.zeros((k, 1), bool),
                  piece_counts=np.full(k, 2, np.int32), energies=np.ones(k), iterations=np.ones(k, np.int32))
    edges = np.stack([np.arange(p - 1), np.arange(1, p)], axis=1).astype(np.int32)
    area = shape[1] * shape[2] / norm.scale ** 2
    pieces = Pieces(tet_piece=slab.astype(np.int32), W=W, volumes=np.bincount(slab, weights=vol),
                    centroids=np.zeros((p, 3)), edges=edges, edge_areas=np.full(p - 1, area),
                    edge_centroids=np.zeros((p - 1, 3)), edge_normals=np.tile([1.0, 0.0, 0.0], (p - 1, 1)))
    return tet_mesh, modes, pieces


@pytest.fixture(scope="module")
def bar_data():
    return runtime(*slab_bar(k=5), RuntimeOptions(radius=0.05, threshold=0.5))


@pytest.fixture(scope="module")
def bar_data_3d():
    return runtime(*slab_bar(k=6, d=3), RuntimeOptions(radius=0.05, threshold=0.5))


def random_hits(data, count, seed):
    rng = np.random.default_rng(seed)
    sites = data.sites.astype(float)
    points = sites[rng.integers(0, len(sites), count)] + rng.normal(scale=0.05, size=(count, 3))
    impulses = rng.normal(size=(count, 3)) * rng.uniform(0.2, 3.0, size=(count, 1))
    return points, impulses


# ---------------------------------------------------------------- worked example in docs/FORMAT.md


def _doc_block(marker: str) -> str:
    text = open(FORMAT_DOC, encoding="utf-8").read()
    match = re.search(re.escape(f"<!-- {marker} -->") + r"\s*```[a-z]*\n(.*?)```", text, re.S)
    assert match, f"docs/FORMAT.md has no block after <!-- {marker} -->"
    return match.group(1)


def _example():
    ex = json.loads(_doc_block("example-data"))
    data = RuntimeData(sites=np.array(ex["sites"], np.float32), B=np.array(ex["B"], np.float32),
                       W=np.array(ex["W"], np.float32), edges=np.array(ex["edges"], np.int32),
                       edge_areas=np.array(ex["edge_areas"], np.float32),
                       fragment_names=tuple(ex["fragment_names"]), default_threshold=ex["default_threshold"],
                       radius=ex["impact_radius"])
    return ex, data


def test_worked_example_results_match_the_doc():
    ex, data = _example()
    for case in ex["cases"]:
        result = project_impact(data, case["point"], case["impulse"], case["threshold"])
        assert result.site == case["site"]
        np.testing.assert_allclose(result.alpha, case["alpha"])
        np.testing.assert_allclose(result.displacement[:, 0], case["displacement"])
        assert result.broken.tolist() == case["broken"]
        assert result.groups.tolist() == case["groups"]


def test_worked_example_bytes_match_the_doc(tmp_path):
    _, data = _example()
    header, binary = encode(data, "example.fracture.bin")
    assert header.decode("ascii") == _doc_block("example-header")
    dump = "".join(f"{i:04x}: " + " ".join(f"{b:02x}" for b in binary[i:i + 16]) + "\n"
                   for i in range(0, len(binary), 16))
    assert dump == _doc_block("example-bin")
    json_path, _ = write_runtime(data, tmp_path / "example.fracture.json")
    for case in json.loads(_doc_block("example-data"))["cases"]:
        assert struct_reader_groups(json_path, case["point"], case["impulse"], case["threshold"]) == case["groups"]


# ---------------------------------------------------------------- a reader written from docs/FORMAT.md only


def struct_reader_groups(json_path, point, impulse, threshold=None):
    """Plain-Python reader following docs/FORMAT.md sections 1, 2 and 4 (no numpy)."""
    header = json.loads(open(json_path, encoding="utf-8").read())
    assert header["format"] == "fracture-modes-runtime" and header["version"] == 1
    raw = open(os.path.join(os.path.dirname(json_path), header["buffer"]["uri"]), "rb").read()
    assert len(raw) == header["buffer"]["byte_length"]

    def array(name):
        entry = header["arrays"][name]
        count = entry["byte_length"] // 4
        code = {"float32": "f", "int32": "i"}[entry["dtype"]]
        return list(struct.unpack_from(f"<{count}{code}", raw, entry["byte_offset"])), entry["shape"]

    sites, (s, _) = array("sites")
    B, (_, k, d) = array("B")
    W, (_, p, _) = array("W")
    edges, (e, _) = array("edges")
    T = header["default_threshold"] if threshold is None else threshold
    x = point
    best, v = None, 0
    for i in range(s):
        dist = sum((sites[3 * i + c] - x[c]) ** 2 for c in range(3))
        if best is None or dist < best:
            best, v = dist, i
    if d == 1:
        norm = math.sqrt(sum(c * c for c in impulse))
        alpha = [B[v * k + i] * norm for i in range(k)]
    else:
        alpha = [sum(B[(v * k + i) * 3 + c] * impulse[c] for c in range(3)) for i in range(k)]
    disp = [[sum(alpha[i] * W[(i * p + j) * d + c] for i in range(k)) for c in range(d)] for j in range(p)]
    parent = list(range(p))

    def find(a):
        while parent[a] != a:
            a = parent[a]
        return a

    for m in range(e):
        P, Q = edges[2 * m], edges[2 * m + 1]
        if sum((disp[P][c] - disp[Q][c]) ** 2 for c in range(d)) > T * T:
            continue  # broken
        rp, rq = find(P), find(Q)
        if rp != rq:
            parent[max(rp, rq)] = min(rp, rq)
    return [find(j) for j in range(p)]


@pytest.mark.parametrize("fixture", ["bar_data", "bar_data_3d"])
def test_struct_reader_agrees_with_project_impact(fixture, request, tmp_path):
    data = request.getfixturevalue(fixture)
    json_path, _ = write_runtime(data, tmp_path / "bar.fracture.json")
    loaded = load_runtime(json_path)
    points, impulses = random_hits(data, 60, seed=3)
    distinct = set()
    for point, impulse in zip(points, impulses):
        expected = struct_reader_groups(json_path, point.tolist(), impulse.tolist())
        got = project_impact(loaded, point, impulse).groups.tolist()
        assert got == expected
        distinct.add(tuple(got))
    assert len(distinct) > 2  # the hits exercise real breaks, not only "nothing breaks"


# ---------------------------------------------------------------- properties of the projection


def test_groups_depend_only_on_impulse_over_threshold(bar_data_3d, bar_data):
    for data in (bar_data, bar_data_3d):
        points, impulses = random_hits(data, 40, seed=5)
        for point, impulse in zip(points, impulses):
            for T in (0.1, 0.5, 2.0):
                a = project_impact(data, point, impulse, T)
                b = project_impact(data, point, 2 * impulse, 2 * T)
                assert a.groups.tolist() == b.groups.tolist()
                np.testing.assert_allclose(b.displacement, 2 * a.displacement, rtol=1e-12, atol=1e-12)


def test_zero_impulse_breaks_nothing(bar_data):
    for T in (0.0, 0.5):
        result = project_impact(bar_data, bar_data.sites[3], (0.0, 0.0, 0.0), T)
        assert not result.broken.any()
        assert result.groups.tolist() == [0] * bar_data.p


def test_hits_at_different_places_break_differently(bar_data):
    lo, hi = bar_data.sites.min(axis=0), bar_data.sites.max(axis=0)
    mid = (lo + hi) / 2
    left = project_impact(bar_data, (lo[0], mid[1], hi[2]), (0, 0, -2.0))
    right = project_impact(bar_data, (hi[0], mid[1], hi[2]), (0, 0, -2.0))
    assert left.groups.tolist() != right.groups.tolist()
    assert left.groups[0] != left.groups[1] and right.groups[-1] != right.groups[-2]
    assert right.groups[0] == right.groups[1] and left.groups[-1] == left.groups[-2]


def test_components_match_a_reference_union_find():
    rng = np.random.default_rng(7)
    for _ in range(300):
        p = int(rng.integers(1, 30))
        pairs = np.unique(np.sort(rng.integers(0, p, (int(rng.integers(0, 3 * p + 1)), 2)), axis=1), axis=0)
        pairs = pairs[pairs[:, 0] < pairs[:, 1]].astype(np.int64)
        forest = _SpanningForest(p, pairs[:, 0], pairs[:, 1])
        for _ in range(4):
            broken = rng.random(len(pairs)) < rng.random()
            parent = list(range(p))

            def find(a, parent=parent):
                while parent[a] != a:
                    a = parent[a]
                return a

            for a, b in pairs[~broken]:
                ra, rb = find(a), find(b)
                parent[max(ra, rb)] = min(ra, rb)
            expected = [find(j) for j in range(p)]
            assert forest.labels(broken).tolist() == expected
            assert components(p, pairs[~broken, 0], pairs[~broken, 1]).tolist() == expected


def test_impact_module_imports_numpy_only():
    code = ("import sys, fracture_cli.runtime.impact, fracture_cli.runtime.format; "
            "bad = sorted(m for m in sys.modules if m.split('.')[0] in ('scipy', 'trimesh', 'manifold3d', 'open3d')"
            " or m.startswith('fracture_cli.stages') or m == 'fracture_cli.types'); print(bad)")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True, cwd=REPO)
    assert out.stdout.strip() == "[]"


@pytest.mark.parametrize("point, impulse, threshold", [
    ((0, 0), (1, 0, 0), None),
    ((0, 0, 0), (1, 0, float("nan")), None),
    ((0, 0, 0), (1, 0, float("inf")), None),
    ((float("inf"), 0, 0), (1, 0, 0), None),
    ((0, 0, 0), (1, 0, 0), -1.0),
    ((0, 0, 0), (1, 0, 0), float("nan")),
    ((0, 0, 0), (1, 0, 0), float("-inf")),
    ((0, 0, 0), (1, 0, 0), "hard"),
])
def test_bad_arguments_are_the_readers_own_value_error(bar_data, point, impulse, threshold):
    with pytest.raises(ImpactArgumentError) as info:
        project_impact(bar_data, point, impulse, threshold)
    assert isinstance(info.value, ValueError) and isinstance(info.value, InputError)


@pytest.mark.parametrize("fixture", ["bar_data", "bar_data_3d"])
def test_projection_is_scale_invariant_down_to_subnormal_and_up_to_overflow(fixture, request):
    """Only impulse / threshold matters, for every magnitude a double can hold (FORMAT.md section 4)."""
    data = request.getfixturevalue(fixture)
    points, impulses = random_hits(data, 25, seed=11)
    seen = set()
    for point, impulse in zip(points, impulses):
        for T in (0.1, 0.5, 2.0):
            reference = project_impact(data, point, impulse, T)
            seen.add(tuple(reference.groups.tolist()))
            for scale in (1e-300, 1e-170, 1e-100, 1e100, 1e155, 1e200, 1e300):
                scaled = project_impact(data, point, impulse * scale, T * scale)
                assert scaled.groups.tolist() == reference.groups.tolist(), (scale, T)
                assert scaled.broken.tolist() == reference.broken.tolist()
                np.testing.assert_allclose(scaled.displacement / scale, reference.displacement, rtol=1e-12)
    assert len(seen) > 2


def test_threshold_limits(bar_data_3d):
    data = bar_data_3d
    point = data.sites[0]
    everything = project_impact(data, point, (0.3, -1.0, 0.2), 0.0)
    assert everything.broken.sum() == np.count_nonzero(
        np.linalg.norm(everything.displacement[data.edges[:, 0]] - everything.displacement[data.edges[:, 1]], axis=1))
    assert everything.broken.any()
    # T / m underflows to 0: every nonzero jump breaks, like T = 0.
    tiny = project_impact(data, point, (0.3e300, -1.0e300, 0.2e300), 1e-300)
    assert tiny.broken.tolist() == everything.broken.tolist()
    # T / m overflows to inf, or T is inf: nothing breaks.
    for impulse, T in (((0.3e-300, -1e-300, 0.2e-300), 1e300), ((1e300, 1e300, -1e300), float("inf"))):
        result = project_impact(data, point, impulse, T)
        assert not result.broken.any() and result.groups.tolist() == [0] * data.p
    # A zero impulse breaks nothing, even with T = 0.
    zero = project_impact(data, point, (0.0, -0.0, 0.0), 0.0)
    assert not zero.broken.any() and not zero.displacement.any()


# ---------------------------------------------------------------- the precomputation stage


def test_stage_shapes_units_and_scale_invariance():
    small = runtime(*slab_bar(k=4), RuntimeOptions())
    big = runtime(*slab_bar(k=4, scale=1000.0, center=(5.0, -2.0, 7.0)), RuntimeOptions())
    tet_mesh = slab_bar(k=4)[0]
    s = len(tet_mesh.boundary_vertices)
    assert small.B.shape == (s, 4, 1) and small.W.shape == (4, 6, 1) and small.edges.shape == (5, 2)
    # Same shape at another size and place: same B and W, sites and areas follow the asset's units.
    np.testing.assert_allclose(big.B, small.B, rtol=1e-5, atol=1e-6)
    np.testing.assert_allclose(big.W, small.W, rtol=1e-6)
    np.testing.assert_allclose(big.sites, small.sites * 1000 + np.array([5.0, -2.0, 7.0]), rtol=1e-6, atol=1e-3)
    np.testing.assert_allclose(big.edge_areas, small.edge_areas * 1e6, rtol=1e-6)
    expected = np.diag([1000.0, 1000.0, 1000.0, 1.0])
    expected[:3, 3] = (5.0, -2.0, 7.0)
    np.testing.assert_array_equal(big.transform, expected)


def test_B_is_the_diffused_mode_average():
    tet_mesh, modes, pieces = slab_bar(k=3)
    tiny = runtime(tet_mesh, modes, pieces, RuntimeOptions(radius=1e-4))
    # As the radius shrinks the unit-mass blob concentrates on the site's tets: B -> local mode value.
    vol = tet_mesh.tet_volumes
    scale = np.sqrt(vol.sum())
    C = tet_mesh.tet_from_vertex.tocsc()
    for row, v in enumerate(tet_mesh.boundary_vertices[:10]):
        weights = np.asarray(C[:, v].todense()).ravel() * vol
        local = (modes.U[:, :, 0] * weights).sum(axis=1) / weights.sum() * scale
        np.testing.assert_allclose(tiny.B[row, :, 0], local, rtol=1e-3, atol=1e-3)
    wide = runtime(tet_mesh, modes, pieces, RuntimeOptions(radius=10.0))
    # A huge radius spreads the impulse evenly: orthogonal to the constant, so B -> 0.
    assert np.abs(wide.B).max() < 0.02 * np.abs(tiny.B).max()


def test_fragment_order_and_missing_pieces():
    tet_mesh, modes, pieces = slab_bar(k=4)
    full = runtime(tet_mesh, modes, pieces)
    order = [3, 0, 1, 5]  # piece of each fragment; pieces 2 and 4 give no fragment
    sub = runtime(tet_mesh, modes, pieces, fragment_pieces=order)
    np.testing.assert_array_equal(sub.W, full.W[:, order])
    # piece edges (0,1) -> fragments (1,2); (3,4),(4,5),(1,2),(2,3) touch a missing piece.
    assert sub.edges.tolist() == [[1, 2]]
    assert sub.fragment_names == ("fragment_000", "fragment_001", "fragment_002", "fragment_003")


# ---------------------------------------------------------------- the file


def test_write_is_deterministic_and_round_trips(bar_data, tmp_path):
    (tmp_path / "a").mkdir()
    (tmp_path / "b").mkdir()
    a, a_bin = write_runtime(bar_data, tmp_path / "a" / "x.fracture.json")
    b, b_bin = write_runtime(bar_data, tmp_path / "b" / "x.fracture.json")
    assert a.read_bytes() == b.read_bytes() and a_bin.read_bytes() == b_bin.read_bytes()
    assert a_bin.name == "x.fracture.bin"
    assert str(tmp_path) not in a.read_text()
    assert sorted(os.listdir(tmp_path / "a")) == ["x.fracture.bin", "x.fracture.json"]  # no temp files left
    header = json.loads(a.read_text())
    for entry in header["arrays"].values():
        assert entry["byte_offset"] % 16 == 0
    loaded = load_runtime(a)
    for name in ("sites", "B", "W", "edges", "edge_areas"):
        np.testing.assert_array_equal(getattr(loaded, name), getattr(bar_data, name))
    assert loaded.fragment_names == bar_data.fragment_names
    assert loaded.default_threshold == bar_data.default_threshold and loaded.radius == bar_data.radius
    np.testing.assert_array_equal(loaded.transform, bar_data.transform)


def _break(path, edit):
    header = json.loads(path.read_text())
    edit(header)
    path.write_text(json.dumps(header))


@pytest.mark.parametrize("damage, message", [
    ("missing", "not found"),
    ("missing_bin", "not found next to the header"),
    ("truncated", "truncated"),
    ("not_json", "not a JSON"),
    ("format", "not a fracture runtime file"),
    ("version", "version 99 is not supported"),
    ("shape", "do not agree"),
    ("counts", "do not match"),
    ("crc", "crc32"),
    ("no_arrays", "missing or has a malformed entry"),
])
def test_load_reports_damaged_files(bar_data, tmp_path, damage, message):
    json_path, bin_path = write_runtime(bar_data, tmp_path / "x.fracture.json")
    if damage == "missing":
        json_path = tmp_path / "nope.fracture.json"
    elif damage == "missing_bin":
        bin_path.unlink()
    elif damage == "truncated":
        bin_path.write_bytes(bin_path.read_bytes()[:-20])
    elif damage == "not_json":
        json_path.write_text("{oops")
    elif damage == "format":
        _break(json_path, lambda h: h.update(format="something-else"))
    elif damage == "version":
        _break(json_path, lambda h: h.update(version=99))
    elif damage == "shape":
        _break(json_path, lambda h: h["arrays"]["W"].update(shape=[1, 2, 3]))
    elif damage == "counts":
        _break(json_path, lambda h: h["counts"].update(fragments=99))
    elif damage == "crc":
        raw = bytearray(bin_path.read_bytes())
        raw[0] ^= 0xFF
        bin_path.write_bytes(bytes(raw))
    elif damage == "no_arrays":
        _break(json_path, lambda h: h.pop("arrays"))
    with pytest.raises(RuntimeFileError, match=message):
        load_runtime(json_path)


_JUNK = [None, True, -1, 0, 3, 2**63, 2**64 + 5, 10**30, 1.5, float("inf"), float("nan"), "x", "..", "a\u0000b",
         [], [2**40, 2**40], [-1, 3], [1e300], {}, {"a": 1}]


def _mutations(header):
    """(path, junk) for every value in the header (recursively) and every junk value."""
    def walk(node, path):
        if isinstance(node, dict):
            for key, value in node.items():
                yield from walk(value, path + (key,))
        elif isinstance(node, list) and node and not isinstance(node[0], (int, float)):
            for i, value in enumerate(node):
                yield from walk(value, path + (i,))
        if path:
            yield path

    for path in walk(header, ()):
        for junk in _JUNK:
            yield path, junk


def test_tampered_headers_raise_only_the_readers_format_error(bar_data, tmp_path):
    """Every header value replaced by junk (huge, negative, wrong type, inf): RuntimeFileError or a valid load."""
    json_path, _ = write_runtime(bar_data, tmp_path / "x.fracture.json")
    original = json.loads(json_path.read_text())
    tried = 0
    for path, junk in _mutations(original):
        header = json.loads(json.dumps(original))
        node = header
        for key in path[:-1]:
            node = node[key]
        node[path[-1]] = junk
        json_path.write_text(json.dumps(header))
        tried += 1
        try:
            loaded = load_runtime(json_path)
        except RuntimeFileError:
            continue
        project_impact(loaded, (0.0, 0.0, 0.0), (1.0, 0.0, 0.0))  # whatever loads must also be usable
    assert tried > 300


# ---------------------------------------------------------------- regrouped GLB


def test_write_groups_glb(tmp_path):
    trimesh = pytest.importorskip("trimesh")
    from fracture_cli.io.gltf import Primitive, glb_bytes
    from fracture_cli.io.regroup import write_groups_glb
    from fracture_cli.types import Material

    meshes = []
    for j in range(3):
        box = trimesh.creation.box(extents=(1, 1, 1))
        box.apply_translation((2.0 * j, 0, 0))
        half = len(box.faces) // 2
        prims = [Primitive(box.vertices, box.vertex_normals, None, box.faces[:half], 0),
                 Primitive(box.vertices, box.vertex_normals, None, box.faces[half:], 1)]
        meshes.append((f"fragment_{j:03d}", prims))
    source = tmp_path / "frags.glb"
    source.write_bytes(glb_bytes(meshes, (Material("outer"), Material("interior"))))
    out = tmp_path / "broken.glb"
    names = write_groups_glb(source, np.array([0, 0, 2], np.int32), out)
    assert names == ["group_000", "group_002"]
    scene = trimesh.load(out, force="scene")
    bounds = {}
    for node in scene.graph.nodes_geometry:
        transform, geometry = scene.graph[node]
        bounds.setdefault(node, []).append(scene.geometry[geometry].bounds)
    x_extent = {}
    for node, b in bounds.items():
        group = "group_000" if "group_000" in node else "group_002"
        lo = min(bb[0][0] for bb in b)
        hi = max(bb[1][0] for bb in b)
        x_extent[group] = (min(lo, x_extent.get(group, (lo, hi))[0]), max(hi, x_extent.get(group, (lo, hi))[1]))
    assert x_extent["group_000"] == pytest.approx((-0.5, 2.5))
    assert x_extent["group_002"] == pytest.approx((3.5, 4.5))
    doc = json.loads(out.read_bytes()[20:20 + struct.unpack_from("<I", out.read_bytes(), 12)[0]])
    assert [n["name"] for n in doc["nodes"]] == ["group_000", "group_002"]
    assert doc["nodes"][0]["extras"]["fragments"] == ["fragment_000", "fragment_001"]
    assert len(doc["meshes"][0]["primitives"]) == 4
    with pytest.raises(InputError, match="missing"):
        write_groups_glb(source, np.zeros(4, np.int32), tmp_path / "x.glb")


# ---------------------------------------------------------------- with the real modes and pieces stages


def test_with_real_modes_and_pieces(tmp_path):
    modes_stage = pytest.importorskip("fracture_cli.stages.modes")
    pieces_stage = pytest.importorskip("fracture_cli.stages.pieces")
    from fracture_cli.testing import two_boxes_with_neck

    tet_mesh = two_boxes_with_neck(3)
    modes = modes_stage.modes(tet_mesh, modes_stage.ModesOptions(num_modes=3))
    pieces = pieces_stage.pieces(tet_mesh, modes)
    data = runtime(tet_mesh, modes, pieces)
    json_path, _ = write_runtime(data, tmp_path / "neck.fracture.json")
    loaded = load_runtime(json_path)
    assert loaded.p == pieces.num_pieces and loaded.k == 3
    points, impulses = random_hits(loaded, 20, seed=11)
    for point, impulse in zip(points, impulses):
        result = project_impact(loaded, point, impulse * 5)
        assert result.groups.tolist() == struct_reader_groups(json_path, point.tolist(), (impulse * 5).tolist())
    assert project_impact(loaded, points[0], (0, 0, 0)).groups.tolist() == [0] * loaded.p
