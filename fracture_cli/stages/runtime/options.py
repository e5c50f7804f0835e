"""Options of the ``runtime`` stage (what a recipe's ``[runtime]`` section may say).

Apart from the stage's work so that resolving a recipe loads neither the runtime file format nor scipy.
"""

from __future__ import annotations

from dataclasses import dataclass

from fracture_cli.options import option

STAGE = "runtime"


@dataclass(frozen=True)
class RuntimeOptions:
    """Options of the runtime precomputation.

    Attributes
    ----------
    radius : float, optional (default 0.05)
        Impact radius ``r`` relative to the bounding-box diagonal; the impulse is
        spread by one implicit diffusion step of time ``tau = r^2``.
    criterion, youngs_modulus, poisson_ratio, tensile_strength, stress_keep, stress_reach, stress_max_bonds
        The stress criterion (:mod:`fracture_cli.stages.stress`); ``criterion = "modes"`` ignores the others
        and writes version 1 as before.
    load_sharing : float, optional (default 2.0)
        Stress criterion: ``kappa`` of feature ``"sharing"`` (docs/FORMAT.md section 11.1), 0 = off.
    threshold : float, optional (default 3.0)
        Default toughness written to the file (games may override it per hit).
        Dimensionless per unit of impulse: an impulse of magnitude ``m`` breaks
        the same edges as an impulse of magnitude 1 with threshold ``T / m``.
        With 3.0 a unit impulse typically splits an object into 2-3 groups
        (measured on two boxes joined by a neck, k = 6 and 12 modes).
    damage : bool, optional (default False)
        Write damage that adds up (feature ``"damage"``, docs/FORMAT.md section 12) with ``crack_level`` and
        ``damage_rate``, and the crack lines of every bond. Off: hits are judged alone (version 1, as before),
        whatever the two values say; a recipe keeps its material's values and a structure turns them on.
    crack_level, damage_rate : float, optional (default 0.6, 0.4)
        ``c`` and ``r`` of docs/FORMAT.md section 12.4: a hit that loads a bond above ``c`` of its strength
        cracks it and takes ``r (load - c) / (1 - c)`` of its health.
    """

    radius: float = option(0.05, "impact radius as a fraction of the bounding-box diagonal (diffusion time r^2)",
                           min=0.0, max=1.0, min_exclusive=True)
    threshold: float = option(3.0, "default toughness: an edge breaks when the fragments' displacement jump per "
                                   "unit impulse exceeds it (bigger = harder to break)", min=0.0)
    criterion: str = option("modes", "what breaks a bond: 'modes' (the projection's jump, format version 1) or "
                                     "'stress' (tensile traction of the elastic response, version 2)",
                            choices=("modes", "stress"))
    youngs_modulus: float = option(1.0e9, "stress criterion: Young's modulus E in Pa (a free body's stress under "
                                          "balanced loads does not depend on it)", min=0.0, min_exclusive=True)
    poisson_ratio: float = option(0.25, "stress criterion: Poisson ratio nu", min=-0.99, max=0.49)
    tensile_strength: float = option(1.0, "stress criterion: tensile strength per unit area of the asset scaled "
                                          "to a unit diagonal, in impulse units (with threshold: bigger = harder)",
                                     min=0.0, min_exclusive=True)
    stress_keep: float = option(0.05, "stress criterion: a site lists the bonds it loads to at least this fraction "
                                      "of its most loaded bond's load", min=0.0, max=1.0)
    stress_reach: float = option(0.05, "stress criterion: how far the impact's stress wave runs during the contact "
                                       "(fraction of the diagonal; small = local breaks, 0 = quasi-static)",
                                 min=0.0, max=100.0)
    stress_measure: str = option("tension_shear", "stress criterion: what loads a bond: 'tension' (normal traction) "
                                                  "or 'tension_shear' (traction without its compressive part)",
                                 choices=("tension_shear", "tension"))
    stress_model: str = option("blocks", "stress criterion: what responds to the hit: 'blocks' (every fragment a rigid "
                                         "body, the faults the elastic part, the hit on the fragment it lands on: it "
                                         "loads every bond of that fragment) or 'tets' (linear elasticity on the "
                                         "bake's tet mesh)", choices=("blocks", "tets"))
    load_sharing: float = option(2.0, "stress criterion: when bonds of the fragment hit break, their load goes to its "
                                      "other bonds, concentrated this much (a crack tip's stress concentration; "
                                      "0: no sharing, one bond breaks at a time)", min=0.0, max=100.0)
    stress_max_bonds: int = option(48, "stress criterion: at most this many bonds per site (0 = no limit)",
                                   min=0, max=100000)
    damage: bool = option(False, "write damage that adds up (format version 2, feature 'damage'): a hit below a "
                                 "bond's strength cracks and weakens it, in a state the game keeps per object; "
                                 "with crack lines to draw")
    crack_level: float = option(0.6, "damage: a hit loading a bond above this fraction of its strength cracks it "
                                     "(1: any crack is a break)", min=0.0, max=1.0, min_exclusive=True)
    damage_rate: float = option(0.4, "damage: the health a hit just under a bond's strength takes (about 1/rate "
                                     "such hits break it; 0: cracks never weaken)", min=0.0, max=100.0)
