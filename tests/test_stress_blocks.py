"""The stress criterion's blocks model (issue 30): rigid fragments held by elastic faults, the hit on one fragment."""

from __future__ import annotations

import hashlib
import os
import subprocess
import sys

import numpy as np
import pytest
from test_stress import NU, box_mesh

from fracture_cli.stages.stress.blocks import block_tractions
from fracture_cli.stages.stress.bonds import bond_faces
from fracture_cli.stages.stress.gains import site_patches
from fracture_cli.stages.stress.stage import patch_normals

from conftest import REPO

BONDS = np.array([[0, 1], [1, 2]])


def thirds(mesh) -> np.ndarray:
    """Three fragments along x: 0 for x < -1/3, 1 in the middle, 2 for x > 1/3."""
    x = mesh.tet_centroids[:, 0]
    return (x > -1.0 / 3.0).astype(np.int64) + (x > 1.0 / 3.0)


def tractions(mesh, owner, sites, site_owner=None, reach=0.05, vector=False):
    faces = bond_faces(mesh, owner, BONDS)
    normals = patch_normals(mesh, faces, None, len(BONDS))
    patchT = site_patches(mesh, sites, 0.1).T.tocsr()
    return block_tractions(mesh, owner, faces, BONDS, normals, patchT, reach, NU, None, vector, site_owner)


def _site(mesh, point) -> np.ndarray:
    V = mesh.vertices
    boundary = np.asarray(mesh.boundary_vertices)
    return boundary[[int(np.argmin(((V[boundary] - point) ** 2).sum(axis=1)))]]


def test_a_pull_on_an_end_block_opens_its_own_fault_and_hardly_the_next():
    mesh = box_mesh(nx=9, ny=3, nz=3, size=(2.0, 1.0, 1.0))
    owner = thirds(mesh)
    site = _site(mesh, np.array([-1.0, 0.0, 0.0]))  # the middle of the left end face
    t = tractions(mesh, owner, site)  # (1, 3, 2): normal traction per unit force along x, y, z
    pull = -t[0, 0]  # a force along -x pulls block 0 away from block 1
    assert pull[0] > 0.0  # bond (0, 1) opens
    assert abs(pull[1]) < 0.1 * pull[0]  # a short contact: block 2 barely feels it
    push = t[0, 0]
    assert push[0] < 0.0  # a push closes it


def test_the_load_acts_on_the_fragment_named_for_the_site():
    mesh = box_mesh(nx=6, ny=2, nz=2, size=(2.0, 1.0, 1.0))  # x = 0 is a vertex plane: a symmetric middle block
    owner = thirds(mesh)
    site = _site(mesh, np.array([0.0, 0.0, 0.5]))  # the top of the middle block
    sideways = tractions(mesh, owner, site, vector=True)[0, 1].reshape(2, 3)  # force along y: shear on both faults
    # both faults sheared alike (within the Kuhn tets' asymmetry)
    assert np.linalg.norm(sideways[0]) == pytest.approx(np.linalg.norm(sideways[1]), rel=0.15)
    on_left = tractions(mesh, owner, site, site_owner=np.array([0]), vector=True)[0, 1].reshape(2, 3)
    assert np.linalg.norm(on_left[0]) > 5 * np.linalg.norm(on_left[1])  # the same hit given to block 0


def test_response_is_linear_and_grows_with_the_reach_towards_the_far_fault():
    mesh = box_mesh(nx=9, ny=3, nz=3, size=(2.0, 1.0, 1.0))
    owner = thirds(mesh)
    site = _site(mesh, np.array([-1.0, 0.0, 0.0]))
    short, long = tractions(mesh, owner, site, reach=0.02), tractions(mesh, owner, site, reach=2.0)
    assert abs(long[0, 0, 1]) / abs(long[0, 0, 0]) > abs(short[0, 0, 1]) / abs(short[0, 0, 0])
    both = tractions(mesh, owner, np.concatenate([site, site]))
    np.testing.assert_array_equal(both[0], both[1])


DIGEST_SCRIPT = """
import hashlib, sys
sys.path.insert(0, {tests!r})
import fracture_cli  # noqa: F401  (pins, unless FRACTURE_NUMERICS=host)
import numpy as np
from test_stress import box_mesh
from test_stress_blocks import thirds, tractions
from fracture_cli.stages.stress.stage import round_bits, sparsify
from threadpoolctl import threadpool_info
mesh = box_mesh(nx=10, ny=5, nz=4, jitter=0.04, seed=4)
raw = tractions(mesh, thirds(mesh), np.asarray(mesh.boundary_vertices), reach=0.3)
ptr, bonds, gain = sparsify(round_bits(raw), np.ones(2), 0.05)
blas = sorted({{i.get("architecture") for i in threadpool_info() if i.get("internal_api") == "openblas"}})
print(hashlib.sha256(gain.astype(np.float32).tobytes() + ptr.tobytes()).hexdigest(), ",".join(map(str, blas)))
"""


def test_stored_block_gains_are_the_same_bytes_with_other_blas_kernels():
    def digests(env):
        run = subprocess.run([sys.executable, "-c", DIGEST_SCRIPT.format(tests=os.path.join(REPO, "tests"))],
                             env={**os.environ, **env}, capture_output=True, text=True, timeout=300, cwd=REPO)
        assert run.returncode == 0, run.stderr
        return run.stdout.split()

    pinned = digests({"OPENBLAS_CORETYPE": "Haswell"})
    haswell = digests({"FRACTURE_NUMERICS": "host", "OPENBLAS_CORETYPE": "Haswell"})
    prescott = digests({"FRACTURE_NUMERICS": "host", "OPENBLAS_CORETYPE": "Prescott"})
    assert haswell[1] != prescott[1], f"could not force two kernels: {haswell[1]} / {prescott[1]}"
    assert pinned[0] == haswell[0] == prescott[0]
    assert hashlib.sha256(b"").hexdigest() not in pinned
