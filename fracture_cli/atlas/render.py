"""The atlas's PNG: the surface coloured by the first-detachment impulse, and three example hits.

Top row: the asset from three views, each outer triangle of the fragments GLB
coloured by ``d1 / T`` of its nearest contact site (log colour scale; grey where
nothing ever detaches), or the contact sites themselves as dots without a GLB.
Bottom row: the hits with the lowest, median and highest ``d1`` of the sweep, at
``2 x b0``, seen from the hit's side: the main group grey, every detached group
in its own colour, pushed away from the centre, the hit as a red arrow. Rendering reuses
:mod:`fracture_cli.view.preview` (matplotlib Agg, flat shading, painter's order); each
view rotates the scene into the preview's camera. Deterministic: the same inputs
give the same bytes; written atomically.
"""

from __future__ import annotations

import os
from typing import Any

import numpy as np

from fracture_cli.atlas.hits import HitAnalysis, detached, groups_at, rest_groups
from fracture_cli.atlas.layout import FragmentLayout
from fracture_cli.runtime.format import RuntimeData
from fracture_cli.types import INTERIOR_MATERIAL_NAME
from fracture_cli.view.preview import UP, VIEW_DIR, FragmentGeometry, draw_triangles, palette, project

# (title, direction from the asset towards the camera); +Y up as in glTF.
VIEWS = (("front right", (1.0, 0.8, 1.4)), ("back left", (-1.0, 0.8, -1.4)), ("from below", (0.7, -1.1, 0.9)))
NEVER = np.array([0.6, 0.6, 0.6])  # colour of sites where nothing detaches
MAIN = np.array([0.82, 0.82, 0.82])  # colour of the main group in the example hits
WIDTH, HEIGHT = 1500, 1000


def fragment_triangles(glb_path: str, names: tuple[str, ...]) -> list[FragmentGeometry] | None:
    """Outer and interior triangles of each fragment (in ``names`` order) from the GLB; None if one is missing."""
    # on first use: the atlas loads the renderer only for a PNG
    from fracture_cli.io.gltf import glb_meshes, read_glb_chunks

    doc, binary = read_glb_chunks(glb_path)
    materials = [m.get("name", "") for m in doc.get("materials", [])]
    by_name = {mesh.name: mesh for mesh in glb_meshes(doc, binary)}
    out = []
    for name in names:
        if name not in by_name:
            return None
        outer, inner = [np.zeros((0, 3, 3))], [np.zeros((0, 3, 3))]
        for prim in by_name[name].primitives:
            interior = prim.material < len(materials) and materials[prim.material] == INTERIOR_MATERIAL_NAME
            (inner if interior else outer).append(prim.positions[prim.indices])
        outer_tris = np.concatenate(outer)
        out.append(FragmentGeometry(outer=outer_tris, inner=np.concatenate(inner),
                                    outer_colors=np.zeros((len(outer_tris), 3))))
    return out


def _basis(view_dir) -> np.ndarray:
    """Rows right, up, forward (3, 3) of a camera looking along ``-view_dir`` (as :mod:`fracture_cli.view.preview`)."""
    d = np.asarray(view_dir, dtype=np.float64)
    forward = -d / np.linalg.norm(d)
    right = np.cross(forward, UP)
    right /= np.linalg.norm(right)
    return np.stack([right, np.cross(right, forward), forward])


def _rotation(view_dir) -> np.ndarray:
    """The rotation (3, 3) that shows the scene from ``view_dir`` through the preview's fixed camera."""
    return _basis(VIEW_DIR).T @ _basis(view_dir)


def _d1_colors(values: np.ndarray) -> tuple[np.ndarray, Any]:
    """RGB (n, 3) for the values on a log scale (grey where not finite and positive), and the norm (or None)."""
    import matplotlib
    from matplotlib.colors import LogNorm

    good = np.isfinite(values) & (values > 0.0)
    colors = np.repeat(NEVER[None], len(values), axis=0)
    if not good.any():
        return colors, None
    low, high = float(values[good].min()), float(values[good].max())
    if not low < high:
        low, high = low / 2.0, high * 2.0
    norm = LogNorm(vmin=low, vmax=high)
    colors[good] = matplotlib.colormaps["viridis"](norm(values[good]))[:, :3]
    return colors, norm


def _draw_map(ax, data: RuntimeData, frags, site_colors: np.ndarray, center, radius: float, view,
              pixels: int) -> None:
    """One view of the breaking-impulse map."""
    title, direction = view
    R = _rotation(direction)
    sites = np.asarray(data.sites, dtype=np.float64)
    if frags is not None:
        from scipy.spatial import cKDTree

        tris = np.concatenate([f.outer for f in frags])
        _, nearest = cKDTree(sites).query(tris.mean(axis=1))
        draw_triangles(ax, (tris - center) @ R.T + center, site_colors[nearest], center=center,
                       extent=radius * 1.05, pixels=pixels)
    else:
        rotated = (sites - center) @ R.T + center
        order = np.argsort(-((rotated - center) @ _basis(VIEW_DIR)[2]), kind="stable")  # far first
        xy = project(rotated[order], center)
        ax.set_xlim(-radius * 1.05, radius * 1.05)
        ax.set_ylim(-radius * 1.05, radius * 1.05)
        ax.set_aspect("equal")
        ax.axis("off")
        ax.scatter(xy[:, 0], xy[:, 1], c=site_colors[order], s=12, linewidths=0)
    ax.set_title(title, fontsize=11)


def _hit_view(hit: HitAnalysis) -> np.ndarray:
    """The preview's camera elevation, turned about the vertical axis to face the hit (as the preview's if
    the hit comes from straight above or below)."""
    horizontal = -hit.direction - (hit.direction @ -UP) * UP
    length = float(np.linalg.norm(horizontal))
    if not length > 0.2:
        return VIEW_DIR
    default = VIEW_DIR - (VIEW_DIR @ UP) * UP
    return horizontal / length * float(np.linalg.norm(default)) + (VIEW_DIR @ UP) * UP


def _draw_example(ax, data: RuntimeData, layout: FragmentLayout, frags, hit: HitAnalysis, center, radius: float,
                  pixels: int) -> None:
    """What comes off at ``2 x b0`` for one hit, seen from the hit's side."""
    groups = groups_at(data, hit, 2.0 * hit.b0)
    gone = detached(groups, rest_groups(data), layout.volumes)
    off_groups = sorted({int(g) for g in groups[gone].tolist()})
    colors = np.repeat(MAIN[None], data.p, axis=0)
    shades = palette(max(len(off_groups), 1))
    for index, g in enumerate(off_groups):
        colors[groups == g] = shades[index]
    threshold = float(data.default_threshold)
    unit = f"{hit.d1 / threshold:.3g} T" if threshold > 0.0 else f"{hit.d1:.3g}"
    ax.set_title(f"site {hit.site}: d1 = {unit}; at 2 b0, {int(gone.sum())} of {data.p} fragments off",
                 fontsize=10)
    R = _rotation(_hit_view(hit))
    point = (hit.point - center) @ R.T + center
    direction = hit.direction @ R.T
    if frags is not None:
        centroids = np.array([f.centroid for f in frags])
        push = np.zeros((data.p, 3))
        for g in off_groups:
            members = groups == g
            push[members] = (centroids[members].mean(axis=0) - center) * 0.35
        tris = [(np.concatenate([f.outer, f.inner]) + push[j] - center) @ R.T + center for j, f in enumerate(frags)]
        cols = [np.repeat(colors[j][None], len(tris[j]), 0) for j in range(data.p)]
        bias = [np.r_[np.zeros(len(f.outer)), np.full(len(f.inner), 0.02 * radius)] for f in frags]
        draw_triangles(ax, np.concatenate(tris), np.concatenate(cols), center=center, extent=radius * 1.35,
                       pixels=pixels, depth_bias=np.concatenate(bias))
    else:
        ax.set_xlim(-radius * 1.35, radius * 1.35)
        ax.set_ylim(-radius * 1.35, radius * 1.35)
        ax.set_aspect("equal")
        ax.axis("off")
        if layout.centroids is not None:
            xy = project((layout.centroids - center) @ R.T + center, center)
            ax.scatter(xy[:, 0], xy[:, 1], c=colors, s=60, linewidths=0.5, edgecolors="k")
    head = project(point[None], center)[0]
    tail = project((point - direction * radius * 0.6)[None], center)[0]
    ax.annotate("", xy=head, xytext=tail, arrowprops=dict(arrowstyle="-|>", color="crimson", lw=2.5))
    ax.plot([head[0]], [head[1]], "o", color="crimson", ms=6)


def render_atlas(data: RuntimeData, layout: FragmentLayout, site_d1: np.ndarray, examples: tuple[HitAnalysis, ...],
                 png_path: str | os.PathLike, *, glb_path: str | os.PathLike | None = None, title: str = "") -> None:
    """Write the atlas PNG (module docstring).

    Parameters
    ----------
    data : RuntimeData
    layout : FragmentLayout
    site_d1 : (s,) float
        First-detachment impulse of an inward hit at every contact site (``+inf``: never).
    examples : tuple of HitAnalysis
        The example hits (at most 3), drawn left to right.
    png_path : path
        Output PNG, written atomically.
    glb_path : path, optional (default None)
        The fragments GLB; without it (or if it lacks a fragment) sites and
        centroids are drawn as dots.
    title : str, optional
        Figure title.
    """
    import matplotlib

    matplotlib.use("Agg")
    # on first use: the atlas loads the renderer only for a PNG
    import matplotlib.pyplot as plt
    from matplotlib.cm import ScalarMappable

    from fracture_cli.io.atomic import atomic_path

    frags = None
    if glb_path is not None and os.path.exists(glb_path):
        frags = fragment_triangles(os.fspath(glb_path), data.fragment_names)
    if frags is not None:
        points = np.concatenate([np.concatenate([f.outer, f.inner]).reshape(-1, 3) for f in frags])
    else:
        points = np.asarray(data.sites, dtype=np.float64)
    low, high = points.min(axis=0), points.max(axis=0)
    center = (low + high) / 2.0
    radius = max(float(np.linalg.norm(high - low)) / 2.0, 1e-9)
    threshold = float(data.default_threshold)
    values = np.asarray(site_d1, dtype=np.float64) / threshold if threshold > 0.0 else np.asarray(site_d1, float)
    site_colors, norm = _d1_colors(values)

    fig = plt.figure(figsize=(WIDTH / 100.0, HEIGHT / 100.0), dpi=100)
    fig.patch.set_facecolor("white")
    grid = fig.add_gridspec(2, 3, hspace=0.12, wspace=0.02, left=0.01, right=0.9, top=0.9, bottom=0.02)
    pixels = HEIGHT // 2
    for column, view in enumerate(VIEWS):
        _draw_map(fig.add_subplot(grid[0, column]), data, frags, site_colors, center, radius, view, pixels)
    for column, hit in enumerate(examples[:3]):
        _draw_example(fig.add_subplot(grid[1, column]), data, layout, frags, hit, center, radius, pixels)
    if norm is not None:
        bar = fig.colorbar(ScalarMappable(norm=norm, cmap="viridis"), cax=fig.add_axes((0.92, 0.55, 0.015, 0.33)))
        bar.set_label("first detachment d1 / T" if threshold > 0.0 else "first detachment d1", fontsize=10)
    fig.suptitle(title, fontsize=13)
    with atomic_path(png_path) as tmp:
        fig.savefig(tmp, format="png", dpi=100, metadata={"Software": None})
    plt.close(fig)
