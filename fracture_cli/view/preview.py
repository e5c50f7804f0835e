"""Preview pictures of a bake: the asset, exploded fragments, modes, an impact.

Rendering is headless and dependency-light: matplotlib's Agg backend, flat
shading, back-face culling and painter's ordering (far triangles first). It
needs no display and no GPU, so it runs in CI.
"""

from __future__ import annotations

import json
import logging
import os
from dataclasses import dataclass
from typing import Any

import numpy as np

from fracture_cli.errors import InputError
from fracture_cli.types import INTERIOR_MATERIAL_NAME

log = logging.getLogger(__name__)

# Camera looks from the front-right-above of a +Y-up asset (glTF convention).
VIEW_DIR = np.array([1.0, 0.8, 1.4]) / np.linalg.norm([1.0, 0.8, 1.4])
UP = np.array([0.0, 1.0, 0.0])
LIGHT = np.array([0.4, 1.0, 0.6]) / np.linalg.norm([0.4, 1.0, 0.6])


@dataclass(frozen=True)
class FragmentGeometry:
    """Triangles of one fragment, split into outer (input) and interior faces.

    Attributes
    ----------
    outer : (m, 3, 3) float
        Outer triangles, input units.
    inner : (q, 3, 3) float
        Interior (fault) triangles.
    outer_colors : (m, 3) float
        Base colour of each outer triangle's material.
    """

    outer: np.ndarray
    inner: np.ndarray
    outer_colors: np.ndarray

    @property
    def centroid(self) -> np.ndarray:
        tris = np.concatenate([self.outer, self.inner]) if len(self.inner) else self.outer
        return tris.reshape(-1, 3).mean(axis=0)


def load_fragments(glb_path: str) -> list[FragmentGeometry]:
    """Read the fragments of a baked GLB for drawing."""
    # on first use: the viewer's start-up loads no geometry
    from fracture_cli.io.gltf import glb_meshes, read_glb_chunks

    doc, binary = read_glb_chunks(glb_path)
    meshes = glb_meshes(doc, binary)
    material_names = [m.get("name", "") for m in doc.get("materials", [])]
    base_colors = [m.get("pbrMetallicRoughness", {}).get("baseColorFactor", [0.8, 0.8, 0.8, 1]) for m in
                   doc.get("materials", [])]
    out = []
    for mesh in meshes:
        outer, inner, colors = [], [], []
        for prim in mesh.primitives:
            tris = prim.positions[prim.indices]
            name = material_names[prim.material] if prim.material < len(material_names) else ""
            if name == INTERIOR_MATERIAL_NAME:
                inner.append(tris)
            else:
                outer.append(tris)
                color = np.asarray(base_colors[prim.material][:3], dtype=float) if base_colors else np.full(3, 0.8)
                colors.append(np.repeat(color[None], len(tris), axis=0))
        out.append(FragmentGeometry(
            outer=np.concatenate(outer) if outer else np.zeros((0, 3, 3)),
            inner=np.concatenate(inner) if inner else np.zeros((0, 3, 3)),
            outer_colors=np.concatenate(colors) if colors else np.zeros((0, 3)),
        ))
    return out


def _camera():
    forward = -VIEW_DIR
    right = np.cross(forward, UP)
    right /= np.linalg.norm(right)
    up = np.cross(right, forward)
    return right, up, forward


def cluster_triangles(tris: np.ndarray, colors: np.ndarray, cell: float):
    """Vertex-clustering simplification of a triangle soup for drawing.

    Every corner snaps to the centre of its grid cell of size ``cell``; triangles
    whose corners share a cell vanish. Corners shared between triangles snap to
    the same point, so the surface stays closed; below a pixel the change is
    invisible, and drawing gets much cheaper for dense meshes.

    Returns
    -------
    tris : (q, 3, 3) float
    colors : (q, 3) float
    keep : (m,) bool
        Which input triangles survive.
    """
    if cell <= 0 or len(tris) == 0:
        return tris, colors, np.ones(len(tris), dtype=bool)
    keys = np.floor(tris / cell).astype(np.int64)  # (m, 3, 3)
    same = (np.all(keys[:, 0] == keys[:, 1], axis=1) | np.all(keys[:, 1] == keys[:, 2], axis=1)
            | np.all(keys[:, 0] == keys[:, 2], axis=1))
    keep = ~same
    return (keys[keep] + 0.5) * cell, colors[keep], keep


def draw_triangles(ax, tris: np.ndarray, colors: np.ndarray, *, center: np.ndarray, extent: float,
                   pixels: int = 0, depth_bias: np.ndarray | None = None) -> None:
    """Draw triangles with flat shading, back-face culling and painter's order.

    Parameters
    ----------
    ax : matplotlib Axes
    tris : (m, 3, 3) float
        Triangles in world coordinates.
    colors : (m, 3) float
        Base RGB colour per triangle.
    center : (3,) float
        World point at the middle of the panel.
    extent : float
        Half-size of the visible square, world units.
    pixels : int, optional (default 0)
        Panel size in pixels; when given, detail below about a pixel is
        clustered away first (:func:`cluster_triangles`).
    depth_bias : (m,) float, optional
        Added to each triangle's depth for ordering: a positive bias draws
        interior faces before the outer faces they sit just behind.
    """
    from matplotlib.collections import PolyCollection

    ax.set_xlim(-extent, extent)
    ax.set_ylim(-extent, extent)
    ax.set_aspect("equal")
    ax.axis("off")
    if len(tris) == 0:
        return
    right, up, forward = _camera()
    # Shade and cull with the true normals: snapped geometry has noisy ones.
    normals = np.cross(tris[:, 1] - tris[:, 0], tris[:, 2] - tris[:, 0])
    bias = np.zeros(len(tris)) if depth_bias is None else np.asarray(depth_bias, dtype=np.float64)
    if pixels:
        tris, colors, kept = cluster_triangles(tris, colors, 2.0 * extent / pixels)  # ~1 px cells
        normals, bias = normals[kept], bias[kept]
    length = np.linalg.norm(normals, axis=1)
    keep = (normals @ forward < 0) & (length > 0)  # facing the camera
    tris, normals, length, colors, bias = tris[keep], normals[keep], length[keep], colors[keep], bias[keep]
    normals = normals / length[:, None]
    rel = tris - center
    xy = np.stack([rel @ right, rel @ up], axis=-1)  # (m, 3, 2)
    depth = (rel @ forward).mean(axis=1) + bias
    order = np.argsort(-depth, kind="stable")  # far first
    shade = 0.35 + 0.65 * np.clip(normals @ LIGHT, 0.0, 1.0)
    rgb = np.clip(colors * shade[:, None], 0.0, 1.0)
    coll = PolyCollection(list(xy[order]), facecolors=rgb[order], edgecolors="none", linewidths=0.0, antialiased=False)
    ax.add_collection(coll, autolim=False)  # limits are set above; autolim costs seconds


def project(points: np.ndarray, center: np.ndarray) -> np.ndarray:
    """Screen coordinates (n, 2) of world points (n, 3), matching :func:`draw_triangles`."""
    right, up, _ = _camera()
    rel = np.atleast_2d(points) - center
    return np.stack([rel @ right, rel @ up], axis=-1)


def palette(n: int) -> np.ndarray:
    """``n`` distinct, deterministic RGB colours."""
    import matplotlib

    base = np.asarray(matplotlib.colormaps["tab20"].colors)  # type: ignore[attr-defined]  # a ListedColormap
    if n <= len(base):
        return base[:n]
    hues = (np.arange(n) * 0.61803398875) % 1.0
    import colorsys

    return np.array([colorsys.hsv_to_rgb(h, 0.55, 0.9) for h in hues])


def pick_example_impact(data, center: np.ndarray):
    """A deterministic, telling example hit: the highest contact site, hit downward-inward.

    The impulse magnitude is the smallest of a geometric series that breaks the
    object into at least three groups (or the largest tried).
    """
    # on first use: the viewer's start-up loads no geometry
    from fracture_cli.runtime.impact import project_impact

    sites = np.asarray(data.sites, dtype=np.float64)
    score = sites @ (UP + 0.5 * VIEW_DIR)
    site = int(np.argmax(score))
    point = sites[site]
    direction = center - point
    direction /= max(np.linalg.norm(direction), 1e-12)
    threshold = data.default_threshold
    best = None
    for magnitude in np.geomspace(0.25, 256.0, 11):
        result = project_impact(data, point, direction * magnitude, threshold)
        best = (point, direction * magnitude, result)
        if len(np.unique(result.groups)) >= 3:
            break
    return best


def render_preview(json_path: str, png_path: str, *, width: int = 1600, height: int = 1000,
                   impact: tuple | None = None, max_modes: int = 6, report: dict | None = None,
                   panels: str = "all") -> dict:
    """Render the preview PNG of a bake.

    Parameters
    ----------
    json_path : str
        ``<stem>.fracture.json``; ``<stem>.glb`` (and ``<stem>.report.json`` if
        present) are read from beside it.
    png_path : str
        Output PNG (written atomically).
    width, height : int, optional (default 1600 x 1000)
        Image size in pixels.
    impact : (point (3,), impulse (3,), threshold or None), optional
        The impact to show; default: :func:`pick_example_impact`.
    max_modes : int, optional (default 6)
        How many modes to draw in the grid.
    report : dict, optional
        The bake report (recipe name, tet and cage counts for the title); by
        default ``<stem>.report.json`` beside the runtime file, if present. A
        bake passes its own: it renders the preview in its staging folder,
        before the report is written there.
    panels : {"all", "fragments"}, optional (default "all")
        ``"all"``: input, exploded fragments and the impact above the first
        modes; ``"fragments"``: the exploded fragments and the impact in one
        row, under a short title (no modes).

    Returns
    -------
    dict
        What was drawn: fragments, modes, groups of the example impact, the title.
    """
    import matplotlib

    matplotlib.use("Agg")
    # on first use: the viewer's start-up loads no geometry
    import matplotlib.pyplot as plt

    from fracture_cli.io.atomic import atomic_path
    from fracture_cli.runtime.format import load_runtime

    if not json_path.endswith(".fracture.json"):
        raise InputError("expected a <stem>.fracture.json runtime file", path=json_path)
    stem_path = json_path[: -len(".fracture.json")]
    glb_path = stem_path + ".glb"
    if not os.path.exists(glb_path):
        raise InputError(f"cannot find the fragments file {os.path.basename(glb_path)} next to it", path=json_path)
    data = load_runtime(json_path)
    frags = load_fragments(glb_path)
    if report is None:
        report = {}
        if os.path.exists(stem_path + ".report.json"):
            with open(stem_path + ".report.json") as fh:
                report = json.load(fh)

    all_pts = np.concatenate([np.concatenate([f.outer, f.inner]).reshape(-1, 3) for f in frags])
    lo, hi = all_pts.min(axis=0), all_pts.max(axis=0)
    view = _View(center=(lo + hi) / 2.0, radius=float(np.linalg.norm(hi - lo)) / 2.0,
                 centroids=np.array([f.centroid for f in frags]))

    fig = plt.figure(figsize=(width / 100.0, height / 100.0), dpi=100)
    fig.patch.set_facecolor("white")
    counts = report.get("counts", {})
    recipe = report.get("recipe", {}).get("name", "?")
    k = 0
    if panels == "fragments":
        grid = fig.add_gridspec(1, 3, wspace=0.02, left=0.01, right=0.99, top=0.84, bottom=0.01)
        _draw_assembled(fig.add_subplot(grid[0, 0]), frags, view, height)
        _draw_exploded(fig.add_subplot(grid[0, 1]), frags, view, height, fontsize=9, title="exploded")
        groups = _draw_impact(fig.add_subplot(grid[0, 2]), data, frags, view, impact, height, fontsize=9)
        kind = report.get("recipe", {}).get("parameters", {}).get("pattern", {}).get("kind", "modes")
        title = f"{os.path.basename(stem_path)}  |  recipe: {recipe}  |  pattern: {kind}  |  {len(frags)} fragments"
        fig.suptitle(title, fontsize=10, y=0.985)
    else:
        grid = fig.add_gridspec(2, 4, height_ratios=[1.0, 1.0], hspace=0.12, wspace=0.02,
                                left=0.01, right=0.99, top=0.9, bottom=0.02)
        _draw_input(fig.add_subplot(grid[0, 0]), frags, view, height // 2)
        _draw_exploded(fig.add_subplot(grid[0, 1:3]), frags, view, height // 2)
        groups = _draw_impact(fig.add_subplot(grid[0, 3]), data, frags, view, impact, height // 2)
        k = min(data.k, max_modes)
        sub = grid[1, :].subgridspec(1, max(k, 1), wspace=0.02)
        for i in range(k):
            _draw_mode(fig.add_subplot(sub[0, i]), data, frags, view, i, width // max(k, 1))
        title = (f"{os.path.basename(stem_path)}  |  recipe: {recipe}  |  {len(frags)} fragments, {data.k} modes, "
                 f"{counts.get('tets', '?')} tets, cage {counts.get('cage_faces', '?')} faces  |  "
                 f"radius {data.radius:g}, threshold {data.default_threshold:g}")
        fig.suptitle(title, fontsize=13)
    with atomic_path(png_path) as tmp:
        # The title also as the PNG's Title text, so it can be read back without looking at pixels.
        fig.savefig(tmp, format="png", dpi=100, metadata={"Software": None, "Title": title})
    plt.close(fig)
    return {"fragments": len(frags), "modes_drawn": k, "impact_groups": groups, "title": title}


@dataclass(frozen=True)
class _View:
    """Where the preview's panels look: the assembled asset's centre, radius and fragment centroids."""

    center: np.ndarray
    radius: float
    centroids: np.ndarray


def _draw_input(ax: Any, frags: list, view: _View, pixels: int) -> None:
    """The asset as it looks: outer faces only, its own materials."""
    tris = np.concatenate([f.outer for f in frags])
    draw_triangles(ax, tris, np.concatenate([f.outer_colors for f in frags]), center=view.center,
                   extent=view.radius * 1.05, pixels=pixels)
    ax.set_title("input", fontsize=11)


def _draw_assembled(ax: Any, frags: list, view: _View, pixels: int) -> None:
    """The asset assembled, each fragment's outer faces in its colour (the pattern as it shows on the surface)."""
    colors = palette(len(frags))
    cols = [np.repeat(colors[j][None], len(f.outer), 0) for j, f in enumerate(frags)]
    draw_triangles(ax, np.concatenate([f.outer for f in frags]), np.concatenate(cols), center=view.center,
                   extent=view.radius * 1.05, pixels=pixels)
    ax.set_title("fragments", fontsize=9)


def _draw_exploded(ax: Any, frags: list, view: _View, pixels: int, fontsize: int = 11, title: str = "") -> None:
    """Exploded fragments, interior faces tinted darker."""
    colors = palette(len(frags))
    push = (view.centroids - view.center) * 0.6
    tris: list[np.ndarray] = []
    cols: list[np.ndarray] = []
    for j, f in enumerate(frags):
        tris += [f.outer + push[j], f.inner + push[j]]
        cols += [np.repeat(colors[j][None], len(f.outer), 0), np.repeat((colors[j] * 0.55)[None], len(f.inner), 0)]
    draw_triangles(ax, np.concatenate(tris), np.concatenate(cols), center=view.center, extent=view.radius * 1.7,
                   pixels=pixels)
    ax.set_title(title or f"{len(frags)} fragments (exploded; darker = interior faces)", fontsize=fontsize)


def _draw_impact(ax: Any, data: Any, frags: list, view: _View, impact: tuple | None, pixels: int,
                 fontsize: int = 11) -> int:
    """An impact (given, or :func:`pick_example_impact`) and the groups it breaks into; returns their number."""
    # on first use: the viewer's start-up loads no geometry
    from fracture_cli.runtime.impact import project_impact

    if impact is None:
        point, impulse, result = pick_example_impact(data, view.center)
    else:
        point, impulse, threshold = impact
        point, impulse = np.asarray(point, float), np.asarray(impulse, float)
        result = project_impact(data, point, impulse, threshold)
    group_ids, group_of = np.unique(result.groups, return_inverse=True)
    gcol = palette(len(group_ids))
    gcent = np.array([view.centroids[group_of == g].mean(axis=0) for g in range(len(group_ids))])
    gpush = (gcent - view.center) * 0.35 if len(group_ids) > 1 else np.zeros_like(gcent)
    tris = [np.concatenate([f.outer, f.inner]) + gpush[group_of[j]] for j, f in enumerate(frags)]
    cols = [np.repeat(gcol[group_of[j]][None], len(tris[j]), 0) for j in range(len(frags))]
    bias = [np.r_[np.zeros(len(f.outer)), np.full(len(f.inner), 0.02 * view.radius)] for f in frags]
    draw_triangles(ax, np.concatenate(tris), np.concatenate(cols), center=view.center, extent=view.radius * 1.35,
                   pixels=pixels, depth_bias=np.concatenate(bias))
    p2 = project(point[None], view.center)[0]
    tail = project((point - impulse / max(np.linalg.norm(impulse), 1e-12) * view.radius * 0.6)[None], view.center)[0]
    ax.annotate("", xy=p2, xytext=tail, arrowprops=dict(arrowstyle="-|>", color="crimson", lw=2.5))
    ax.plot([p2[0]], [p2[1]], "o", color="crimson", ms=7)
    ax.set_title(f"impact |n|={np.linalg.norm(impulse):.3g}: {len(group_ids)} group(s)", fontsize=fontsize)
    return int(len(group_ids))


def _draw_mode(ax: Any, data: Any, frags: list, view: _View, i: int, pixels: int) -> None:
    """Mode ``i``: fragments coloured by their mode displacement (outer faces only: inner faces lie inside
    the assembled object and, with painter's ordering, would speckle through its surface)."""
    import matplotlib

    W = np.asarray(data.W, dtype=np.float64)
    w = W[i, :, 0] if data.dim == 1 else np.linalg.norm(W[i], axis=1) * np.sign(W[i, :, 0] + 1e-30)
    scale = max(np.abs(w).max(), 1e-30)
    fc = matplotlib.colormaps["coolwarm"](0.5 + 0.5 * w / scale)[:, :3]
    tris = [f.outer for f in frags]
    cols = [np.repeat(fc[j][None], len(tris[j]), 0) for j in range(len(frags))]
    draw_triangles(ax, np.concatenate(tris), np.concatenate(cols), center=view.center, extent=view.radius * 1.05,
                   pixels=pixels)
    ax.set_title(f"mode {i + 1}", fontsize=10)
