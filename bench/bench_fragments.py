"""Benchmark of pieces, fault smoothing and fragment booleans, and how much smoothing smooths.

    python bench/bench_fragments.py [--quick]

Two tables. (1) Synthetic: the tet mesh is a jittered grid over the input's
bounding box and the pieces are the Voronoi cells of 30 seeded sites (synthetic
modes), so the timings isolate these three stages from the cage and modes
stages. (2) Sample assets through their manifest recipes (repair, cage, tetra,
modes, pieces), smoothed with lambda = 0 and with the recipe's lambda by both
methods.
Fault shape is :func:`fracture_cli.checks.faultshape.fragment_fault_shape`: the
mean dihedral angle of bent edges inside each fault (degrees) and the crease
density (edges bending more than 30 degrees per unit fault area, 1/diagonal);
lower is smoother.
"""

from __future__ import annotations

import os
import sys
import time

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, os.path.dirname(HERE))

from fracture_cli.checks import fragment_invariants  # noqa: E402
from fracture_cli.checks.faultshape import fragment_fault_shape  # noqa: E402
from fracture_cli.geometry.tetgeom import tet_edge_lengths  # noqa: E402
from fracture_cli.stages.fragments import fragments  # noqa: E402
from fracture_cli.stages.pieces import pieces  # noqa: E402
from fracture_cli.stages.smooth import SmoothOptions, smooth  # noqa: E402
from fracture_cli.testing import grid_tetmesh  # noqa: E402
from fracture_cli.types import Material, Modes, Normalization, SurfaceMesh, TetMesh  # noqa: E402

SAMPLE_ASSETS = os.path.join(os.path.dirname(HERE), "sample_assets")
SAMPLE_FILES = ("pillar.glb", "chair.glb", "vase.obj")


def bumpy_sphere(n_theta: int = 125, n_phi: int = 200) -> SurfaceMesh:
    """A closed bumpy sphere with UVs: ``2 * n_phi * (n_theta - 1)`` triangles (~50k by default)."""
    theta = np.linspace(0, np.pi, n_theta + 1)[1:-1]
    phi = np.linspace(0, 2 * np.pi, n_phi, endpoint=False)
    T, P = np.meshgrid(theta, phi, indexing="ij")
    r = 1.0 + 0.08 * np.sin(5 * T) * np.sin(4 * P)
    ring = np.stack([r * np.sin(T) * np.cos(P), r * np.sin(T) * np.sin(P), r * np.cos(T)], -1).reshape(-1, 3)
    V = np.vstack([ring, [[0, 0, 1.0]], [[0, 0, -1.0]]])
    north, south = len(ring), len(ring) + 1
    i, j = np.meshgrid(np.arange(n_theta - 2), np.arange(n_phi), indexing="ij")
    a = i * n_phi + j
    b = i * n_phi + (j + 1) % n_phi
    c = (i + 1) * n_phi + (j + 1) % n_phi
    d = (i + 1) * n_phi + j
    F = [np.stack([a, d, c], -1).reshape(-1, 3), np.stack([a, c, b], -1).reshape(-1, 3)]
    j = np.arange(n_phi)
    F.append(np.stack([np.full(n_phi, north), j, (j + 1) % n_phi], -1))
    last = (n_theta - 2) * n_phi
    F.append(np.stack([np.full(n_phi, south), last + (j + 1) % n_phi, last + j], -1))
    F = np.concatenate(F).astype(np.int64)
    uv = np.column_stack([np.arctan2(V[:, 1], V[:, 0]) / (2 * np.pi) + 0.5,
                          np.arccos(np.clip(V[:, 2] / np.linalg.norm(V, axis=1), -1, 1)) / np.pi])
    norm = Normalization.from_points(V)
    Vn = norm.to_normalized(V)
    return SurfaceMesh(vertices=Vn, faces=F, uvs=uv, normals=Vn / np.linalg.norm(Vn, axis=1, keepdims=True),
                       colors=None, material_ids=np.zeros(len(F), np.int32), materials=(Material("surface"),),
                       normalization=norm, name="bumpy_sphere")


def covering_tets(surface: SurfaceMesh, target_tets: int, seed: int = 0) -> TetMesh:
    """Jittered grid tets over the surface's bounding box (5% margin), about ``target_tets`` tets."""
    lo, hi = surface.vertices.min(axis=0), surface.vertices.max(axis=0)
    margin = 0.05 * (hi - lo).max()
    lo, hi = lo - margin, hi + margin
    extent = hi - lo
    spacing = (np.prod(extent) * 6 / target_tets) ** (1 / 3)
    shape = np.maximum(1, np.round(extent / spacing)).astype(int)
    g = grid_tetmesh(tuple(shape), spacing=1.0, origin=(0, 0, 0))
    V = lo + g.vertices / shape * extent
    rng = np.random.default_rng(seed)
    inside = np.all((g.vertices > 0) & (g.vertices < shape), axis=1)
    V[inside] += rng.uniform(-0.1, 0.1, (inside.sum(), 3)) * (extent / shape)
    return TetMesh(vertices=V, tets=g.tets)


def voronoi_modes(tm: TetMesh, sites: int, seed: int = 0) -> Modes:
    rng = np.random.default_rng(seed)
    c = tm.tet_centroids
    centres = c[rng.choice(len(c), sites, replace=False)]
    lab = np.argmin(np.linalg.norm(c[:, None, :] - centres[None], axis=2), axis=1)
    ft = tm.interior_face_tets
    return Modes(U=lab[None, :, None].astype(float), labels=lab[None].astype(np.int32),
                 cut=(lab[ft[:, 0]] != lab[ft[:, 1]])[None], piece_counts=np.array([sites]),
                 energies=np.zeros(1), iterations=np.ones(1, np.int32))


def _row(name, surface, tets, sites, quick):
    tm = covering_tets(surface, tets)
    modes = voronoi_modes(tm, sites)
    t0 = time.perf_counter()
    P = pieces(tm, modes)
    t_pieces = time.perf_counter() - t0
    cells = []
    for lam in (0.0, SmoothOptions().smoothing):
        t0 = time.perf_counter()
        R = smooth(tm, P, SmoothOptions(smoothing=lam))
        t_smooth = time.perf_counter() - t0
        t0 = time.perf_counter()
        F = fragments(surface, R)
        t_frag = time.perf_counter() - t0
        inv = fragment_invariants(surface, F, max_pairs=200 if quick else 2000)
        rough = fragment_fault_shape(F)
        cells.append((lam, t_smooth, t_frag, len(F.fragments), inv, rough))
    rows = []
    for lam, t_smooth, t_frag, count, inv, rough in cells:
        rows.append(
            f"| {name} | {surface.num_faces} | {tm.num_tets} | {P.num_pieces} | {lam:g} | {t_pieces:.3f} | "
            f"{t_smooth:.2f} | {t_frag:.2f} | {count} | {inv['watertight']} | {inv['volume_error']:.1e} | "
            f"{inv['max_overlap']:.1e} | {inv['max_outer_distance']:.1e} | {rough['mean_dihedral_degrees']:.1f} | "
            f"{rough['crease_density']:.1f} |"
        )
    return rows


def _manifest() -> list[tuple[str, str]]:
    import tomllib

    with open(os.path.join(SAMPLE_ASSETS, "manifest.toml"), "rb") as fh:
        return sorted(tomllib.load(fh)["assets"].items())


def _smoothing_table(load_surface) -> list[str]:
    """Rows: each sample asset through its manifest recipe, smoothed with lambda = 0, then with the recipe's
    lambda by both methods (the recipe's own first)."""
    import dataclasses

    from fracture_cli.pipeline.recipe import load_recipe
    from fracture_cli.stages.cage import cage
    from fracture_cli.stages.material import material
    from fracture_cli.stages.modes import modes
    from fracture_cli.stages.repair import repair
    from fracture_cli.stages.tetra import tetra

    lines = [
        "### Fault smoothing on the sample assets (manifest recipes)",
        "",
        "Each asset through its recipe; smoothed with lambda = 0, then with the recipe's lambda by its own method "
        "(first) and by the other one. `h` = mean cage-tet edge (diagonal units); `r/h` = sqrt(lambda) / h. "
        "Fault shape of the fragments' interior faces: mean dihedral angle of bent edges (degrees) and crease "
        "density (length of edges bending > 30 degrees per unit area, 1/diagonal); lower is smoother. "
        "Vanished pieces keep their own tets.",
        "",
        "| asset | recipe | tets | h | pieces | method | lambda | r/h | smooth s | vanished | mean dihedral | "
        "creases | fragments s |",
        "|---|---|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for name, recipe_name in _manifest():
        path = os.path.join(SAMPLE_ASSETS, name)
        if load_surface is None or not os.path.exists(path):
            continue
        try:
            recipe = load_recipe(recipe_name)
            surface = repair(load_surface(path), recipe["repair"])
            tm = tetra(cage(surface, recipe["cage"]), recipe["tetra"])
            P = pieces(tm, modes(tm, recipe["modes"], eta=material(tm, surface, recipe["material"])),
                       recipe["pieces"])
            h = float(tet_edge_lengths(tm.vertices, tm.tets).mean())
            own = recipe["smooth"]
            other = "field" if own.method == "geometric" else "geometric"
            for options in (dataclasses.replace(own, smoothing=0.0), own, dataclasses.replace(own, method=other)):
                t0 = time.perf_counter()
                R = smooth(tm, P, options, surface=surface)
                t_smooth = time.perf_counter() - t0
                t0 = time.perf_counter()
                F = fragments(surface, R, recipe["fragments"])
                t_frag = time.perf_counter() - t0
                shape = fragment_fault_shape(F)
                lam = options.smoothing
                lines.append(
                    f"| {name} | {recipe_name} | {tm.num_tets} | {h:.3f} | {P.num_pieces} | "
                    f"{options.method if lam else '-'} | {lam:g} | {np.sqrt(lam) / h:.2f} | {t_smooth:.2f} | "
                    f"{len(R.vanished)} | {shape['mean_dihedral_degrees']:.1f} | {shape['crease_density']:.1f} | "
                    f"{t_frag:.2f} |"
                )
        except Exception as exc:  # a benchmark row, not a test: report and go on
            lines.append(f"| {name} | failed: {str(exc)[:120]} |")
    return lines


def run(quick: bool = False) -> str:
    lines = [
        "## Pieces, fault smoothing and fragment booleans",
        "",
        "Synthetic pieces (Voronoi cells of 30 sites) on a jittered grid tet mesh over the input's bbox; "
        "seconds on this machine (default smoothing options). Fault shape of the fragments' interior faces: mean "
        "dihedral angle (degrees) and crease density (1/diagonal), see the module docstring; lower is smoother.",
        "",
        "| input | triangles | tets | pieces | lambda | pieces s | smooth s | fragments s | fragments | "
        "watertight | volume error | max overlap | max outer dist | mean dihedral | creases |",
        "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    if quick:
        lines += _row("bumpy sphere", bumpy_sphere(40, 60), 1500, 12, quick)
        return "\n".join(lines) + "\n"
    lines += _row("bumpy sphere", bumpy_sphere(), 5000, 30, quick)
    from fracture_cli.stages.load import load_surface
    from fracture_cli.stages.repair import repair

    for name in SAMPLE_FILES:
        path = os.path.join(SAMPLE_ASSETS, name)
        try:
            # The open vase needs the repair stage, as in a bake.
            lines += _row(name, repair(load_surface(path)), 5000, 30, quick)
        except Exception as exc:  # a benchmark row, not a test: report and go on
            lines.append(f"| {name} | failed: {str(exc)[:120]} |")
    lines += ["", *_smoothing_table(load_surface)]
    return "\n".join(lines) + "\n"


if __name__ == "__main__":
    print(run(quick="--quick" in sys.argv))
