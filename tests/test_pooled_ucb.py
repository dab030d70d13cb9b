"""Pooled Bayes-UCB (ours): a grasp's posterior adds the outcomes of its pose's
other candidates as a pseudo-observation of their pooled success rate worth at
most POOL_ATTEMPTS attempts; the choice is Bayes-UCB's on these posteriors and
the recommendation their highest mean. The parity tests (tests/test_parity.py)
compare the engine with the NumPy twin in distribution, as for every learning
method."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
from scipy import stats
from test_bayes_ucb import B, P, _setup, reached
from test_reference import hand_problem

from legs_jax.core import methods
from legs_jax.core.methods import pooled_ucb

M = pooled_ucb.POOL_ATTEMPTS


def test_the_pool_by_hand():
    # three candidates and one empty slot; counts (S, F): (3, 1), (0, 2), (0, 0)
    a0 = jnp.asarray([[1.5, 1.2, 1.9, 1.0]])
    b0 = jnp.asarray([[1.5, 1.8, 1.1, 1.0]])
    succ = jnp.asarray([[3.0, 0.0, 0.0, 7.0]])  # the empty slot's counts are ignored
    fail = jnp.asarray([[1.0, 2.0, 0.0, 7.0]])
    mask = jnp.asarray([[True, True, True, False]])
    a, b = pooled_ucb.pooled(a0 + succ, b0 + fail, succ, fail, mask)
    # grasp 0 borrows (0, 2); grasp 1 borrows (3, 1); grasp 2 borrows (3, 3): all
    # under M attempts, so in full; the empty slot is left as it is
    np.testing.assert_allclose(a, [[4.5, 4.2, 4.9, 8.0]], rtol=1e-6)
    np.testing.assert_allclose(b, [[4.5, 4.8, 4.1, 8.0]], rtol=1e-6)
    # 40 other attempts (10 successes) count for M = 10: c = 1/4
    succ = jnp.asarray([[0.0, 10.0]])
    fail = jnp.asarray([[0.0, 30.0]])
    a, b = pooled_ucb.pooled(
        jnp.ones((1, 2)), jnp.ones((1, 2)), succ, fail, mask[:, :2]
    )
    np.testing.assert_allclose(a[0, 0], 1.0 + 10.0 * M / 40.0, rtol=1e-6)
    np.testing.assert_allclose(b[0, 0], 1.0 + 30.0 * M / 40.0, rtol=1e-6)
    # nothing tried at the pose: the prior alone
    z = jnp.zeros((1, 2))
    a, b = pooled_ucb.pooled(a0[:, :2], b0[:, :2], z, z, mask[:, :2])
    np.testing.assert_array_equal(a, a0[:, :2])
    np.testing.assert_array_equal(b, b0[:, :2])


def test_choice_and_recommendation_read_the_pooled_posteriors():
    """From random reachable states: the choice is the highest 1 − 1/(t + 1)
    quantile and the recommendation the highest mean of the pooled posteriors,
    computed here with SciPy in float64 from the counts."""
    m, ctx, cfg, st = _setup("pooled_ucb")
    rng = np.random.default_rng(0)
    n = st.inner.alpha.shape
    tried = rng.uniform(size=n) < 0.3
    wins = np.where(tried, rng.poisson(1.5, n), 0).astype(np.float32)
    losses = np.where(tried, rng.poisson(4, n), 0).astype(np.float32)
    count = rng.integers(0, 400, (B, P)).astype(np.int32)
    st = reached(st, wins, losses, count)
    inner = st.inner
    s = jnp.asarray(rng.integers(0, P, B), jnp.int32)
    keys = jax.random.split(jax.random.key(0), B)
    grasp, slot, _ = jax.jit(m.select, static_argnums=2)(st, ctx, cfg, s, keys)
    rec = jax.jit(m.recommend, static_argnums=2)(st, ctx, cfg, s)
    checked = 0
    for i in range(B):
        si = int(s[i])
        ids = np.asarray(inner.gid[i, si])
        keep = ids >= 0
        w, f = (
            wins[i, si][keep].astype(np.float64),
            losses[i, si][keep].astype(np.float64),
        )
        a = np.asarray(inner.alpha[i, si], np.float64)[keep]
        b = np.asarray(inner.beta[i, si], np.float64)[keep]
        so, fo = w.sum() - w, f.sum() - f
        c = np.minimum(1.0, M / np.maximum(so + fo, 1.0)) * (so + fo > 0)
        a, b, ids = a + c * so, b + c * fo, ids[keep]
        mean = a / (a + b)
        assert abs(mean[ids == int(rec[i])][0] - mean.max()) < 1e-5, f"row {i}"
        index = stats.beta.ppf(1.0 - 1.0 / (count[i, si] + 2.0), a, b)
        top2 = np.sort(index)[-2:]
        if top2[1] - top2[0] < 1e-4:
            continue  # within the float32 quantile tolerance
        assert int(grasp[i]) == int(ids[np.argmax(index)]), f"row {i}"
        assert int(inner.gid[i, si, int(slot[i])]) == int(grasp[i])
        checked += 1
    assert checked >= B // 2


def test_the_twin_pools_and_caps():
    pb = hand_problem([1.0], [[1.0]], [[0.5, 0.5, 0.5]], [[0.5, 0.5, 0.5]])
    twin = methods.get("pooled_ucb").card.reference(
        pb, 0, {"s": 1.0, "prior_offset": 1.0}
    )
    for _ in range(30):
        twin.update(0, 0, False)
    for _ in range(10):
        twin.update(0, 1, True)
    a, b = twin._pooled(0, np.arange(3))
    # grasp 2 borrows 10 successes and 30 failures at a quarter (M = 10 of 40)
    np.testing.assert_allclose([a[2], b[2]], [1.5 + 2.5, 1.5 + 7.5])
    # grasp 1 borrows grasp 0's 30 failures at a third; grasp 0, grasp 1's 10 wins
    np.testing.assert_allclose([a[1], b[1]], [1.5 + 10.0, 1.5 + 10.0])
    np.testing.assert_allclose([a[0], b[0]], [1.5 + 10.0, 1.5 + 30.0])
    # the untried grasp, judged by a pose that fails 3 times in 4, now loses
    # the recommendation to the grasp that won 10 of 10
    assert twin._recommend_pose(0) == 1
