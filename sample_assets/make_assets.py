"""Generate the sample assets in this folder (run from the repo root).

    python sample_assets/make_assets.py

Every asset is made here from primitives, so nothing is copied from elsewhere:

* ``pillar.glb``   closed column (shaft, base, capital) with cylindrical UVs and
  a small checker texture: the ordinary case.
* ``chair.glb``    seat, back and four thin legs unioned into one solid, with
  box-projected UVs: thin parts that must not vanish in the cage.
* ``pane.glb``     a thin glass pane (1.0 x 0.8 x 0.012, normal +Z) for the
  ``glass_pane`` recipe (radial pattern).
* ``wall.glb``     a wall (2.0 x 1.2 x 0.25, courses along +X) for the
  ``brick_wall`` recipe (bricks pattern).
All assets are +Y up (the glTF convention), in metres.

* ``vase.obj``     a surface of revolution, open at the top (a single sheet, no
  wall thickness) and split at its UV seam (duplicated vertices): the
  deliberately awkward input.
"""

from __future__ import annotations

import os

import manifold3d as m3d
import numpy as np
import trimesh
from PIL import Image

HERE = os.path.dirname(os.path.abspath(__file__))


def _manifold_to_trimesh(man: m3d.Manifold) -> trimesh.Trimesh:
    mesh = man.to_mesh()
    return trimesh.Trimesh(np.asarray(mesh.vert_properties)[:, :3], np.asarray(mesh.tri_verts), process=False)


def _box_uv_split(mesh: trimesh.Trimesh, texel: float) -> trimesh.Trimesh:
    """Unweld every face and give it a planar UV along its dominant normal axis."""
    tri = mesh.vertices[mesh.faces]  # (m, 3, 3)
    axis = np.argmax(np.abs(mesh.face_normals), axis=1)
    keep = np.array([[1, 2], [0, 2], [0, 1]])[axis]  # (m, 2) the two other axes
    uv = np.take_along_axis(tri, keep[:, None, :].repeat(3, axis=1), axis=2) / texel
    verts = tri.reshape(-1, 3)
    faces = np.arange(len(verts)).reshape(-1, 3)
    out = trimesh.Trimesh(verts, faces, process=False)
    # Weld identical (position, uv) pairs so the mesh is closed except at UV seams.
    key = np.round(np.hstack([verts, uv.reshape(-1, 2)]), 9)
    _, first, inverse = np.unique(key, axis=0, return_index=True, return_inverse=True)
    order = np.argsort(first)
    remap = np.empty_like(order)
    remap[order] = np.arange(len(order))
    out = trimesh.Trimesh(verts[first[order]], remap[inverse.reshape(-1)].reshape(-1, 3), process=False)
    out.visual = trimesh.visual.TextureVisuals(uv=uv.reshape(-1, 2)[first[order]])
    return out


def _checker(size=64, cells=8, a=(196, 180, 150), b=(150, 130, 105)) -> Image.Image:
    ij = (np.arange(size) * cells // size)
    grid = (ij[:, None] + ij[None, :]) % 2
    img = np.where(grid[..., None] == 0, np.array(a, np.uint8), np.array(b, np.uint8))
    return Image.fromarray(img.astype(np.uint8), "RGB")


def _z_up_to_y_up(points: np.ndarray) -> np.ndarray:
    """glTF is +Y up; the shapes are built +Z up. A rotation, so winding is kept."""
    x, y, z = points.T
    return np.stack([x, z, -y], axis=1)


def _glb(mesh: trimesh.Trimesh, name: str, material) -> None:
    mesh.vertices = _z_up_to_y_up(np.asarray(mesh.vertices))
    mesh.visual.material = material
    scene = trimesh.Scene()
    scene.add_geometry(mesh, node_name=name, geom_name=name)
    data = scene.export(file_type="glb")
    with open(os.path.join(HERE, f"{name}.glb"), "wb") as fh:
        fh.write(data)


def pillar() -> None:
    sections = 48
    shaft = m3d.Manifold.cylinder(2.5, 0.32, 0.32, sections).translate((0, 0, 0.25))
    base = m3d.Manifold.cube((1.0, 1.0, 0.3)).translate((-0.5, -0.5, 0.0))
    capital = m3d.Manifold.cylinder(0.3, 0.32, 0.55, sections).translate((0, 0, 2.68))
    abacus = m3d.Manifold.cube((1.1, 1.1, 0.15)).translate((-0.55, -0.55, 2.95))
    solid = m3d.Manifold.batch_boolean([shaft, base, capital, abacus], m3d.OpType.Add)
    # Refine so the fine surface is visibly finer than a 2k-face cage; manifold's
    # refinement keeps the mesh conforming (no T-junctions).
    mesh = _manifold_to_trimesh(solid.refine_to_length(0.12))
    mesh = _box_uv_split(mesh, texel=0.5)
    material = trimesh.visual.material.PBRMaterial(
        name="stone", baseColorFactor=[255, 255, 255, 255], baseColorTexture=_checker(),
        metallicFactor=0.0, roughnessFactor=0.9)
    _glb(mesh, "pillar", material)


def chair() -> None:
    parts = [m3d.Manifold.cube((0.9, 0.9, 0.06)).translate((0.0, 0.0, 0.8))]  # seat
    parts.append(m3d.Manifold.cube((0.9, 0.06, 0.9)).translate((0.0, 0.84, 0.83)))  # back
    for x in (0.03, 0.81):
        for y in (0.03, 0.81):
            parts.append(m3d.Manifold.cube((0.06, 0.06, 0.83)).translate((x, y, 0.0)))  # legs
    parts.append(m3d.Manifold.cube((0.04, 0.80, 0.04)).translate((0.04, 0.05, 0.3)))  # rails
    parts.append(m3d.Manifold.cube((0.04, 0.80, 0.04)).translate((0.82, 0.05, 0.3)))
    solid = m3d.Manifold.batch_boolean(parts, m3d.OpType.Add)
    mesh = _manifold_to_trimesh(solid.refine_to_length(0.1))
    mesh = _box_uv_split(mesh, texel=0.25)
    material = trimesh.visual.material.PBRMaterial(
        name="wood", baseColorFactor=[150, 100, 60, 255], metallicFactor=0.0, roughnessFactor=0.8)
    _glb(mesh, "chair", material)


def vase() -> None:
    rings, sections = 24, 32
    t = np.linspace(0.0, 1.0, rings)
    z = 1.6 * t
    radius = 0.35 + 0.25 * np.sin(np.pi * t * 1.2) - 0.12 * t
    theta = np.linspace(0.0, 2 * np.pi, sections + 1)  # last column duplicates the first: the UV seam
    tt, rr = np.meshgrid(theta, radius, indexing="xy")
    zz = np.repeat(z[:, None], sections + 1, axis=1)
    verts = np.stack([rr * np.cos(tt), rr * np.sin(tt), zz], axis=-1).reshape(-1, 3)
    uv = np.stack(np.meshgrid(theta / (2 * np.pi), t, indexing="xy"), axis=-1).reshape(-1, 2)
    idx = np.arange(rings * (sections + 1)).reshape(rings, sections + 1)
    a, b = idx[:-1, :-1].ravel(), idx[:-1, 1:].ravel()
    c, d = idx[1:, :-1].ravel(), idx[1:, 1:].ravel()
    faces = np.concatenate([np.stack([a, b, d], 1), np.stack([a, d, c], 1)])
    # Bottom: a fan to a centre vertex, so the vase is open only at the top.
    centre = len(verts)
    verts = np.vstack([verts, [0.0, 0.0, 0.0]])
    uv = np.vstack([uv, [0.5, 0.0]])
    bottom = np.stack([np.full(sections, centre), idx[0, 1:], idx[0, :-1]], 1)
    faces = np.concatenate([faces, bottom])
    lines = ["# vase: open at the top, UV seam split (generated by make_assets.py)", "mtllib vase.mtl", "o vase"]
    lines += [f"v {x:.6f} {y:.6f} {zc:.6f}" for x, y, zc in _z_up_to_y_up(verts)]
    lines += [f"vt {u:.6f} {v:.6f}" for u, v in uv]
    lines.append("usemtl glaze")
    lines += [f"f {i+1}/{i+1} {j+1}/{j+1} {k+1}/{k+1}" for i, j, k in faces]
    with open(os.path.join(HERE, "vase.obj"), "w") as fh:
        fh.write("\n".join(lines) + "\n")
    with open(os.path.join(HERE, "vase.mtl"), "w") as fh:
        fh.write("newmtl glaze\nKd 0.20 0.35 0.60\n")


def pane() -> None:
    # Built +Z up as the others: 1.0 wide (x), 0.012 thick (y), 0.8 high (z); +Y up it faces +Z.
    solid = m3d.Manifold.cube((1.0, 0.012, 0.8)).translate((-0.5, -0.006, 0.0))
    mesh = _manifold_to_trimesh(solid.refine_to_length(0.08))
    mesh = _box_uv_split(mesh, texel=1.0)
    material = trimesh.visual.material.PBRMaterial(
        name="glass", baseColorFactor=[190, 215, 230, 110], metallicFactor=0.0, roughnessFactor=0.05,
        alphaMode="BLEND")
    _glb(mesh, "pane", material)


def wall() -> None:
    # 2.0 long (x), 0.25 deep (y), 1.2 high (z); +Y up the courses run along +X and stack along +Y.
    solid = m3d.Manifold.cube((2.0, 0.25, 1.2)).translate((-1.0, -0.125, 0.0))
    mesh = _manifold_to_trimesh(solid.refine_to_length(0.1))
    mesh = _box_uv_split(mesh, texel=0.4)
    material = trimesh.visual.material.PBRMaterial(
        name="brick", baseColorFactor=[255, 255, 255, 255],
        baseColorTexture=_checker(a=(170, 80, 60), b=(140, 62, 48)), metallicFactor=0.0, roughnessFactor=0.95)
    _glb(mesh, "wall", material)


MAKERS = {"pillar": pillar, "chair": chair, "vase": vase, "pane": pane, "wall": wall}

if __name__ == "__main__":
    import sys

    # `python sample_assets/make_assets.py pane wall` makes only those; no names: all of them.
    for name in sys.argv[1:] or list(MAKERS):
        MAKERS[name]()
