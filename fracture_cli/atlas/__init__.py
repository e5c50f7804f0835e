"""The break atlas: where and how much an object breaks for a hit, measured over its surface.

For every hit of a deterministic sweep (contact sites spread by farthest-point
sampling, impulse towards the asset's centre) a break criterion gives each bond
of the fragment graph its *breaking impulse*, the smallest impulse magnitude
that breaks it; the first break ``b0``, the first detachment ``d1``, the impulse
that breaks everything and the groups at any magnitude follow exactly, with no
sampling of magnitudes. The figures over the sweep say whether breaking follows
the hit (issue 30): is the fragment hit among what comes off first, how close to
the hit is what comes off, does the first break split the object, how graded is
the response.

Modules, one concern each:

* :mod:`~fracture_cli.atlas.criterion`: breaking impulses per bond (the modes criterion; the plug-in interface);
* :mod:`~fracture_cli.atlas.hits`: one hit: ``b0``, ``d1``, everything, groups, detached fragments, hit fragment;
* :mod:`~fracture_cli.atlas.layout`: fragment volumes and centroids (game-ready arrays, GLB, or none);
* :mod:`~fracture_cli.atlas.leaves`: files with levels: the fragment hit breaks into its children too;
* :mod:`~fracture_cli.atlas.sweep`: the sweep and the figures, every definition in its docstring;
* :mod:`~fracture_cli.atlas.summary`: the JSON summary and the ``KEY<=VALUE`` gate;
* :mod:`~fracture_cli.atlas.render`: the PNG;
* :mod:`~fracture_cli.atlas.run`: :func:`run_atlas`, what the CLI calls.

Only IEEE arithmetic and ``sqrt`` reach the figures (no libm functions), so the
summary is the same on every machine.
"""

from fracture_cli.atlas.run import AtlasResult, run_atlas

__all__ = ["AtlasResult", "run_atlas"]
