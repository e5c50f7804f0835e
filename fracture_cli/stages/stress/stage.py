"""The stress criterion's arrays of the runtime file: sparse per-site bond gains and bond strengths.

Called by the ``runtime`` stage when the recipe says ``runtime.criterion = "stress"``
(docs/ALGORITHM.md "Stress criterion", docs/FORMAT.md section 11).

What is stored, per contact site ``v`` (CSR over sites):

* ``site_bond_gain[j, :] = G[v, e, :]``: the normal force across bond ``e``'s fault
  (mean normal traction times the bond's fault area ``A_e``, positive = tension) per
  unit force along x, y, z at site ``v``; the bonds of site ``v`` are
  ``site_bonds[site_bonds_ptr[v] : site_bonds_ptr[v + 1]]``, ascending;
* at most ``max_bonds`` bonds per site (the most loaded), and only bonds with
  ``|G[v, e, :]| / S_e >= keep * max_e' |G[v, e', :]| / S_e'`` (the bonds the site
  can load to at least ``keep`` of its most loaded bond's load);
* ``bond_strength[e] = S_e`` (:mod:`fracture_cli.stages.stress.bonds`).

Determinism: the one sparse factorization and its back-substitutions may round
differently with another BLAS kernel (SuperLU calls BLAS on its supernodes); the
bake pins the kernels (:mod:`fracture_cli.system.numeric_env`), and on top of that every
stored gain and strength is rounded to :data:`SIGNIFICANT_BITS` significant bits
(an exact operation: ``frexp``, ``rint``, ``ldexp``) before it becomes float32 and
before any keep/drop decision, so a last-bit difference of the solve changes a
stored byte only when it straddles a rounding boundary (about ``1e-11 / 2^-12``
per value), not whenever it happens.
"""

from __future__ import annotations

import dataclasses
import logging
import time
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from fracture_cli.errors import StageError
from fracture_cli.geometry.parts import nearest_parts, part_planes
from fracture_cli.stages.stress.blocks import block_tractions, most_loaded_block
from fracture_cli.stages.stress.bonds import (
    BondFaces,
    ContactPoints,
    bond_faces,
    bond_strengths,
    contact_points,
    split_into_patches,
    tet_fragments,
)
from fracture_cli.stages.stress.gains import site_bond_tractions, site_patches
from fracture_cli.types import Fragments, Pieces, TetMesh

if TYPE_CHECKING:  # the runtime stage imports this module
    from fracture_cli.runtime.format import RuntimeData
    from fracture_cli.stages.runtime import RuntimeOptions

log = logging.getLogger(__name__)

SIGNIFICANT_BITS = 12
"""Stored gains and strengths keep this many significant bits (relative step 2^-12 = 2.4e-4)."""


@dataclass(frozen=True)
class StressParameters:
    """The material parameters of the stress criterion (recipe ``[runtime]`` keys).

    Attributes
    ----------
    youngs_modulus : float
        ``E`` (any unit; the stress of a free body under balanced loads does not depend on it).
    poisson_ratio : float
        ``nu``, ``-1 < nu < 0.5``.
    tensile_strength : float
        ``sigma_t`` per unit area of the asset normalized to a unit bounding-box diagonal, in impulse units.
    keep : float
        Fraction of a site's strongest bond load below which a bond is left out of its list.
    max_bonds : int
        At most this many bonds per site (the most loaded; ties by bond index); 0 = no limit.
    radius : float
        Load patch radius, fraction of the bounding-box diagonal.
    reach : float
        How far the impact's stress wave runs during the contact, fraction of the diagonal
        (:func:`fracture_cli.stages.stress.gains.site_bond_tractions`); 0 = quasi-static (inertia relief).
    patches : int
        Each fault is cut into ``patches x patches`` quadrant patches
        (:func:`fracture_cli.stages.stress.bonds.split_into_patches`); 1 = the whole fault's mean traction.
    model : {"tets", "blocks"}
        What responds to the hit: linear elasticity on the tet mesh
        (:func:`fracture_cli.stages.stress.gains.site_bond_tractions`), or the fragments as rigid blocks held by
        elastic faults, the load on the fragment each site lands on
        (:func:`fracture_cli.stages.stress.blocks.block_tractions`).
    measure : {"tension_shear", "tension"}
        What loads a bond: ``"tension"``, the normal traction ``n . sigma n`` (Rankine on the fault plane);
        ``"tension_shear"``, the traction vector without its compressive part, ``|sigma n - min(0, s_nn) n|``,
        along its direction under an inward hit (:func:`shear_gains`).
    """

    youngs_modulus: float = 1.0
    poisson_ratio: float = 0.25
    tensile_strength: float = 1.0
    keep: float = 0.05
    max_bonds: int = 48
    radius: float = 0.05
    reach: float = 0.05
    patches: int = 2
    measure: str = "tension_shear"
    model: str = "blocks"


def round_bits(values: np.ndarray, bits: int = SIGNIFICANT_BITS) -> np.ndarray:
    """``values`` rounded to ``bits`` significant bits (ties to even), exactly; zeros and signs kept.

    Parameters
    ----------
    values : array of float64
    bits : int

    Returns
    -------
    float64 array of the same shape
    """
    mantissa, exponent = np.frexp(np.asarray(values, dtype=np.float64))
    return np.ldexp(np.rint(np.ldexp(mantissa, bits)), exponent - bits)


def stress_arrays(tet_mesh: TetMesh, pieces: Pieces, fragments: Fragments, eta: np.ndarray | None, edges: np.ndarray,
                  edge_areas: np.ndarray, parameters: StressParameters,
                  site_owner: np.ndarray | None = None) -> dict[str, np.ndarray]:
    """The four stress arrays of the runtime file (module docstring).

    Parameters
    ----------
    tet_mesh : TetMesh
        The bake's tet mesh (normalized coordinates); its boundary vertices are the contact sites.
    pieces : Pieces
    fragments : Fragments
        The exported fragments (their ``piece`` and meshes).
    eta : (f,) or (f, d) float or None
        Material weights of the interior tet faces.
    edges : (e, 2) int
        The runtime file's bonds.
    edge_areas : (e,) float
        Their fault areas, normalized units squared.
    parameters : StressParameters
    site_owner : (s,) int, optional
        The fragment every contact site lands on (the one whose collision parts are nearest, as a game's
        collider reports it): ``model = "blocks"`` loads it; by default the fragment with the most of the
        site's load spread.

    Returns
    -------
    dict
        ``site_bonds_ptr (s + 1,) int32``, ``site_bonds (nnz,) int32``, ``site_bond_gain (nnz, 3) float32``,
        ``bond_strength (e,) float32``, and ``site_fragment (s,) int32``: ``site_owner`` (feature ``"sharing"``).
    """
    started = time.perf_counter()
    edges = np.asarray(edges, dtype=np.int64).reshape(-1, 2)
    areas = np.asarray(edge_areas, dtype=np.float64).reshape(-1)
    sites = np.asarray(tet_mesh.boundary_vertices, dtype=np.int64)
    owner = tet_fragments(tet_mesh, pieces, [f.piece for f in fragments.fragments],
                          [f.vertices for f in fragments.fragments])
    faces = bond_faces(tet_mesh, owner, edges)
    faceless = np.flatnonzero(faces.face_area == 0.0)
    contacts = contact_points(tet_mesh, fragments, edges, faceless) if len(faceless) else None
    patches, patch_bond = split_into_patches(tet_mesh, faces, parameters.patches)
    if contacts is not None:
        # A bond without tet faces has exactly one (empty) patch: measure it at the contact points.
        patch_of = np.full(len(edges), -1, dtype=np.int64)
        patch_of[patch_bond[::-1]] = np.arange(len(patch_bond))[::-1]
        contacts = dataclasses.replace(contacts, bond=patch_of[contacts.bond])
    vector = parameters.measure == "tension_shear"
    spread = site_patches(tet_mesh, sites, parameters.radius).T.tocsr()
    if site_owner is None:
        site_owner = most_loaded_block(tet_mesh, owner, spread, max(int(owner.max()) + 1, len(fragments.fragments)))
    if parameters.model == "blocks":
        traction = block_tractions(tet_mesh, owner, patches, edges[patch_bond],
                                   patch_normals(tet_mesh, patches, contacts, len(patch_bond)),
                                   spread, parameters.reach, parameters.poisson_ratio, contacts, vector, site_owner)
    else:
        traction = site_bond_tractions(tet_mesh, patches, sites, parameters.radius, parameters.youngs_modulus,
                                       parameters.poisson_ratio, contacts, parameters.reach, vector)  # (s, 3, P|3P)
    strength = round_bits(bond_strengths(faces, eta, areas, parameters.tensile_strength))
    score = None
    if vector:
        traction, score = shear_gains(tet_mesh, traction, patches, contacts, sites, len(patch_bond))
    patch_gain = round_bits(traction * areas[patch_bond][None, None, :])
    gain = most_loaded_patch(patch_gain, patch_bond, len(edges),
                             None if score is None else round_bits(score * areas[patch_bond][None, :]))
    ptr, bonds, kept = sparsify(gain, strength, parameters.keep, parameters.max_bonds)
    unmeasured = len(faceless) - (0 if contacts is None else len(np.unique(contacts.bond)))
    log.info("runtime: stress gains for %d sites x %d bonds, %d kept (%.1f per site), %d bond(s) measured at "
             "contact points, %d unmeasured, %.2fs", len(sites), len(edges), len(bonds),
             len(bonds) / max(len(sites), 1), len(faceless) - unmeasured, unmeasured, time.perf_counter() - started)
    return {
        "site_bonds_ptr": ptr.astype(np.int32),
        "site_bonds": bonds.astype(np.int32),
        "site_bond_gain": kept.astype(np.float32),
        "bond_strength": strength.astype(np.float32),
        "site_fragment": np.asarray(site_owner, dtype=np.int32),
    }


def shear_gains(tet_mesh: TetMesh, traction: np.ndarray, patches: BondFaces, contacts: ContactPoints | None,
                sites: np.ndarray, count: int) -> tuple[np.ndarray, np.ndarray]:
    """Linear gains of the tension-and-shear load of every patch, frozen at an inward hit.

    Parameters
    ----------
    traction : (s, 3, 3P) float64
        Mean traction vectors (entry ``3 p + c``) per unit force along each axis at each site.

    Returns
    -------
    gains : (s, 3, P) float64
        ``w . t_k`` with ``t_k`` the patch's traction for a unit force along axis ``k`` and ``w`` the unit
        direction of ``t_eff = t(u) - min(0, n . t(u)) n`` for the inward unit impulse ``u`` at the site
        (towards the tet mesh's centroid): the traction without its compressive part. For the inward hit
        ``G . u = |t_eff|`` (shear and tension load the bond, compression does not); other directions are
        measured along the same ``w`` (linear, as the runtime needs).
    score : (s, P) float64
        ``|t_eff|`` for the inward hit.
    """
    s = traction.shape[0]
    T = traction.reshape(s, 3, count, 3)  # [v, k, p, c]
    V = tet_mesh.vertices
    centroid = tet_mesh.tet_centroids
    volume = np.abs(tet_mesh.tet_volumes)
    center = np.array([float((volume * centroid[:, c]).sum()) for c in range(3)]) / float(volume.sum())
    inward = center[None, :] - V[np.asarray(sites, dtype=np.int64)]
    length = np.sqrt((inward[:, 0] * inward[:, 0] + inward[:, 1] * inward[:, 1]) + inward[:, 2] * inward[:, 2])
    inward = inward / np.where(length > 0.0, length, 1.0)[:, None]
    normal = patch_normals(tet_mesh, patches, contacts, count)  # (P, 3)
    t = (T[:, 0] * inward[:, 0, None, None] + T[:, 1] * inward[:, 1, None, None]) + T[:, 2] * inward[:, 2, None, None]
    snn = (t[:, :, 0] * normal[None, :, 0] + t[:, :, 1] * normal[None, :, 1]) + t[:, :, 2] * normal[None, :, 2]
    eff = t - np.minimum(snn, 0.0)[:, :, None] * normal[None, :, :]
    mag = np.sqrt((eff[:, :, 0] * eff[:, :, 0] + eff[:, :, 1] * eff[:, :, 1]) + eff[:, :, 2] * eff[:, :, 2])
    w = eff / np.where(mag > 0.0, mag, 1.0)[:, :, None]
    gains = (T[:, :, :, 0] * w[:, None, :, 0] + T[:, :, :, 1] * w[:, None, :, 1]) + T[:, :, :, 2] * w[:, None, :, 2]
    return gains, mag


def patch_normals(tet_mesh: TetMesh, patches: BondFaces, contacts: ContactPoints | None, count: int) -> np.ndarray:
    """Unit mean normal (P, 3) of every patch, oriented from the bond's fragment ``P`` to ``Q``."""
    normals = tet_mesh.interior_face_normals[patches.faces] * (patches.sign * patches.weight)[:, None]
    total = np.stack([np.bincount(patches.bond, weights=normals[:, c], minlength=count) for c in range(3)], axis=1)
    if contacts is not None and len(contacts.bond):
        extra = contacts.normal * contacts.weight[:, None]
        total += np.stack([np.bincount(contacts.bond, weights=extra[:, c], minlength=count) for c in range(3)], 1)
    length = np.sqrt((total[:, 0] * total[:, 0] + total[:, 1] * total[:, 1]) + total[:, 2] * total[:, 2])
    return total / np.where(length > 0.0, length, 1.0)[:, None]


def most_loaded_patch(gain: np.ndarray, patch_bond: np.ndarray, e: int, score: np.ndarray | None = None
                      ) -> np.ndarray:
    """Per site and bond, the gain (s, 3, e) of the bond's most loaded patch (ties: the first).

    The load is ``score`` (s, P) when given, else ``|G[v, p, :]|``, the most a unit impulse at ``v`` can
    load the patch (in the direction of ``G``): the site keeps, for each bond, the patch it loads the most.
    """
    s = gain.shape[0]
    norm = (np.sqrt((gain[:, 0] * gain[:, 0] + gain[:, 1] * gain[:, 1]) + gain[:, 2] * gain[:, 2])
            if score is None else score)  # (s, P)
    out = np.zeros((s, 3, e))
    rows = np.arange(s)
    for bond in range(e):
        mine = np.flatnonzero(patch_bond == bond)
        if not len(mine):
            continue
        best = mine[norm[:, mine].argmax(axis=1)]  # argmax: the first maximum, the smallest patch index
        out[:, :, bond] = gain[rows, :, best]
    return out


def sparsify(gain: np.ndarray, strength: np.ndarray, keep: float, max_bonds: int = 0
             ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The CSR form of the bonds each site loads enough (module docstring).

    Parameters
    ----------
    gain : (s, 3, e) float64
        Rounded gains.
    strength : (e,) float64
        Rounded strengths (> 0 for a bond to be kept).
    keep : float
        In [0, 1].
    max_bonds : int, optional (default 0: no limit)
        Keep at most this many per site, the most loaded (ties: the smaller bond index).

    Returns
    -------
    ptr : (s + 1,) int64
    bonds : (nnz,) int64
        Ascending within each site.
    values : (nnz, 3) float64
    """
    s, _, e = gain.shape
    norm = np.sqrt((gain[:, 0] * gain[:, 0] + gain[:, 1] * gain[:, 1]) + gain[:, 2] * gain[:, 2])  # (s, e)
    positive = strength > 0.0
    load = np.where(positive[None, :], norm / np.where(positive, strength, 1.0)[None, :], 0.0)
    strongest = load.max(axis=1) if e else np.zeros(s)
    mask = (load > 0.0) & (load >= keep * strongest[:, None])
    if 0 < max_bonds < e:
        # Rank of every bond within its site by decreasing load, ties by index (a stable sort).
        order = np.argsort(-load, axis=1, kind="stable")
        rank = np.empty_like(order)
        np.put_along_axis(rank, order, np.arange(e)[None, :].repeat(s, axis=0), axis=1)
        mask &= rank < max_bonds
    ptr = np.zeros(s + 1, dtype=np.int64)
    ptr[1:] = np.cumsum(mask.sum(axis=1))
    site_index, bonds = np.nonzero(mask)  # row-major: sites ascending, bonds ascending within a site
    return ptr, bonds.astype(np.int64), gain[site_index, :, bonds]


def with_stress(data: RuntimeData, tet_mesh: TetMesh, pieces: Pieces, fragments: Fragments, eta: np.ndarray | None,
                graph: tuple[np.ndarray, np.ndarray], options: RuntimeOptions,
                parts: tuple | None = None) -> RuntimeData:
    """``data`` (RuntimeData) with the stress criterion's arrays, criterion ``"stress"`` and its parameters.

    Parameters
    ----------
    data : RuntimeData
        The runtime stage's output; its ``edges`` are ``graph``'s, sorted.
    tet_mesh, pieces, fragments, eta
        As :func:`stress_arrays`.
    graph : ((e, 2) int, (e,) float)
        The fragment graph (normalized areas) the runtime data was built from.
    options : RuntimeOptions
    parts : tuple of tuple of (k, 3) float, optional
        Every fragment's convex collision parts, model space (as ``data.sites``): each site lands on the
        fragment whose parts are nearest it (``stress_model = "blocks"`` loads it; ``load_sharing`` shares
        among its bonds).
    """
    edges = np.asarray(graph[0], dtype=np.int64).reshape(-1, 2)
    areas = np.asarray(graph[1], dtype=np.float64).reshape(-1)
    sort = np.lexsort((edges[:, 1], edges[:, 0]))
    edges, areas = edges[sort], areas[sort]
    if not np.array_equal(edges, np.asarray(data.edges, dtype=np.int64)):
        raise StageError("the stress criterion's bonds are not the runtime file's edges", stage="runtime")
    parameters = StressParameters(youngs_modulus=float(options.youngs_modulus),
                                  poisson_ratio=float(options.poisson_ratio),
                                  tensile_strength=float(options.tensile_strength), keep=float(options.stress_keep),
                                  max_bonds=int(options.stress_max_bonds), radius=float(options.radius),
                                  reach=float(options.stress_reach), measure=str(options.stress_measure),
                                  model=str(options.stress_model))
    owner = None
    if parts is not None:
        planes = part_planes(parts)
        if planes is not None:
            owner = nearest_parts(planes, np.asarray(data.sites, dtype=np.float64))
    arrays = stress_arrays(tet_mesh, pieces, fragments, eta, edges, areas, parameters, owner)
    sharing: dict = {}
    if float(options.load_sharing) > 0.0:  # docs/FORMAT.md section 11.1
        sharing = {"concentration": float(options.load_sharing)}
    else:
        del arrays["site_fragment"]
    info = {"youngs_modulus": parameters.youngs_modulus, "poisson_ratio": parameters.poisson_ratio,
            "tensile_strength": parameters.tensile_strength, "keep": parameters.keep,
            "max_bonds": parameters.max_bonds, "reach": parameters.reach, "measure": parameters.measure,
            "model": parameters.model,
            "significant_bits": SIGNIFICANT_BITS}
    return dataclasses.replace(data, criterion="stress", stress=arrays, stress_info=info, sharing=sharing)
