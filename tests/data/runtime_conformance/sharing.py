"""Conformance files for docs/FORMAT.md section 11.1 (feature ``"sharing"``: the struck fragment's bonds share load).

Three synthetic runtime files (see README.md here): ``sharing_dyadic`` (five fragments, fragment 0 a hub
with three bonds, dyadic values so the passes below are exact), ``damage_sharing`` (the same with damage:
bonds broken by earlier hits start the passes) and ``levels_sharing`` (``levels_stress`` with sharing in
both bodies). The sample chair baked with its manifest recipe and the stress criterion (blocks, kappa 2)
is ``chair_sharing`` (generate.py).
"""

from __future__ import annotations

import dataclasses

import levels
import numpy as np

from fracture_cli.runtime.format import RuntimeData

KAPPA = 2.0


def sharing_dyadic() -> RuntimeData:
    """Fragment 0 bonded to 1, 2, 3 (bonds 0, 1, 2), plus bonds (1, 2) and (3, 4); kappa 2; dyadic values.

    Site 0 (on fragment 0), impulse ``(1, 0, 0)``: ``a0 = (1, 0.25, 0.125, -0.5, 0)``, strengths
    ``(0.5, 4, 0.75, 1, 0.25)``, fault areas ``(0.5, 0.25, 0.25, 1, 0.5)``. Bond 0 breaks alone for ``T < 2``;
    it leaves ``L = 1`` on ``A = 0.5``: ``q = 4``, bond 1 then carries ``1.25`` and bond 2 ``1.125``:

    * ``T = 1.5``: bond 2's ``1.125 == 0.75 T`` holds (an exact tie after sharing), bond 1 holds;
    * ``T = 1.25``: bond 2 breaks; ``L = 1.125`` on ``A = 0.25``: ``q = 9``, bond 1 carries ``2.5 < 5``;
    * ``T = 0.5``: bond 2 breaks in pass 1, bond 1 (``2.5 > 2``) in pass 2: fragment 0 comes off.

    Site 1 (on fragment 3), impulse ``(0, 1, 0)``: only bond 4 is listed (``a0 = 1``); bond 2 is unlisted but
    is fragment 3's other bond: ``q = 2 / 0.25 = 8``, it carries ``2`` against ``0.75 T`` (breaks for ``T < 8/3``).
    """
    gains = [[1.0, 0.0, 0.0], [0.25, 0.0, 0.0], [0.125, 0.25, 0.0], [-0.5, 0.0, 0.0],  # site 0: bonds 0-3
             [0.0, 1.0, 0.0],  # site 1: bond 4
             [0.5, 0.0, 0.25], [0.0, 0.5, 0.5]]  # site 2: bonds 0, 3
    return RuntimeData(
        sites=np.array([[0, 0, 0], [4, 0, 0], [0, 4, 0]], np.float32),
        B=np.array([[[1.0]], [[0.5]], [[-0.25]]], np.float32),
        W=np.array([[[1.0], [0.5], [-0.5], [0.0], [0.25]]], np.float32),
        edges=np.array([[0, 1], [0, 2], [0, 3], [1, 2], [3, 4]], np.int32),
        edge_areas=np.array([0.5, 0.25, 0.25, 1.0, 0.5], np.float32),
        fragment_names=tuple(f"fragment_{j:03d}" for j in range(5)),
        default_threshold=1.5,
        radius=0.05,
        criterion="stress",
        stress={
            "site_bonds_ptr": np.array([0, 4, 5, 7], np.int32),
            "site_bonds": np.array([0, 1, 2, 3, 4, 0, 3], np.int32),
            "site_bond_gain": np.array(gains, np.float32),
            "bond_strength": np.array([0.5, 4.0, 0.75, 1.0, 0.25], np.float32),
            "site_fragment": np.array([0, 3, 1], np.int32),
        },
        stress_info={"note": "synthetic"},
        sharing={"concentration": KAPPA},
    )


def _case(name: str, point, impulse, threshold) -> dict:
    return {"name": name, "point": point, "impulse": impulse, "threshold": threshold, "exact": True}


SHARING_TIES: list[dict] = [
    _case("sharing: bond 2 carries exactly its strength after bond 0 breaks (holds)", [0.5, 0.0, 0.0],
          [1.0, 0.0, 0.0], 1.5),
    _case("sharing: the same x 1024", [0.5, 0.0, 0.0], [1024.0, 0.0, 0.0], 1536.0),
    _case("sharing: bond 2 breaks in pass 1, bond 1 holds", [0.5, 0.0, 0.0], [1.0, 0.0, 0.0], 1.25),
    _case("sharing: pass 2 breaks bond 1, fragment 0 comes off", [0.5, 0.0, 0.0], [1.0, 0.0, 0.0], 0.5),
    _case("sharing: nothing breaks, nothing shared", [0.5, 0.0, 0.0], [1.0, 0.0, 0.0], 2.5),
    _case("sharing: an unlisted bond of the struck fragment breaks", [3.5, 0.0, 0.0], [0.0, 1.0, 0.0], 2.0),
    _case("sharing: an unlisted bond of the struck fragment holds", [3.5, 0.0, 0.0], [0.0, 1.0, 0.0], 3.0),
    _case("sharing: threshold 0", [0.5, 0.0, 0.0], [1.0, 0.0, 0.0], 0.0),
    _case("sharing: threshold inf", [0.5, 0.0, 0.0], [1.0, 0.0, 0.0], float("inf")),
]


def damage_sharing(base: RuntimeData) -> RuntimeData:
    """``sharing_dyadic`` with damage (``c = 0.25``, ``r = 0.75``: ``q = 1``) and fragment 4 anchored."""
    return dataclasses.replace(base, anchored=np.array([0, 0, 0, 0, 1], np.int32),
                               damage={"crack_level": 0.25, "damage_rate": 0.75})


def levels_sharing() -> RuntimeData:
    """``levels_stress`` with sharing: level-1 sites on fragments 0, 1, 2; the body's sites on children 0 and 1."""
    data = levels.levels_stress()
    arrays = dict(data.levels)
    arrays["body_site_fragment"] = np.array([0, 1], np.int32)
    stress = dict(data.stress)
    stress["site_fragment"] = np.array([0, 1, 2], np.int32)
    return dataclasses.replace(data, stress=stress, levels=arrays, sharing={"concentration": KAPPA})

