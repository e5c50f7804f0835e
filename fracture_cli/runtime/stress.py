"""The stress criterion at runtime (format version 2, feature ``"stress"``; docs/FORMAT.md section 11).

A hit at site ``v`` with scaled impulse ``n'`` (docs/FORMAT.md section 4, steps 1-2)
breaks bond ``e`` of the site's list when its tensile gain exceeds its strength at
the scaled threshold ``t = T / m``:

``g = (G0 * n'0 + G1 * n'1) + G2 * n'2``, broken when ``g > t * S_e``

with ``(G0, G1, G2) = site_bond_gain[j]`` for the list entry ``j`` of bond ``e``
and ``S_e = bond_strength[e]``; every bond not in the site's list holds. This is
``L_e = max(0, G . n') * m / (T * S_e) > 1`` of the v2 design, evaluated without
forming ``m * G`` or ``T * S_e`` so that it is scale-invariant like version 1.

Depends on numpy only.
"""

from __future__ import annotations

import math

import numpy as np

# name -> (dtype, number of dimensions), in file order (after the game-ready arrays).
STRESS_LAYOUT: dict[str, tuple[str, int]] = {
    "site_bonds_ptr": ("int32", 1),
    "site_bonds": ("int32", 1),
    "site_bond_gain": ("float32", 2),
    "bond_strength": ("float32", 1),
}
# Feature "sharing" (docs/FORMAT.md section 11.1): the fragment each site loads, after the four above.
SHARING_LAYOUT: dict[str, tuple[str, int]] = {"site_fragment": ("int32", 1)}
KNOWN_FEATURES: tuple[str, ...] = ("anchors", "damage", "levels", "sharing", "stress")
"""The ``features`` this reader implements (``"anchors"`` and ``"damage"``: :mod:`fracture_cli.runtime.structure`;
``"levels"``: :mod:`fracture_cli.runtime.levels`; ``"sharing"``: :class:`PreparedStress`)."""
CRITERIA: tuple[str, ...] = ("modes", "stress")


def header_features(header: dict, version: int) -> tuple[tuple[str, ...], str]:
    """The header's ``features`` and ``criterion`` (docs/FORMAT.md section 11).

    Raises
    ------
    ValueError
        With the reason: ``features`` malformed or empty in version 2, a feature or criterion this reader
        does not implement (named), or criterion ``"stress"`` without the feature.
    """
    features = header.get("features", []) if version >= 2 else []
    if not isinstance(features, list) or not all(isinstance(f, str) for f in features):
        raise ValueError("runtime header 'features' must be a list of strings")
    if version >= 2 and not features:  # version 2 exists only for its features (notes/runtime-format-v2.md)
        raise ValueError(f"runtime file version {version} lists no features; a file without any is version 1")
    for name in features:
        if name not in KNOWN_FEATURES:
            raise ValueError(f"runtime file needs feature {name!r}, which this reader does not implement")
    criterion = header.get("criterion", "modes") if version >= 2 else "modes"
    if criterion not in CRITERIA:
        raise ValueError(f"runtime file needs criterion {criterion!r}, which this reader does not implement")
    if criterion == "stress" and "stress" not in features:
        raise ValueError("runtime file has criterion 'stress' but does not list feature 'stress'")
    if "sharing" in features and criterion != "stress":
        raise ValueError("runtime file has feature 'sharing' without criterion 'stress'")
    return tuple(features), str(criterion)


def check_sharing(sharing: dict, site_fragment: np.ndarray | None, s: int, p: int) -> str | None:
    """Why the feature ``"sharing"``'s object and array do not fit ``s`` sites and ``p`` fragments, or None.

    Parameters
    ----------
    sharing : dict
        The header's ``sharing`` object: ``concentration`` a finite number > 0.
    site_fragment : (s,) int or None
        Values in ``0 .. p-1``.
    """
    kappa = sharing.get("concentration")
    if isinstance(kappa, bool) or not isinstance(kappa, (int, float)) or not math.isfinite(kappa) or kappa <= 0:
        return f"sharing.concentration must be a finite number > 0, got {kappa!r}"
    if site_fragment is None:
        return "the feature 'sharing' needs the array site_fragment"
    fragment = np.asarray(site_fragment)
    if fragment.shape != (s,):
        return f"array site_fragment has shape {list(fragment.shape)}, expected [{s}]"
    if s and (fragment.min() < 0 or fragment.max() >= p):
        return f"site_fragment must be fragment indices in 0..{p - 1}"
    return None


def check_stress(arrays: dict[str, np.ndarray], s: int, e: int) -> str | None:
    """Why the stress arrays are inconsistent with ``s`` sites and ``e`` bonds, or None.

    Checks: all four present; ``site_bonds_ptr`` has ``s + 1`` entries, starts at 0, never decreases
    and ends at ``nnz``; ``site_bonds`` has ``nnz`` entries in ``0..e-1``, strictly ascending within a site;
    ``site_bond_gain`` is ``(nnz, 3)`` and finite; ``bond_strength`` is ``(e,)``, finite and ``>= 0``.
    """
    missing = [name for name in STRESS_LAYOUT if name not in arrays]
    if missing:
        return f"the stress criterion needs {', '.join(missing)}"
    ptr = np.asarray(arrays["site_bonds_ptr"], dtype=np.int64)
    bonds = np.asarray(arrays["site_bonds"], dtype=np.int64)
    gain = np.asarray(arrays["site_bond_gain"])
    strength = np.asarray(arrays["bond_strength"])
    nnz = len(bonds)
    if ptr.shape != (s + 1,) or ptr[0] != 0 or ptr[-1] != nnz or np.any(np.diff(ptr) < 0):
        return f"site_bonds_ptr must have {s + 1} entries, start at 0, never decrease and end at {nnz}"
    if gain.shape != (nnz, 3):
        return f"array site_bond_gain has shape {list(gain.shape)}, expected [{nnz}, 3]"
    if strength.shape != (e,):
        return f"array bond_strength has shape {list(strength.shape)}, expected [{e}]"
    if nnz and (bonds.min() < 0 or bonds.max() >= e):
        return f"site_bonds must be bond indices in 0..{e - 1}"
    if nnz > 1:
        step = np.diff(bonds) > 0
        starts = ptr[1:-1]
        starts = starts[(starts > 0) & (starts < nnz)]
        step[starts - 1] = True  # a new site may start anywhere
        if not step.all():
            return "site_bonds must be strictly ascending within each site"
    if not (np.all(np.isfinite(gain)) and np.all(np.isfinite(strength))):
        return "arrays site_bond_gain and bond_strength must be finite"
    if np.any(strength < 0):
        return "bond_strength must be >= 0"
    return None


class PreparedStress:
    """Float64 copies of the stress arrays for fast per-hit evaluation (and section 11.1's sharing)."""

    def __init__(self, arrays: dict[str, np.ndarray], e: int, edges: np.ndarray | None = None,
                 areas: np.ndarray | None = None, sharing: dict | None = None):
        self.e = e
        self.sharing: Sharing | None = None
        if sharing and edges is not None and areas is not None:
            self.sharing = Sharing(arrays["site_fragment"], edges, areas, float(sharing["concentration"]))
        self.ptr = np.asarray(arrays["site_bonds_ptr"], dtype=np.int64)
        self.bonds = np.asarray(arrays["site_bonds"], dtype=np.int64)
        gain = np.asarray(arrays["site_bond_gain"], dtype=np.float64)
        self.g0, self.g1, self.g2 = (np.ascontiguousarray(gain[:, c]) for c in range(3))
        self.strength = np.asarray(arrays["bond_strength"], dtype=np.float64)

    def gains(self, site: int, nx: float, ny: float, nz: float) -> tuple[np.ndarray, np.ndarray]:
        """(bonds, g) of the site's list for the scaled impulse ``n'``: ``g = (G0 n'0 + G1 n'1) + G2 n'2``."""
        lo, hi = int(self.ptr[site]), int(self.ptr[site + 1])
        g = self.g0[lo:hi] * nx
        g += self.g1[lo:hi] * ny
        g += self.g2[lo:hi] * nz
        return self.bonds[lo:hi], g


class Sharing:
    """Load sharing among the struck fragment's bonds (feature ``"sharing"``, docs/FORMAT.md section 11.1).

    Parameters
    ----------
    site_fragment : (s,) int
        The fragment each site loads.
    edges : (e, 2) int
        The bonds.
    areas : (e,) float
        Their fault areas (``edge_areas``).
    concentration : float
        ``kappa > 0``.
    """

    def __init__(self, site_fragment: np.ndarray, edges: np.ndarray, areas: np.ndarray, concentration: float):
        self.site_fragment = np.asarray(site_fragment, dtype=np.int64)
        edges = np.asarray(edges, dtype=np.int64).reshape(-1, 2)
        self.areas = np.asarray(areas, dtype=np.float64).tolist()
        self.kappa = float(concentration)
        p = int(max(edges.max() + 1 if len(edges) else 0, self.site_fragment.max() + 1 if len(self.site_fragment)
                    else 0))
        self.incident: list[list[int]] = [[] for _ in range(p)]
        for index, (a, b) in enumerate(edges.tolist()):  # increasing bond index per fragment
            self.incident[a].append(index)
            self.incident[b].append(index)

    def share(self, site: int, measure: np.ndarray, bound: np.ndarray, broken_before: np.ndarray | None
              ) -> np.ndarray:
        """Section 11.1's passes: the measure (e,) float64 after the struck fragment's bonds share their load.

        Parameters
        ----------
        site : int
            The hit's site.
        measure : (e,) float64
            ``a0``: section 11's ``g`` for the site's bonds, 0 for the others (not modified).
        bound : (e,) float64
            ``b = t * S``.
        broken_before : (e,) bool or None
            Bonds already broken (a damage state's ``health <= 0``), None for none.

        Returns
        -------
        (e,) float64
            The measure ``a``: ``a0`` off the struck fragment, the pass values on it.
        """
        bonds = self.incident[int(self.site_fragment[site])]
        a0 = [float(measure[e]) for e in bonds]
        b = [float(bound[e]) for e in bonds]
        area = [self.areas[e] for e in bonds]
        out = [x > y or (broken_before is not None and bool(broken_before[e])) for e, x, y in zip(bonds, a0, b)]
        a = list(a0)
        while True:
            load, held = 0.0, 0.0  # sums in increasing bond order, as the spec says
            for i in range(len(bonds)):
                if out[i]:
                    load = load + max(a0[i], 0.0)
            for i in range(len(bonds)):
                if not out[i]:
                    held = held + area[i]
            if load == 0.0 or held == 0.0:
                break
            q = (self.kappa * load) / held
            new = []
            for i in range(len(bonds)):
                if not out[i]:
                    a[i] = a0[i] + q * area[i]  # Python floats: overflow gives inf, inf * 0 NaN (holds)
                    if a[i] > b[i]:
                        new.append(i)
            if not new:
                break
            for i in new:
                out[i] = True
        result = np.array(measure, dtype=np.float64, copy=True)
        result[bonds] = a
        return result
