"""Benchmark of the game-ready modules on the sample assets (fracture_cli.gameready).

    python bench/bench_gameready.py [--quick] [--from DIR] [--only-lean]

Each sample asset runs through the pipeline with the recipe its manifest names
(one process, ``--jobs 1``), and the game-ready steps run on its fragments
(with ``--from DIR`` bodies and collision read ``DIR/<stem>/<stem>.glb`` instead
and the lean-mesh table is left out):

* bodies: closed bodies per fragment, fragments after splitting (tiny bodies,
  below 1e-4 of the asset's volume, merged into their neighbour);
* collision: convex parts per fragment, hull volume / volume of each fragment
  before (its plain hull) and after (its parts), the share of each fragment's
  volume inside its parts, the largest overlap between two collision shapes
  (fraction of the smaller) with plain hulls and with the parts;
* lean meshes (the ``simplify`` stage at the recipe's settings): triangles of
  the input, of the fragments as cut and as simplified, the budget of issue 20
  (twice the cut solid's triangles plus 64 per fragment), GLB bytes as cut and
  as simplified, and the CPU seconds the stage adds to the bake (simplifying
  and checking the fragments again), one process;
* rest (when Godot 3 is installed): one rigid body per fragment, gravity off,
  one second of physics (Bullet, shape margin 1e-4), largest speed with each
  fragment's convex hull and with its exported parts (``UCX_`` meshes).

Seconds are CPU seconds (``time.process_time``) of one process: the machine
may be shared; collision runs on every core, and its CPU seconds include its
worker processes (next to its wall seconds). Targets: collision parts in a few seconds per asset, no
overlap above 1% of the smaller part.
"""

from __future__ import annotations

import argparse
import os
import shutil
import sys
import tempfile
import time
import tomllib

import numpy as np

REPO = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
sys.path.insert(0, REPO)

from fracture_cli.geometry.mass import mass_properties  # noqa: E402
from fracture_cli.io.gltf import read_glb  # noqa: E402
from fracture_cli.stages.collision.convex import _solid, collision_shapes, hull_corners, max_overlap_fraction  # noqa: E402
from fracture_cli.stages.fragments.bodies import body_faces, split_fragments  # noqa: E402
from fracture_cli.system import parallel  # noqa: E402
from fracture_cli.types import Fragment, Fragments, Material, Normalization  # noqa: E402


def read_fragments(path: str) -> Fragments:
    """The fragments of a baked GLB as :class:`Fragments` (normalized by the fragments' bounding box)."""
    meshes, names = read_glb(path)
    world = np.vstack([p.positions for m in meshes for p in m.primitives])
    norm = Normalization.from_points(world)
    frags = []
    for k, mesh in enumerate(meshes):
        offset, positions, normals, uvs, faces, material = 0, [], [], [], [], []
        for prim in mesh.primitives:
            positions.append(prim.positions)
            normals.append(prim.normals)
            uvs.append(prim.uvs if prim.uvs is not None else np.zeros((len(prim.positions), 2)))
            faces.append(prim.indices + offset)
            material.append(np.full(len(prim.indices), prim.material, dtype=np.int32))
            offset += len(prim.positions)
        frags.append(Fragment(vertices=norm.to_normalized(np.vstack(positions)), faces=np.vstack(faces),
                              uvs=np.vstack(uvs), normals=np.vstack(normals), material_ids=np.concatenate(material),
                              piece=k))
    volume = sum(mass_properties(f.vertices, f.faces).volume for f in frags)
    return Fragments(tuple(frags), tuple(Material(n) for n in names), norm, volume)


def _glb(asset: str, source: str) -> str:
    stem = os.path.splitext(asset)[0]
    return os.path.join(source, stem, f"{stem}.glb")


def _measure(fragments: Fragments) -> dict:
    out: dict = {}
    t = time.process_time()
    bodies = [len(body_faces(f.vertices, f.faces)) for f in fragments.fragments]
    split, report = split_fragments(fragments, 1e-4)
    out["bodies"] = (len(fragments.fragments), max(bodies), sum(b > 1 for b in bodies), len(split.fragments),
                     report.merged, time.process_time() - t)
    meshes = [(f.vertices, f.faces) for f in split.fragments]
    # The stage runs on --jobs worker processes (every core here): CPU counts them (os.times' children) and wall.
    before, wall = os.times(), time.perf_counter()
    shapes = collision_shapes(meshes)
    after = os.times()
    wall = time.perf_counter() - wall
    seconds = (after.user + after.system + after.children_user + after.children_system
               - before.user - before.system - before.children_user - before.children_system)
    parts = np.array([len(p) for p in shapes.parts])
    hulls = [hull_corners(_solid(V, F)) for V, F in meshes]
    out["collision"] = (len(meshes), parts.mean(), parts.max(), parts.sum(),
                        max(len(p) for ps in shapes.parts for p in ps), shapes.hull_ratio.max(),
                        int((shapes.hull_ratio > 1.5).sum()), shapes.parts_ratio.max(), shapes.coverage.min(),
                        np.median(shapes.coverage), max_overlap_fraction(hulls),
                        max_overlap_fraction([p for ps in shapes.parts for p in ps]), seconds, wall)
    out["rest"] = _rest_in_godot(split, shapes) if shutil.which("godot3-server") else None
    return out


def _lean(asset: str, recipe_name: str, tmp: str) -> tuple[Fragments, tuple]:
    """The pipeline up to ``simplify`` on one sample asset; its fragments and the lean-mesh row's figures."""
    from fracture_cli.io.write import write_fragments_glb
    from fracture_cli.pipeline import STAGE_NAMES, PipelineState
    from fracture_cli.pipeline.recipe import load_recipe
    from fracture_cli.pipeline.runner import Runner
    from fracture_cli.stages.simplify import triangle_budget

    recipe = load_recipe(recipe_name)
    runner = Runner(asset)
    state = PipelineState(source=os.path.join(REPO, "sample_assets", asset))
    with parallel.using(1):
        for name in STAGE_NAMES[:STAGE_NAMES.index("simplify")]:
            state = runner.run(name, state, recipe[name])
        cut = state.fragments
        t = time.process_time()
        state = runner.run("simplify", state, recipe["simplify"])
        seconds = time.process_time() - t
    sizes = []
    for label, frags in (("cut", cut), ("lean", state.fragments)):
        path = os.path.join(tmp, f"{label}.glb")
        write_fragments_glb(path, frags)
        sizes.append(os.path.getsize(path))
    triangles = [sum(len(f.faces) for f in frags.fragments) for frags in (cut, state.fragments)]
    budget = triangle_budget(len(state.surface.faces), len(state.fragments.fragments))
    row = (state.loaded.num_faces, len(state.surface.faces), len(cut.fragments), triangles[0], triangles[1], budget,
           sizes[0], sizes[1], seconds, recipe["simplify"].tolerance, state.checks["watertight"],
           state.checks["volume_error"])
    return state.fragments, row


def _rest_in_godot(fragments: Fragments, shapes) -> tuple[float, float]:
    """Largest body speed after one second in Godot 3: (convex hulls, exported parts)."""
    sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
    from bench_recipes import rest_in_godot

    from fracture_cli.io.gltf import glb_bytes
    from fracture_cli.io.names import fragment_name
    from fracture_cli.io.physics import FragmentPhysics, physics_extender
    from fracture_cli.io.write import split_by_material

    norm = fragments.normalization
    nodes, physics = [], []
    for i, frag in enumerate(fragments.fragments):
        mass = mass_properties(frag.vertices, frag.faces).to_world(norm)
        prims = split_by_material(frag.vertices, frag.faces, frag.normals, frag.uvs, frag.material_ids, norm,
                                  mass.center)
        nodes.append((fragment_name(i), prims, mass.center))
        physics.append(FragmentPhysics(mass, mass.center, [norm.to_world(p) for p in shapes.parts[i]]))
    with tempfile.TemporaryDirectory() as tmp:
        glb = os.path.join(tmp, "asset.glb")
        with open(glb, "wb") as fh:
            fh.write(glb_bytes(nodes, fragments.materials, extend=physics_extender(physics, "unreal")))
        hull, parts = rest_in_godot(glb, ("hull", "parts"))
    return hull, parts


def run(quick: bool = False, source: str | None = None, lean_only: bool = False) -> str:
    with open(os.path.join(REPO, "sample_assets", "manifest.toml"), "rb") as fh:
        assets = sorted(tomllib.load(fh)["assets"].items())
    if quick:
        assets = [a for a in assets if a[0] == "chair.glb"]
    rows: dict[str, list[str]] = {"bodies": [], "collision": [], "lean": [], "rest": []}
    with tempfile.TemporaryDirectory() as tmp:
        for asset, recipe in assets:
            name = f"{asset} ({recipe})"
            if source:
                fragments = read_fragments(_glb(asset, source))
            else:
                fragments, r = _lean(asset, recipe, tmp)
                rows["lean"].append(
                    f"| {name} | {r[0]:,} / {r[1]:,} | {r[2]} | {r[3]:,} | {r[4]:,} | {r[5]:,} | {r[4] / r[1]:.2f} "
                    f"| {r[6] / 1024:,.0f} | {r[7] / 1024:,.0f} | {r[8]:.1f} | {r[9]:g} | {r[10]} / {r[11]:.1e} |")
            if lean_only:
                continue
            measured = _measure(fragments)
            b = measured["bodies"]
            rows["bodies"].append(f"| {name} | {b[0]} | {b[1]} | {b[2]} | {b[3]} | {b[4]} | {b[5]:.2f} |")
            c = measured["collision"]
            rows["collision"].append(
                f"| {name} | {c[0]} | {c[1]:.2f} / {c[2]} / {c[3]} | {c[4]} | {c[5]:.2f} ({c[6]} > 1.5) | {c[7]:.2f} "
                f"| {c[8]:.3f} / {c[9]:.3f} | {c[10]:.3f} | {c[11]:.1e} | {c[12]:.1f} / {c[13]:.1f} |")
            if measured["rest"] is not None:
                rows["rest"].append(f"| {name} | {measured['rest'][0]:.3f} | {measured['rest'][1]:.4f} |")
    lean = [
        ("Lean meshes (the simplify stage, recipe defaults; budget = 2 x cut solid's triangles + 64 x fragments; "
         "input = as read / the solid that is cut, after repair; KiB of the fragments GLB; CPU s of the stage, "
         "including checking the fragments again)."),
        "",
        ("| asset | input triangles | fragments | triangles cut | triangles lean | budget | lean / input "
         "| GLB KiB cut | GLB KiB lean | stage CPU s | tolerance | watertight / volume error |"),
        "|---|---|---|---|---|---|---|---|---|---|---|---|",
        *(rows["lean"] or ["| (not measured with --from) |"]),
        "",
    ]
    if lean_only:
        return "\n".join(["## gameready (lean meshes only)", "", *lean])
    return "\n".join([
        "## gameready",
        "",
        __doc__.split("\n\n", 2)[2].strip(),
        "",
        ("Bodies (per asset): fragments, most bodies in one fragment, fragments with several bodies, fragments "
         "after splitting, tiny bodies merged, CPU s."),
        "",
        "| asset | fragments | max bodies | multi-body | after split | merged | s |",
        "|---|---|---|---|---|---|---|",
        *rows["bodies"],
        "",
        "Collision (defaults: at most 8 parts of at most 64 vertices, concavity 0.1), on the split fragments.",
        "",
        ("| asset | fragments | parts mean / max / total | max vertices | hull/volume max | parts/volume max "
         "| coverage min / median | overlap, plain hulls | overlap, parts | CPU s / wall s |"),
        "|---|---|---|---|---|---|---|---|---|---|",
        *rows["collision"],
        "",
        *lean,
        "At rest in Godot 3 (largest speed after 1 s, m/s; target: under 0.05), on the split fragments."
        if rows["rest"] else "At rest in Godot 3: not measured (godot3-server not installed).",
        "",
        *(["| asset | convex hulls | exported parts |", "|---|---|---|", *rows["rest"]] if rows["rest"] else []),
    ])


if __name__ == "__main__":
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="the chair only")
    parser.add_argument("--only-lean", action="store_true", help="the lean-mesh table only")
    parser.add_argument("--from", dest="source", default=None,
                        help="take <stem>/<stem>.glb from this folder instead of baking (no lean-mesh table)")
    args = parser.parse_args()
    print(run(quick=args.quick, source=args.source, lean_only=args.only_lean))
