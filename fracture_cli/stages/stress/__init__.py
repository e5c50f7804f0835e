"""The stress criterion, offline half: linear elastostatics on the bake's tet mesh (issue 30).

* :mod:`~fracture_cli.stages.stress.fem`: P1 elasticity (stiffness, normal-traction functionals);
* :mod:`~fracture_cli.stages.stress.bonds`: the tet faces and strength of every bond;
* :mod:`~fracture_cli.stages.stress.gains`: the response to a unit load at every site (inertia relief, adjoint solve);
* :mod:`~fracture_cli.stages.stress.stage`: the runtime file's stress arrays (sparse, rounded).

The runtime half (the per-hit test) is :mod:`fracture_cli.runtime.stress`.
"""
