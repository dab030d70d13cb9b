"""Bayes-UCB (K=100 and K=2000): the index is the 1 − 1/(t + 1) quantile of each
candidate's Beta posterior, t the attempts at the pose counting this one; the
highest index is chosen (ties: lowest grasp id), with no random draw. The NumPy
twin follows the same rule; the parity tests (tests/test_parity.py) compare the
two in distribution, as for every learning method."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from scipy import stats
from test_reference import hand_problem

from legs_jax import engine, methods
from legs_jax.methods.base import Config, Ctx
from legs_jax.problem import stack
from legs_jax.synthetic import make_problem

B, P, K = 64, 3, 150


def _setup(name):
    m = methods.get(name)
    batch = stack([make_problem(2, num_poses=P, num_grasps=K, num_trials=1)])
    tables = jax.tree.map(jnp.asarray, engine.make_tables(batch, [0]))
    hp = m.traced_hparams(s=jnp.full(B, 1.0), prior_offset=jnp.full(B, 1.0))
    ctx = Ctx(tables, jnp.zeros(B, jnp.int32), hp)
    cfg = Config(num_poses=P, num_grasps=K)
    return m, ctx, cfg, m.init(ctx, cfg)


@pytest.mark.parametrize("name", ["bayes_ucb_100", "bayes_ucb_2000"])
def test_choice_is_the_highest_posterior_quantile(name):
    m, ctx, cfg, st = _setup(name)
    rng = np.random.default_rng(0)
    inner = st.inner
    n = inner.alpha.shape
    wins = rng.poisson(rng.uniform(0, 3, n)).astype(np.float32)
    losses = rng.poisson(rng.uniform(0, 6, n)).astype(np.float32)
    count = rng.integers(0, 400, (B, P)).astype(np.int32)
    inner = inner._replace(alpha=inner.alpha + wins, beta=inner.beta + losses)
    st = st._replace(inner=inner, count=jnp.asarray(count))
    s = jnp.asarray(rng.integers(0, P, B), jnp.int32)
    keys = jax.random.split(jax.random.key(0), B)
    grasp, slot, _ = jax.jit(m.select, static_argnums=2)(st, ctx, cfg, s, keys)
    again, _, _ = jax.jit(m.select, static_argnums=2)(
        st, ctx, cfg, s, jax.random.split(jax.random.key(9), B)
    )
    np.testing.assert_array_equal(grasp, again)  # no random draw
    valid = np.asarray(ctx.tables.valid[0])
    checked = 0
    for i in range(B):
        si = int(s[i])
        a = np.asarray(inner.alpha[i, si], np.float64)
        b = np.asarray(inner.beta[i, si], np.float64)
        if name == "bayes_ucb_100":
            ids = np.asarray(inner.gid[i, si])
            a, b, ids = a[ids >= 0], b[ids >= 0], ids[ids >= 0]
            assert int(np.asarray(inner.gid)[i, si, int(slot[i])]) == int(grasp[i])
        else:
            ids = np.flatnonzero(valid[si])
            a, b = a[ids], b[ids]
        level = 1.0 - 1.0 / (count[i, si] + 2.0)
        index = stats.beta.ppf(level, a, b)
        top2 = np.sort(index)[-2:]
        if top2[1] - top2[0] < 1e-4:
            continue  # within the float32 quantile tolerance
        assert int(grasp[i]) == int(ids[np.argmax(index)]), f"row {i}"
        checked += 1
    assert checked >= B // 2


@pytest.mark.parametrize("name", ["bayes_ucb_100", "bayes_ucb_2000"])
def test_counts_attempts_per_pose_and_prefers_the_uncertain(name):
    """Attempts are counted per pose (only live ones); at the first attempt the
    index is the median, and a well-known arm loses to an untried arm of about
    the same mean once the level rises."""
    m, ctx, cfg, st = _setup(name)
    s = jnp.zeros(B, jnp.int32)
    live = jnp.arange(B) % 2 == 0
    grasp = jnp.zeros(B, jnp.int32)
    st2, _ = m.update(st, ctx, cfg, s, grasp, grasp, jnp.ones(B, bool), live)
    np.testing.assert_array_equal(st2.count[:, 0], np.where(live, 1, 0))
    np.testing.assert_array_equal(st2.count[:, 1:], 0)
    # the twin: two arms, one known well (mean a little above 1/2), one not at all
    pb = hand_problem([1.0], [[1.0]], [[0.5, 0.5]], [[0.5, 0.5]])
    twin = m.reference(pb, 0, m.defaults())
    twin.alpha[0, 0] += 51.0
    twin.beta[0, 0] += 50.0
    twin.count[0] = 100  # level 1 - 1/102: the uncertain arm's index is higher
    assert twin.select(0, np.random.default_rng(0)) == 1
    twin.count[0] = 0  # level 1/2, the medians: the better-known arm
    assert twin.select(0, np.random.default_rng(0)) == 0
    twin.update(0, 1, True)
    assert twin.count[0] == 1 and twin.alpha[0, 1] == 2.5
