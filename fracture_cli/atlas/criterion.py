"""Breaking impulses: the impulse magnitude at which each bond breaks for one hit.

A *criterion* is a function ``(data, site, direction) -> (e,) magnitudes``: for a
hit at contact site ``site`` with unit impulse direction ``direction``, entry
``m[e]`` is the smallest impulse magnitude ``|n|`` at which bond (graph edge)
``e`` breaks, ``+inf`` if it never does. Everything else in
:mod:`fracture_cli.atlas` (first break, first detachment, groups at any
magnitude, the sweep's figures) is derived from these magnitudes and the
fragment graph, so another criterion (a stress criterion) plugs in by adding one
function to :data:`CRITERIA` (the ``stress`` criterion, docs/FORMAT.md section 11, is one);
it only has to be *monotone*: a bond broken at
some magnitude stays broken at every larger one.

The ``modes`` criterion is the runtime algorithm of docs/FORMAT.md section 4.
Its jump across bond ``e = (P, Q)`` is linear in the impulse magnitude ``M``:

* ``d = 1``: ``jump = M * |J[v, e]|``, ``J[v, e] = sum_i B[v, i, 0] * (W[i, P, 0] - W[i, Q, 0])``;
* ``d = 3``: ``jump = M * |g|``, ``g = sum_i (B[v, i, :] . u) * (W[i, P, :] - W[i, Q, :])``;

and the bond breaks when ``jump > T`` (strictly), so ``m[e] = T / |J|`` (or
``T / |g|``), exactly up to one rounding, with ``T`` the file's default
threshold. A bond with zero response never breaks (``+inf``), whatever ``T``.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from fracture_cli.errors import UsageError
from fracture_cli.runtime.format import RuntimeData

BreakingImpulses = Callable[[RuntimeData, int, np.ndarray], np.ndarray]
"""Signature of a criterion: ``(data, site, unit direction (3,)) -> (e,) float64 magnitudes``."""


def bond_response(data: RuntimeData, site: int, direction: np.ndarray) -> np.ndarray:
    """Jump across every bond per unit impulse magnitude, modes criterion.

    Parameters
    ----------
    data : RuntimeData
    site : int
        Contact site index, ``0 <= site < s``.
    direction : (3,) float
        Unit impulse direction, model axes (ignored for ``d = 1``, where only
        the magnitude counts).

    Returns
    -------
    (e,) float64
        ``|J[site, e]|`` (d = 1) or ``|g_e|`` (d = 3), >= 0.
    """
    B = np.asarray(data.B[site], dtype=np.float64)  # (k, d)
    W = np.asarray(data.W, dtype=np.float64)  # (k, p, d)
    edges = np.asarray(data.edges, dtype=np.int64)
    dW = W[:, edges[:, 0], :] - W[:, edges[:, 1], :]  # (k, e, d)
    if data.dim == 1:
        return np.abs(B[:, 0] @ dW[:, :, 0])
    u = np.asarray(direction, dtype=np.float64)
    alpha = (B[:, 0] * u[0] + B[:, 1] * u[1]) + B[:, 2] * u[2]  # (k,), docs/FORMAT.md section 4 step 3
    g = np.einsum("i,iec->ec", alpha, dW)
    return np.sqrt((g[:, 0] * g[:, 0] + g[:, 1] * g[:, 1]) + g[:, 2] * g[:, 2])


def modes_breaking_impulses(data: RuntimeData, site: int, direction: np.ndarray) -> np.ndarray:
    """Breaking impulse magnitude of every bond for one hit, modes criterion (closed form).

    Parameters
    ----------
    data : RuntimeData
    site : int
        Contact site index.
    direction : (3,) float
        Unit impulse direction, model axes.

    Returns
    -------
    (e,) float64
        ``T / response`` with ``T = data.default_threshold``; ``+inf`` where the
        response is 0 (the bond never breaks); 0 where ``T = 0`` and the
        response is positive (any nonzero impulse breaks it).
    """
    response = bond_response(data, site, direction)
    threshold = float(data.default_threshold)
    out = np.full(response.shape, np.inf)
    loaded = response > 0.0
    out[loaded] = threshold / response[loaded]
    return out


def stress_breaking_impulses(data: RuntimeData, site: int, direction: np.ndarray) -> np.ndarray:
    """Breaking impulse magnitude of every bond for one hit, stress criterion (closed form).

    The runtime test (docs/FORMAT.md section 11) breaks bond ``e`` of site ``v``'s list when
    ``G[v, e] . n' > (T / m) * S_e``; with ``n = M u`` that is ``M * (G[v, e] . u) > T * S_e``, so
    ``m[e] = T * S_e / (G[v, e] . u)`` where the gain is positive, ``+inf`` elsewhere (compression, or a bond
    the site does not list), exactly up to one rounding as for the modes criterion.

    Parameters
    ----------
    data : RuntimeData
        A file baked with ``runtime.criterion = "stress"``.
    site : int
    direction : (3,) float
        Unit impulse direction, model axes.

    Returns
    -------
    (e,) float64
    """
    # on first use: the atlas loads the reader's stress step only for stress files
    from fracture_cli.runtime.impact import prepare

    stress = prepare(data).stress
    if stress is None:
        raise UsageError("the stress criterion needs a runtime file baked with runtime.criterion = 'stress' "
                         "(fracture bake --set runtime.criterion=stress)")
    u = np.asarray(direction, dtype=np.float64)
    bonds, g = stress.gains(site, float(u[0]), float(u[1]), float(u[2]))
    out = np.full(data.num_edges, np.inf)
    pulled = g > 0.0
    out[bonds[pulled]] = (float(data.default_threshold) * stress.strength[bonds[pulled]]) / g[pulled]
    if stress.sharing is not None:
        gain = np.zeros(data.num_edges)
        gain[bonds] = g
        struck = stress.sharing.incident[int(stress.sharing.site_fragment[site])]
        out[struck] = shared_breaking_impulses(gain[struck], float(data.default_threshold) * stress.strength[struck],
                                               np.asarray(stress.sharing.areas)[struck], stress.sharing.kappa)
    return out


def shared_breaking_impulses(gain: np.ndarray, capacity: np.ndarray, area: np.ndarray, kappa: float) -> np.ndarray:
    """Breaking impulses of the struck fragment's bonds when they share load (docs/FORMAT.md section 11.1).

    At magnitude ``M`` with the bonds ``X`` broken, bond ``k`` carries ``M * h_k`` with ``h_k = g_k + kappa *
    L / A * area_k`` (``L``: the positive gains over ``X``, ``A``: the intact area) and breaks when that exceeds
    ``T * S_k``. The gains only grow as ``X`` does, so the runtime's passes at ``M`` break exactly the bonds
    this event sweep finds below ``M``: the next bond to break on its own, then every bond the shared load
    breaks at that same magnitude, and so on.

    Parameters
    ----------
    gain : (f,) float64
        ``g`` per unit impulse along the hit's direction (0 for bonds the site does not list).
    capacity : (f,) float64
        ``T * S`` of each bond.
    area : (f,) float64
        Fault areas.
    kappa : float
        The concentration.

    Returns
    -------
    (f,) float64
        The smallest magnitude above which each bond is broken (``+inf``: never).
    """
    out = np.full(len(gain), np.inf)
    broken = np.zeros(len(gain), dtype=bool)
    level = 0.0
    while not broken.all():
        load = float(np.maximum(gain[broken], 0.0).sum())
        held = float(area[~broken].sum())
        h = gain + (kappa * load / held) * area if load > 0.0 and held > 0.0 else gain
        with np.errstate(divide="ignore", invalid="ignore"):
            at = np.where(~broken & (h > 0.0), capacity / np.where(h > 0.0, h, 1.0), np.inf)
        if not np.isfinite(at).any():
            break
        level = max(level, float(at.min()))
        now = ~broken & (at <= level)  # the next break, then what the shared load breaks at the same magnitude
        broken |= now
        out[now] = level
    return out


CRITERIA: dict[str, BreakingImpulses] = {"modes": modes_breaking_impulses, "stress": stress_breaking_impulses}
"""The criteria the atlas knows, by the name ``runtime.criterion`` will use."""


def criterion_named(name: str) -> BreakingImpulses:
    """The criterion called ``name``; :class:`UsageError` naming the valid ones otherwise."""
    try:
        return CRITERIA[name]
    except KeyError:
        raise UsageError(f"unknown break criterion {name!r}; pick one of {', '.join(sorted(CRITERIA))}") from None
