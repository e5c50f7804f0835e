"""The stress criterion (issue 30): P1 elasticity, the bond gains, the runtime test, determinism, a bake."""

from __future__ import annotations

import hashlib
import json
import os
import subprocess
import sys

import numpy as np
import pytest

from fracture_cli.errors import RuntimeFileError
from fracture_cli.geometry.tetgeom import orient_positive
from fracture_cli.runtime.format import RuntimeData, decode, encode, load_runtime, write_runtime
from fracture_cli.runtime.impact import project_impact
from fracture_cli.stages.stress.bonds import bond_faces, split_into_patches
from fracture_cli.stages.stress.fem import elasticity_matrix, lame, normal_traction_coefficients, tet_stress
from fracture_cli.stages.stress.gains import site_bond_tractions
from fracture_cli.stages.stress.stage import round_bits, sparsify
from fracture_cli.types import TetMesh

from conftest import REPO, SAMPLE_ASSETS

E, NU = 2.0, 0.3


def box_mesh(nx=6, ny=3, nz=3, size=(2.0, 1.0, 1.0), jitter=0.0, seed=0) -> TetMesh:
    """A box ``[-sx/2, sx/2] x ...`` of ``nx * ny * nz`` cubes, six tets each (Kuhn), optionally jittered inside."""
    xs, ys, zs = (np.linspace(-s / 2, s / 2, k + 1) for s, k in zip(size, (nx, ny, nz)))
    V = np.stack(np.meshgrid(xs, ys, zs, indexing="ij"), axis=-1).reshape(-1, 3)
    if jitter:
        inner = np.all(np.abs(V) < np.asarray(size) / 2 - 1e-9, axis=1)
        V[inner] += np.random.default_rng(seed).uniform(-jitter, jitter, (int(inner.sum()), 3))

    def vid(i, j, k):
        return (i * (ny + 1) + j) * (nz + 1) + k

    tets = []
    paths = [(0, 1, 2), (0, 2, 1), (1, 0, 2), (1, 2, 0), (2, 0, 1), (2, 1, 0)]
    for i in range(nx):
        for j in range(ny):
            for k in range(nz):
                for path in paths:
                    corner = [i, j, k]
                    chain = [vid(*corner)]
                    for axis in path:
                        corner[axis] += 1
                        chain.append(vid(*corner))
                    tets.append(chain)
    T = orient_positive(V, np.asarray(tets, dtype=np.int64))
    return TetMesh(vertices=V, tets=T)


def mirrored_box(nx=3, ny=3, nz=3) -> TetMesh:
    """The box ``[-1, 1] x [-0.5, 0.5]^2``, exactly mirror-symmetric in x: a half box and its mirror image."""
    half = box_mesh(nx, ny, nz, size=(1.0, 1.0, 1.0))
    V = half.vertices + np.array([0.5, 0.0, 0.0])
    mirror = V * np.array([-1.0, 1.0, 1.0])
    allv = np.concatenate([V, mirror])
    # Weld the shared plane x = 0.
    key = {tuple(np.round(v, 12)): i for i, v in enumerate(allv[: len(V)])}
    remap = np.array([key.get(tuple(np.round(v, 12)), len(V) + i) for i, v in enumerate(mirror)])
    used = np.unique(np.concatenate([np.arange(len(V)), remap]))
    T = np.concatenate([half.tets, remap[half.tets]])
    T = np.searchsorted(used, T)
    return TetMesh(vertices=allv[used], tets=orient_positive(allv[used], T))


def halves(mesh: TetMesh) -> np.ndarray:
    """Fragment of every tet: 0 for x < 0, 1 for x > 0."""
    return (mesh.tet_centroids[:, 0] > 0).astype(np.int64)


def test_patch_test_uniform_tension_gives_the_analytic_stress():
    mesh = box_mesh(jitter=0.05)
    lam, mu = lame(E, NU)
    K, G = elasticity_matrix(mesh.vertices, mesh.tets, lam, mu)
    eps = np.array([[1e-3, 2e-4, 0.0], [2e-4, -3e-4, 1e-4], [0.0, 1e-4, 5e-4]])
    u = mesh.vertices @ eps.T  # linear field: constant strain eps
    sigma = tet_stress(G, mesh.tets, u, lam, mu)
    want = lam * np.trace(eps) * np.eye(3) + 2 * mu * eps
    assert np.allclose(sigma, want[None], rtol=0, atol=1e-12)
    # Patch test: interior vertices feel no force under a linear field.
    force = (K @ u.reshape(-1)).reshape(-1, 3)
    interior = np.setdiff1d(np.arange(mesh.num_vertices), mesh.boundary_vertices)
    assert np.abs(force[interior]).max() < 1e-12
    # The normal-traction functional gives n . sigma n on any face.
    n = np.array([[0.6, 0.0, 0.8]])
    coef = normal_traction_coefficients(G[:1], n, lam, mu)
    assert np.isclose(float((coef[0] * u[mesh.tets[0]]).sum()), float(n[0] @ want @ n[0]), rtol=1e-12)


def test_uniaxial_pull_of_a_free_bar_is_tension_across_its_middle():
    """Pulling a bar's end (+x at x = +1) puts the middle section in tension F/2 / area (inertia relief)."""
    mesh = box_mesh(nx=8, ny=2, nz=2)
    edges = np.array([[0, 1]])
    faces = bond_faces(mesh, halves(mesh), edges)
    end = np.flatnonzero(np.isclose(mesh.vertices[:, 0], 1.0) & (np.abs(mesh.vertices[:, 1:]).max(axis=1) < 1e-9))
    g = site_bond_tractions(mesh, faces, end, radius=1.0, youngs_modulus=E, poisson_ratio=NU)
    assert g.shape == (1, 3, 1)
    assert g[0, 0, 0] == pytest.approx(0.5 / 1.0, rel=0.05)  # area of the section is 1
    assert abs(g[0, 1, 0]) < 1e-2 and abs(g[0, 2, 0]) < 1e-2  # a sideways push pulls (almost) nothing on average


def test_response_is_linear_in_the_impulse():
    mesh = box_mesh(jitter=0.03, seed=2)
    faces = bond_faces(mesh, halves(mesh), np.array([[0, 1]]))
    sites = mesh.boundary_vertices[:20]
    g = site_bond_tractions(mesh, faces, sites, 0.3, E, NU, reach=0.5)
    n1, n2 = np.array([0.3, -1.0, 0.2]), np.array([-0.7, 0.1, 0.4])
    one, two = g[:, :, 0] @ n1, g[:, :, 0] @ n2
    both = g[:, :, 0] @ (2.5 * n1 + n2)
    assert np.allclose(both, 2.5 * one + two, rtol=1e-12, atol=1e-15)
    # E does not change the stress of a free body.
    assert np.allclose(site_bond_tractions(mesh, faces, sites, 0.3, 7 * E, NU, reach=0.5), g, rtol=1e-9, atol=1e-14)


@pytest.mark.parametrize("reach", [0.0, 0.4])
def test_a_symmetric_object_gives_symmetric_loads(reach):
    """The box is mirror-symmetric in x: a hit at (x, y, z) along (a, b, c) loads the middle bond as the
    mirrored hit at (-x, y, z) along (-a, b, c)."""
    mesh = mirrored_box()
    faces = bond_faces(mesh, halves(mesh), np.array([[0, 1]]))
    V = mesh.vertices
    sites = np.asarray(mesh.boundary_vertices)
    mirror = {tuple(np.round(V[v], 9)): v for v in sites.tolist()}
    pairs = [(v, mirror[(round(-V[v, 0], 9) + 0.0, round(V[v, 1], 9), round(V[v, 2], 9))]) for v in sites[:40].tolist()]
    chosen = np.asarray([v for pair in pairs for v in pair])
    g = site_bond_tractions(mesh, faces, chosen, 0.3, E, NU, reach=reach)[:, :, 0]  # (2 * pairs, 3)
    a, b = g[0::2], g[1::2]
    scale = np.abs(g).max()
    assert np.allclose(a[:, 0], -b[:, 0], atol=1e-9 * scale) and np.allclose(a[:, 1:], b[:, 1:], atol=1e-9 * scale)


def test_patches_keep_a_bent_bond_loaded():
    """A sideways push at the end bends the bar: the whole section averages ~0, its patches do not."""
    mesh = box_mesh(nx=8, ny=2, nz=2)
    faces = bond_faces(mesh, halves(mesh), np.array([[0, 1]]))
    patches, patch_bond = split_into_patches(mesh, faces, 2)
    assert len(patch_bond) == 4 and np.all(patch_bond == 0)
    end = np.flatnonzero(np.isclose(mesh.vertices[:, 0], 1.0) & (np.abs(mesh.vertices[:, 1:]).max(axis=1) < 1e-9))
    whole = site_bond_tractions(mesh, faces, end, 1.0, E, NU)[0, 1, 0]
    parts = site_bond_tractions(mesh, patches, end, 1.0, E, NU)[0, 1, :]
    assert abs(whole) < 1e-2 and np.abs(parts).max() > 10 * abs(whole)


def test_rounding_and_sparsify():
    x = np.array([1.0, 1.0 + 2.0 ** -13, -3.14159, 0.0, 1e-300])
    r = round_bits(x, 12)
    assert r[0] == 1.0 and r[1] == 1.0 and r[3] == 0.0 and abs(r[2] + 3.14159) < 3.14159 * 2.0 ** -12
    assert np.array_equal(round_bits(r, 12), r)
    gain = np.zeros((2, 3, 3))
    gain[0, 0] = (1.0, 0.5, 0.01)
    gain[1, 2] = (0.0, 2.0, 2.0)
    ptr, bonds, values = sparsify(gain, np.ones(3), keep=0.05)
    assert ptr.tolist() == [0, 2, 4] and bonds.tolist() == [0, 1, 1, 2]
    ptr, bonds, values = sparsify(gain, np.ones(3), keep=0.0, max_bonds=1)
    assert ptr.tolist() == [0, 1, 2] and bonds.tolist() == [0, 1] and values[1].tolist() == [0.0, 0.0, 2.0]


def stress_file() -> RuntimeData:
    """Three fragments in a row, two sites, criterion stress; dyadic values."""
    return RuntimeData(
        sites=np.array([[0.0, 0.0, 0.0], [2.0, 0.0, 0.0]], dtype=np.float32),
        B=np.ones((2, 1, 1), dtype=np.float32), W=np.zeros((1, 3, 1), dtype=np.float32),
        edges=np.array([[0, 1], [1, 2]], dtype=np.int32), edge_areas=np.array([1.0, 2.0], dtype=np.float32),
        fragment_names=("a", "b", "c"), default_threshold=2.0, criterion="stress",
        stress={"site_bonds_ptr": np.array([0, 2, 3], dtype=np.int32),
                "site_bonds": np.array([0, 1, 1], dtype=np.int32),
                "site_bond_gain": np.array([[1.0, 0.0, 0.0], [0.25, 0.5, 0.0], [-1.0, 0.0, 4.0]], dtype=np.float32),
                "bond_strength": np.array([0.5, 0.25], dtype=np.float32)},
        stress_info={"poisson_ratio": 0.25})


def test_runtime_stress_step_and_scale_invariance():
    data = stress_file()
    # Site 0, impulse (1, 0, 0): bond 0 g = 1 > 2 * 0.5? no (equal holds); bond 1 g = 0.25 > 0.5? no.
    r = project_impact(data, (0.1, 0, 0), (1.0, 0.0, 0.0))
    assert r.broken.tolist() == [False, False] and r.groups.tolist() == [0, 0, 0]
    r = project_impact(data, (0.1, 0, 0), (2.0, 0.0, 0.0))  # t = 1: bond 0: 1 > 0.5 breaks, bond 1: 0.25 > 0.25 holds
    assert r.broken.tolist() == [True, False] and r.groups.tolist() == [0, 1, 1]
    r = project_impact(data, (1.9, 0, 0), (-1.0, 0.0, 1.0))  # site 1: bond 1 g = 1 + 4 = 5 > 2 * 0.25
    assert r.broken.tolist() == [False, True] and r.groups.tolist() == [0, 0, 2]
    r = project_impact(data, (1.9, 0, 0), (1.0, 0.0, 0.0))  # compression: nothing breaks
    assert not r.broken.any()
    for scale in (2.0 ** -600, 3.0, 2.0 ** 600):
        s = project_impact(data, (0.1, 0, 0), (2.0 * scale, 0.0, 0.0), 2.0 * scale)
        assert s.broken.tolist() == [True, False]


def test_writer_versions_and_reader_refuses_unknown_features(tmp_path):
    data = stress_file()
    header, binary = encode(data, "x.fracture.bin")
    parsed = json.loads(header)
    assert parsed["version"] == 2 and parsed["features"] == ["stress"] and parsed["criterion"] == "stress"
    back = decode(header, binary)
    assert back.criterion == "stress" and np.array_equal(back.stress["site_bond_gain"], data.stress["site_bond_gain"])
    plain = RuntimeData(sites=data.sites, B=data.B, W=data.W, edges=data.edges, edge_areas=data.edge_areas,
                        fragment_names=data.fragment_names)
    plain_header = json.loads(encode(plain, "x.fracture.bin")[0])
    assert plain_header["version"] == 1 and "features" not in plain_header and "criterion" not in plain_header
    parsed["features"] = ["stress", "teleport"]
    with pytest.raises(RuntimeFileError, match="needs feature 'teleport'"):
        decode(json.dumps(parsed).encode(), binary)
    parsed["features"] = []
    with pytest.raises(RuntimeFileError, match="lists no features"):
        decode(json.dumps(parsed).encode(), binary)
    parsed["features"], parsed["criterion"] = ["stress"], "damage"
    with pytest.raises(RuntimeFileError, match="criterion 'damage'"):
        decode(json.dumps(parsed).encode(), binary)
    path = tmp_path / "x.fracture.json"
    write_runtime(data, path)
    assert load_runtime(path).criterion == "stress"


DIGEST_SCRIPT = """
import hashlib, sys
sys.path.insert(0, {tests!r})
import fracture_cli  # noqa: F401  (pins, unless FRACTURE_NUMERICS=host)
import numpy as np
from test_stress import box_mesh, halves
from fracture_cli.stages.stress.bonds import bond_faces
from fracture_cli.stages.stress.gains import site_bond_tractions
from fracture_cli.stages.stress.stage import round_bits, sparsify
from threadpoolctl import threadpool_info
mesh = box_mesh(nx=10, ny=5, nz=4, jitter=0.04, seed=4)
part = (mesh.tet_centroids[:, 0] > 0.3).astype(np.int64) + (mesh.tet_centroids[:, 0] > -0.4)
faces = bond_faces(mesh, part, np.array([[0, 1], [1, 2]]))
sites = np.asarray(mesh.boundary_vertices)
raw = site_bond_tractions(mesh, faces, sites, 0.2, 1.0, 0.25, reach=0.3)
ptr, bonds, gain = sparsify(round_bits(raw), np.ones(2), 0.05)
blas = sorted({{i.get("architecture") for i in threadpool_info() if i.get("internal_api") == "openblas"}})
print(hashlib.sha256(gain.astype(np.float32).tobytes() + ptr.tobytes()).hexdigest(),
      hashlib.sha256(raw.tobytes()).hexdigest(), ",".join(map(str, blas)))
"""


def _digests(env: dict) -> list[str]:
    script = DIGEST_SCRIPT.format(tests=os.path.join(REPO, "tests"))
    run = subprocess.run([sys.executable, "-c", script], env={**os.environ, **env}, capture_output=True, text=True,
                         timeout=300, cwd=REPO)
    assert run.returncode == 0, run.stderr
    return run.stdout.split()


def test_stored_gains_are_the_same_bytes_with_other_blas_kernels():
    """Pinned (the bake's way) and with the host's kernels forced to Haswell or Prescott: the rounded gains
    are the same bytes, even where the unrounded solve differs in its last bits."""
    pinned = _digests({"OPENBLAS_CORETYPE": "Haswell"})
    haswell = _digests({"FRACTURE_NUMERICS": "host", "OPENBLAS_CORETYPE": "Haswell"})
    prescott = _digests({"FRACTURE_NUMERICS": "host", "OPENBLAS_CORETYPE": "Prescott"})
    assert haswell[2] != prescott[2], f"could not force two kernels: {haswell[2]} / {prescott[2]}"
    assert pinned[0] == haswell[0] == prescott[0]


@pytest.mark.slow
def test_a_stress_bake_has_the_same_fragments_and_a_version_2_file(tmp_path):
    from fracture_cli.pipeline.bake import bake
    from fracture_cli.pipeline.recipe import load_recipe

    golden = json.load(open(os.path.join(REPO, "tests", "golden", "chair.wood.json")))
    recipe = load_recipe("wood", ("runtime.criterion=stress",))
    result = bake(os.path.join(SAMPLE_ASSETS, "chair.glb"), str(tmp_path), recipe)
    checks = result.report["checks"]
    assert checks["volume_error"] < 1e-6
    with open(tmp_path / "chair.glb", "rb") as fh:
        assert hashlib.sha256(fh.read()).hexdigest() == golden["sha256"]["glb"], "the criterion changed fragments"
    data = load_runtime(tmp_path / "chair.fracture.json")
    assert data.criterion == "stress" and data.version == 2
    assert os.path.getsize(tmp_path / "chair.fracture.bin") < 1_200_000
    site = data.sites[0]
    r = project_impact(data, site, -np.asarray(site, dtype=np.float64), 1e-6)
    assert r.broken.any()


def test_tension_shear_sees_the_shear_of_a_pushed_fragment():
    """A push down on the top of one half, beside the middle fault: the fault is sheared. Its normal
    traction is small; the tension-and-shear load (the default measure) is not, and is linear along w."""
    from fracture_cli.stages.stress.stage import shear_gains

    mesh = box_mesh(nx=8, ny=2, nz=2)
    faces = bond_faces(mesh, halves(mesh), np.array([[0, 1]]))
    V = mesh.vertices
    top = np.flatnonzero(np.isclose(V[:, 2], 0.5) & np.isclose(V[:, 0], 0.25) & np.isclose(V[:, 1], 0.0))
    normal = site_bond_tractions(mesh, faces, top, 0.2, E, NU, reach=0.5)[0, :, 0]
    vector = site_bond_tractions(mesh, faces, top, 0.2, E, NU, reach=0.5, vector=True)
    gains, score = shear_gains(mesh, vector, faces, None, top, 1)
    down = np.array([0.0, 0.0, -1.0])
    assert gains.shape == (1, 3, 1) and score[0, 0] > 0
    assert float(gains[0, :, 0] @ down) > 3 * abs(float(normal @ down))
    inward = -V[top[0]] / np.linalg.norm(V[top[0]])
    assert float(gains[0, :, 0] @ inward) == pytest.approx(score[0, 0], rel=1e-12)


def test_the_atlas_command_gates_a_stress_bake(tmp_path):
    """`fracture atlas` on the chair baked with the stress criterion (the conformance copy): figures, the gate."""
    import shutil

    from click.testing import CliRunner

    from fracture_cli.cli import cli

    src = os.path.join(REPO, "tests", "data", "runtime_conformance", "chair_stress")
    for suffix in (".fracture.json", ".fracture.bin"):
        shutil.copyfile(src + suffix, tmp_path / ("chair_stress" + suffix))
    path = str(tmp_path / "chair_stress.fracture.json")
    ok = CliRunner().invoke(cli, ["atlas", path, "--sites", "40", "--json", "--require", "locality_8x<=0.6"])
    assert ok.exit_code == 0, ok.output
    summary = json.loads(ok.output)
    assert summary["criterion"] == "stress" and summary["hits"]["used"] == 40
    failing = CliRunner().invoke(cli, ["atlas", path, "--sites", "40", "--require", "hit_detached>=0.999"])
    assert failing.exit_code == 1 and "hit_detached" in failing.output
    modes = CliRunner().invoke(cli, ["atlas", path, "--sites", "40", "--criterion", "modes", "--json"])
    assert modes.exit_code == 0 and json.loads(modes.output)["criterion"] == "modes"
