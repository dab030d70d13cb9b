"""The online loop runs the batched engine's method code, step for step.

Given the engine's own poses and rewards, a session's :class:`Loop` (B = 1, poses
given their reservoirs only when first visited) selects exactly the engine's
grasps with the engine's keys, and ends with the engine's recommendations.
"""

from __future__ import annotations

import jax.numpy as jnp
import numpy as np
import pytest

from legs_jax import runtime
from legs_jax.core import engine, keys
from legs_jax.core import methods as methods_mod
from legs_jax.core.methods.base import Config
from legs_jax.core.problem import stack
from legs_jax.online._adapter import Loop, method_names
from legs_jax.synthetic import make_problem

H = 200
B = 2


@pytest.fixture(scope="module")
def setup():
    pb = make_problem(seed=5, num_poses=4, num_grasps=150, num_trials=1)
    batch = stack([pb])
    tables = engine.make_tables(batch, [0])
    return tables


@pytest.mark.parametrize(
    "method",
    ["legs"]
    + [pytest.param(m, marks=pytest.mark.slow) for m in method_names() if m != "legs"],
)
def test_loop_follows_the_engine_step_for_step(setup, method):
    tables = setup
    P, K = tables.p.shape[1:]
    m = methods_mod.get(method)
    # k = 20, n = 25 for the methods that have them (active sets fill and pruning
    # runs within H steps)
    given_hp = {n: v for n, v in {"k": 20, "n": 25}.items() if n in m.defaults()}
    hp_vals = dict(m.defaults(), **given_hp)
    cfg = Config(num_poses=P, num_grasps=K, **{n: hp_vals[n] for n in m.static})
    fn = runtime.compiled(
        m, cfg, H, record_every=10, check_every=None, trajectory=True, dirichlet=False
    )
    ks = keys.rollout_keys(4, np.zeros(B, int), np.zeros(B, int), np.arange(B))
    hp = m.traced_hparams(**{n: jnp.full(B, hp_vals[n], jnp.float32) for n in m.traced})
    t_dev = type(tables)(*(jnp.asarray(x) for x in tables))
    out = fn(t_dev, jnp.zeros(B, jnp.int32), ks, hp)
    q = np.asarray(tables.q[0])
    valid = np.asarray(tables.valid[0])
    p = np.asarray(tables.p[0])
    for r in range(B):
        loop = Loop(method, P, K, given_hp, keys.rollout_key(4, 0, 0, r))
        assert loop.cfg == cfg
        pose = np.asarray(out["pose"][r])
        grasp = np.asarray(out["grasp"][r])
        reward = np.asarray(out["reward"][r])
        given = set()
        for t in range(1, H + 1):
            s = int(pose[t - 1])
            if s not in given:  # the reservoir arrives on the first visit
                loop.set_reservoir(s, q[s], valid[s])
                given.add(s)
            g, slot = loop.select(s, t)
            assert g == grasp[t - 1], (method, r, t)
            loop.tell(s, g, slot, bool(reward[t - 1]), t)
        rec = loop.recommendation()
        # the engine's final gap from the loop's recommendations (poses never
        # visited keep π_0 in both)
        for s in set(range(P)) - given:
            loop.set_reservoir(s, q[s], valid[s])
        rec = loop.recommendation()
        lam = np.asarray(tables.landing[0])
        perf = sum(lam[s] * p[s, rec[s]] for s in range(P) if rec[s] >= 0)
        gap = float(lam @ p.max(-1) - perf)
        assert gap == pytest.approx(float(out["final_gap"][r]), abs=1e-5)


def test_oracles_are_refused():
    from legs_jax.errors import ConfigError

    assert "k100_ub" not in method_names()
    with pytest.raises(ConfigError, match="ground-truth"):
        Loop("k100_ub", 2, 10, {}, keys.rollout_key(0, 0, 0, 0))
    with pytest.raises(ConfigError, match="unknown method"):
        Loop("nope", 2, 10, {}, keys.rollout_key(0, 0, 0, 0))


def test_hyperparameters_are_the_methods_own():
    from legs_jax.errors import ConfigError
    from legs_jax.online._adapter import check_hparams

    assert check_hparams("legs", {"k": 5}, 10) == dict(
        methods_mod.get("legs").defaults(), k=5
    )
    assert check_hparams("tql", None, 10) == {"epsilon": 0.1, "eta": 0.1}
    with pytest.raises(ConfigError, match="unknown hyperparameter"):
        check_hparams("dexnet", {"k": 5}, 10)
    with pytest.raises(ConfigError, match="delta"):
        check_hparams("legs", {"delta": 1.5}, 10)
    # a session recorded with every method's hyperparameters (as sessions were
    # before each method declared its own) resumes with the method's own
    every = dict(methods_mod.column_defaults(), k=5, n=7, eta=0.3)
    key = keys.rollout_key(0, 0, 0, 0)
    for name in ("legs", "tql"):
        m = methods_mod.get(name)
        loop = Loop(name, 2, 10, every, key)
        own = {n: every[n] for n in m.defaults()}
        assert loop.hp_values == own
        assert loop.cfg == Config(2, 10, **{n: own[n] for n in m.static})
        assert loop.hp._fields == m.traced
        for n in m.traced:
            np.testing.assert_array_equal(loop.hp._asdict()[n], [np.float32(own[n])])
