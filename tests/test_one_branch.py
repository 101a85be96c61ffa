"""Skipping what no sample or curve needs changes nothing, bit for bit.

The jets' ``qexp``/``qlog`` evaluate only the branch (series near the identity, or
closed form) that some sample takes, and ``build_curves`` only the kinds of curve
present: a batch of one branch or kind must give exactly its rows of a mixed batch.
"""

import numpy as np
import pytest

from trajgen import jet as J
from trajgen import quat as Q
from trajgen.local_curves import build_curves


@pytest.mark.parametrize("order", [1, 3, 4])
def test_jet_exp_and_log_of_one_branch_are_their_rows_of_a_mixed_batch(order, rng):
    m = 20  # per branch; enough samples that both batches take the same product path
    v = rng.normal(size=(order + 1, 3, 2 * m))
    v[0, :, :m] *= 0.02 / np.linalg.norm(v[0, :, :m], axis=0)  # |v|^2 below SERIES_BELOW
    v[0, :, m:] *= 0.8 / np.linalg.norm(v[0, :, m:], axis=0)
    mixed, small, large = J.Jet(v), J.Jet(v[..., :m].copy()), J.Jet(v[..., m:].copy())
    both = J.qexp(mixed).c
    np.testing.assert_array_equal(J.qexp(small).c, both[..., :m])
    np.testing.assert_array_equal(J.qexp(large).c, both[..., m:])
    logs = J.qlog(J.Jet(both)).c
    np.testing.assert_array_equal(J.qlog(J.qexp(small)).c, logs[..., :m])
    np.testing.assert_array_equal(J.qlog(J.qexp(large)).c, logs[..., m:])
    np.testing.assert_allclose(logs, v, atol=1e-12)  # and log inverts exp


def test_curve_table_of_one_kind_is_its_rows_of_a_mixed_table(rng):
    n = 40
    q = Q.exp(np.cumsum(rng.normal(scale=0.5, size=(n, 3)), axis=0))
    q[10] = q[11]  # geodesic and held-point triples
    q[20] = q[21] = q[22]
    q[1:] *= np.where(np.cumsum(np.einsum("ij,ij->i", q[1:], q[:-1]) < 0) % 2, -1.0, 1.0)[:, None]
    t = np.cumsum(rng.uniform(0.2, 2.0, n))
    triples = np.stack([q[:-2], q[1:-1], q[2:]], axis=1)
    times = np.stack([t[:-2], t[1:-1], t[2:]], axis=1)
    options = {"k": 2, "local": "auto", "reparam": "rational"}
    mixed = build_curves(triples, times, **options)
    assert len(set(mixed.kind.tolist())) == 4
    for kind in range(4):
        rows = mixed.kind == kind
        alone = build_curves(triples[rows], times[rows], **options)
        for name in ("kind", "q", "radius", "a3", "g_kind", "g_coef", "rise", "power"):
            np.testing.assert_array_equal(getattr(alone, name), getattr(mixed, name)[rows])
        for name in ("centre", "e1", "e2", "A", "B", "basis"):
            np.testing.assert_array_equal(getattr(alone, name), getattr(mixed, name)[:, rows])
