"""The cut solver's compiled partition kernels equal the scipy/numpy code they replace, bit for bit."""

import numpy as np
import pytest
import scipy.sparse as sp
from scipy.sparse.csgraph import connected_components

from fracture_cli.stages.modes.solver import partition_kernels


def _graph(rng, t, f):
    fa = rng.integers(0, t, f)
    fb = rng.integers(0, t, f)
    keep = fa != fb
    return np.ascontiguousarray(fa[keep]), np.ascontiguousarray(fb[keep])


def _reference_components(fa, fb, keep, t):
    graph = sp.csr_matrix((np.ones(int(keep.sum())), (fa[keep], fb[keep])), shape=(t, t))
    count, labels = connected_components(graph, directed=False)
    return count, labels.astype(np.int64)


def _reference_cell_graph(cells, fa, fb, omega, n):
    ca, cb = cells[fa], cells[fb]
    between = ca != cb
    lo, hi = np.minimum(ca[between], cb[between]), np.maximum(ca[between], cb[between])
    key, inverse = np.unique(lo * n + hi, return_inverse=True)
    edge_omega = np.bincount(inverse.reshape(-1), weights=omega[between], minlength=len(key))
    return np.column_stack([key // n, key % n]), edge_omega


@pytest.mark.parametrize("seed", range(8))
def test_components_and_cell_graph_match_scipy(seed):
    rng = np.random.default_rng(seed)
    t = int(rng.integers(1, 400))
    fa, fb = _graph(rng, t, int(rng.integers(0, 3 * t)))
    keep = rng.random(len(fa)) < rng.random()
    count, labels = partition_kernels.masked_components(fa, fb, keep, t)
    ref_count, ref_labels = _reference_components(fa, fb, keep, t)
    assert count == ref_count
    np.testing.assert_array_equal(labels, ref_labels)

    omega = rng.random(len(fa)) * 10.0 ** rng.uniform(-8, 8, len(fa))  # sums whose order shows in the bits
    edges, edge_omega = partition_kernels.cell_graph(labels, fa, fb, omega, count)
    ref_edges, ref_omega = _reference_cell_graph(labels, fa, fb, omega, count)
    np.testing.assert_array_equal(edges, ref_edges.reshape(-1, 2))
    assert edge_omega.tobytes() == ref_omega.tobytes()

    order, indptr = partition_kernels.cell_order(labels, count)
    np.testing.assert_array_equal(order, np.argsort(labels, kind="stable"))
    np.testing.assert_array_equal(indptr[1:], np.cumsum(np.bincount(labels, minlength=count)))
