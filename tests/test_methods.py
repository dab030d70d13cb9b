"""Conformance of every registered method and the LEGS pruning step.

Every method runs under ``jit(vmap(...))`` on a problem with padded poses and
grasps, invalid grasps and a real pose without any valid grasp: it never selects a
masked grasp or one outside its own candidate set, its outputs are finite, and a
new grid of hyperparameters or new keys do not recompile it. The LEGS removal rule
and refill agree exactly with the NumPy reference on given states.
"""

from __future__ import annotations

import dataclasses
import functools

import chex
import jax
import jax.numpy as jnp
import numpy as np
import pytest

from legs_jax import results, runtime
from legs_jax.core import engine, keys, methods
from legs_jax.core import reference as ref
from legs_jax.core.methods import _slots
from legs_jax.core.methods import legs as legs_method
from legs_jax.core.methods.base import Config, Ctx, check_declaration, prune_mask
from legs_jax.core.problem import stack
from legs_jax.errors import ConfigError
from legs_jax.runtime import conformance
from legs_jax.synthetic import make_problem

H = 300
CFG_KN = dict(k=20, n=25)
RUN = dict(horizon=H, record_every=10, check_every=100, record_active_set=True)
G, B = 3, 128  # the shared jit(vmap) program: 3 grid points x 128 rollouts
# Grid points 0 and 1 hold the defaults (256 rollouts for the parity tests);
# point 2 exercises unusual values, among them the original BORGES prior
# (prior_offset = 0, s = 5: Beta shapes below 1).
ODD = dict(s=5.0, prior_offset=0.0, delta=0.2, gamma=0.5, epsilon=0.5, eta=0.3)


def own(method: str, **hp):
    """The entries of ``hp`` that are hyperparameters of ``method``."""
    known = methods.get(method).defaults()
    return {k: v for k, v in hp.items() if k in known}


def conformance_problem():
    """3 real poses (pose 2 of trial 0 has no valid grasp), 30 % invalid grasps,
    padded to P=4, K=160. Shared with the parity tests (same compiled program)."""
    pb = make_problem(
        5, num_poses=3, num_grasps=150, num_trials=2, invalid_fraction=0.3,
        topple_stay=0.5, good_fraction=0.05,
    )  # fmt: skip
    valid = pb.valid.copy()
    valid[0, 2] = False
    return dataclasses.replace(
        pb,
        valid=valid,
        robustness=np.where(valid, pb.robustness, 0).astype(np.float32),
        prior=np.where(valid, pb.prior, 0).astype(np.float32),
    ).validate()


@functools.cache
def shared_setup():
    """(tables, cfg) of the padded conformance problem, trials 0 and 1."""
    batch = stack([conformance_problem()], num_poses=4, num_grasps=160)
    tables = jax.tree.map(jnp.asarray, engine.make_tables(batch, [0, 1]))
    return tables, Config(num_poses=4, num_grasps=160, **CFG_KN)


def grid_hparams(name: str):
    m = methods.get(name)
    vals = m.defaults()
    leaves = {}
    for n in m.traced:
        col = np.array([vals[n], vals[n], ODD[n]], np.float32)
        leaves[n] = jnp.asarray(np.repeat(col[:, None], B, 1))
    return m.traced_hparams(**leaves)


@functools.cache
def shared_run(name: str) -> dict[str, np.ndarray]:
    """3 x 128 rollouts of ``name`` under ``jit(vmap)`` over a grid axis, with the
    per-step trajectory (trials 0, 1 alternate); shared with the parity tests.
    Arrays have leading axes [G, B]."""
    tables, cfg = shared_setup()
    fn = runtime.compiled(name, cfg, **RUN, trajectory=True, grid=True, dirichlet=False)
    ot = jnp.asarray(np.arange(B) % 2, jnp.int32)
    r = np.arange(G * B)
    ks = keys.rollout_keys(0, np.full(G * B, 3), r % 2, r)  # r % 2 == ot
    out = fn(tables, ot, ks.reshape(G, B), grid_hparams(name))
    assert fn._cache_size() == 1
    flat = jax.tree.map(lambda x: x.reshape((G * B,) + x.shape[2:]), out)
    flat = jax.device_get(runtime.compiled_checks()(ks, flat))  # shared by methods
    out = {k: np.asarray(v).reshape((G, B) + v.shape[1:]) for k, v in flat.items()}
    out["ot"] = np.broadcast_to(np.asarray(ot), (G, B))
    return out


def _check_rollouts(name, tables, o, ot, horizon):
    """Masks, candidate sets, finiteness and counters of a batch of rollouts."""
    floats = {k: v for k, v in o.items() if v.dtype.kind == "f"}
    eb = floats.pop("check_p_lower_eb", None)
    chex.assert_tree_all_finite(floats)
    if eb is not None:
        # our bound needs per-grasp counts: finite for a method that keeps them,
        # NaN by contract for one that does not (TQL, the constant rows)
        if methods.get(name).counts is None:
            assert np.all(np.isnan(eb)), name
        else:
            assert np.all(np.isfinite(eb) & (eb >= 0) & (eb <= 1 + 1e-6)), name
    pose, grasp, live = o["pose"], o["grasp"], o["live"]  # [..., B, H]
    assert pose.shape[-1] == horizon
    ot_ = np.broadcast_to(np.asarray(ot)[:, None], pose.shape)
    valid = np.asarray(tables.valid)
    # live exactly where the pose has a valid grasp; never a padded pose
    assert np.array_equal(live, valid[ot_, pose].any(-1))
    assert np.all(pose < 3)
    assert not live.all()  # the empty pose is visited
    # never a masked grasp, never outside the method's candidate set
    g = np.where(live, grasp, 0)
    assert np.all(valid[ot_, pose, g][live])
    assert np.all(o["in_candidates"])
    assert np.all(grasp[~live] == -1)
    assert np.all(~o["reward"][~live])
    # gaps non-negative; counters consistent with the trajectory
    assert np.all(o["gaps"] >= -1e-6)
    assert np.all(o["successes"] == o["reward"].sum(-1))
    tried = [
        len({(int(p), int(a)) for p, a, l_ in zip(*x, strict=True) if l_})
        for x in zip(pose.reshape(-1, horizon), grasp.reshape(-1, horizon),
                     live.reshape(-1, horizon), strict=True)
    ]  # fmt: skip
    assert np.array_equal(np.asarray(tried), o["distinct_grasps"].reshape(-1))
    _method_specific(name, tables, o, live, pose, grasp, ot_)


# A method whose per-step work is a sibling's with another size or without its
# active set is conformance-checked by default through that sibling, and itself
# in the slow suite.
_SIBLING_OF = {"bayes_ucb_2000": "bayes_ucb_100", "borges_2000": "borges_100",
               "legs_no_as": "legs"}  # fmt: skip


def shared_run_params(names) -> list:
    """``names`` as parameters of a test that reads ``shared_run(name)``: each in
    the group of tests that read the same run (one worker computes it once), and
    a sibling in the slow suite."""
    return [
        pytest.param(
            n,
            marks=[pytest.mark.xdist_group(f"shared-run-{n}")]
            + ([pytest.mark.slow] if n in _SIBLING_OF else []),
        )
        for n in names
    ]


@pytest.mark.parametrize("name", shared_run_params(methods.names()))
def test_conformance_jit_vmap_grid(name):
    """Every method under jit(vmap) over a grid axis of hyperparameters: masks,
    candidate sets, finite outputs, counters (one compiled program)."""
    tables, _ = shared_setup()
    o = shared_run(name)
    assert o["pose"].shape == (G, B, H)
    _check_rollouts(name, tables, o, o["ot"][0], H)
    assert o["check_p_lower"].shape == (G, B, H // 100)
    for f in ("check_p_lower", "check_p_lower_attempted", "check_true_performance"):
        assert np.all((o[f] >= 0) & (o[f] <= 1 + 1e-6)), f
    assert np.all(o["check_p_lower_attempted"] <= o["check_p_lower"] + 1e-6)


@pytest.mark.slow
@pytest.mark.parametrize("name", methods.names())
def test_conformance_jit(name):
    """Every method under plain jit with odd hyperparameters, a second call with
    new values and keys reusing the compiled program."""
    tables, cfg = shared_setup()
    fn = runtime.compiled(name, cfg, 200, check_every=50, trajectory=True)
    b = 16
    ot = jnp.asarray(np.arange(b) % 2, jnp.int32)
    before = sum(runtime.trace_counts().values())
    m = methods.get(name)
    for i, vals in enumerate([ODD, m.defaults()]):
        ks = jax.random.split(jax.random.key(i), b)
        leaves = {n: jnp.full(b, vals[n], jnp.float32) for n in m.traced}
        hp = m.traced_hparams(**leaves)
        o = {
            k: np.asarray(v) for k, v in jax.device_get(fn(tables, ot, ks, hp)).items()
        }
        _check_rollouts(name, tables, o, np.asarray(ot), 200)
    assert sum(runtime.trace_counts().values()) - before <= 1
    assert fn._cache_size() == 1


def _method_specific(name, tables, o, live, pose, grasp, ot_):
    p = np.asarray(tables.p)
    valid = np.asarray(tables.valid)
    order = np.asarray(tables.order)
    n_valid = valid.sum(-1)
    rank = np.argsort(order, axis=-1)  # position of each grasp in the q order
    r = rank[ot_, pose, np.where(live, grasp, 0)][live]
    if name == "dexnet":
        assert np.all(r == 0)  # argmax q
    if name in ("borges_100", "k100_ub"):
        assert np.all(r < 100)  # fixed top-100 by q
    if name == "k100_ub":
        pt = np.where(rank < np.minimum(100, n_valid)[..., None], p, -1)
        best = pt.max(-1)
        assert np.all(
            p[ot_, pose, np.where(live, grasp, 0)][live] == best[ot_, pose][live]
        )
    if name in ("dexnet", "k100_ub"):
        assert np.all(o["replacements"] == 0)
        assert np.ptp(o["gaps"], axis=-1).max() == 0  # constant gap
    if name == "legs":
        act = o.get("active_set", np.full((1, 1, 4, 20), -1))
        for a in act.reshape(-1, *act.shape[-2:]):
            for row in a:
                ids = row[row >= 0]
                assert len(set(ids.tolist())) == ids.size  # no duplicates
        assert np.any(o["replacements"] > 0)
    if name in ("borges_100", "borges_2000", "tql"):
        assert np.all(o["replacements"] == 0)


def test_registry_declarations():
    for name in [n for n in methods.names() if methods.builtin(n)]:
        m = methods.get(name)
        assert m.name == name
        check_declaration(m)
        assert m.card.label and m.card.short_label and m.card.style
    assert methods.get("legs").prune is not None
    assert methods.get("legs_no_as").prune is not None
    assert methods.get("borges_2000").prune is None
    assert methods.get("legs").static == ("k", "n")
    assert [n for n in methods.names() if methods.get(n).card.oracle] == ["k100_ub"]
    # the result columns: every hyperparameter, first declarer's default
    cols = methods.column_defaults()
    assert cols["delta"] == 0.05 and cols["k"] == 100 and cols["epsilon"] == 0.1
    assert set(cols) == {"s", "prior_offset", "delta", "gamma", "k", "n"} | {
        "epsilon",
        "eta",
    }
    # the result tables carry those columns, typed as the methods declare them
    assert results.hparam_columns() == tuple(cols)
    # in the order of the committed tables (LEGS's first, then TQL's)
    assert tuple(cols) == ("s", "prior_offset", "delta", "gamma", "k", "n") + (
        "epsilon",
        "eta",
    )
    assert results.integer_hparams() == {"k", "n"}
    # LEGS owns its pruning schedule: every n-th step, whatever the pose
    legs = methods.get("legs")
    cfg = Config(num_poses=2, num_grasps=8, k=4, n=3)
    due = [
        bool(legs.prune_due(None, None, cfg, jnp.zeros(2, jnp.int32), t)[0])
        for t in range(1, 8)
    ]
    assert due == [False, False, True, False, False, True, False]
    assert legs.active_width(cfg) == 4 and methods.get("tql").active_width(cfg) == 100


def test_parse_grid_uses_the_method_declaration():
    g, hp = methods.parse_grid(methods.get("legs"), {"delta": [0.1, 0.2], "k": 30})
    assert g == 2 and hp["delta"].tolist() == [0.1, 0.2]
    assert hp["k"].dtype == np.int64 and hp["k"].tolist() == [30, 30]
    assert set(hp) == {"s", "prior_offset", "delta", "gamma", "k", "n"}
    with pytest.raises(ConfigError, match="unknown hyperparameter.*of tql"):
        methods.parse_grid(methods.get("tql"), {"delta": 0.1})
    with pytest.raises(ConfigError, match="exceeds the K = 20"):
        methods.parse_grid(methods.get("legs"), {"k": 30}, num_grasps=20)


def _broken(**changes):
    m = methods.get("borges_2000")
    return dataclasses.replace(m, name="broken", **changes)


def test_conformance_refuses_what_breaks_the_contract():
    import jax.numpy as jnp

    def masked_select(st, ctx, cfg, s, key):  # always the last (padded) grasp
        g = jnp.full(s.shape, cfg.num_grasps - 1, jnp.int32)
        return g, g, None

    with pytest.raises(ConfigError, match="masked"):
        conformance.check(_broken(select=masked_select, recommend_updated=None))

    def nan_estimates(st, ctx, cfg):
        a, b = methods.get("borges_2000").estimates(st, ctx, cfg)
        return a * jnp.nan, b

    with pytest.raises(ConfigError, match="not finite"):
        conformance.check(_broken(estimates=nan_estimates))
    with pytest.raises(ConfigError, match="NamedTuple"):
        check_declaration(_broken(hparams=dict))


def test_conformance_refuses_a_prune_that_changes_another_pose():
    # our bound counts the grasps a prune forgets on the pruned pose's rows only
    import jax.numpy as jnp

    legs = methods.get("legs")

    def leaky_prune(st, ctx, cfg, s, live):  # also forgets pose s + 1's counts
        st, removed = legs.prune(st, ctx, cfg, s, live)
        bi = jnp.arange(s.shape[0])
        nxt = (s + 1) % cfg.num_poses
        return st._replace(beta=st.beta.at[bi, nxt].add(1.0)), removed

    leaky = dataclasses.replace(legs, name="leaky", prune=leaky_prune)
    with pytest.raises(ConfigError, match="changed another pose's counts"):
        conformance.check(leaky)


def test_conformance_accepts_legs_prune():
    """LEGS's prune changes the pruned pose's counts only. The rest of the check
    LEGS passes is test_conformance_jit_vmap_grid[legs] (stricter), and the whole
    check's acceptance of a method runs in tests/test_user_method.py."""
    legs = methods.get("legs")
    tables = conformance._setup()
    cfg = Config(num_poses=4, num_grasps=160, k=20, n=20)
    b = 8
    ot = jnp.asarray(np.arange(b) % 2, jnp.int32)
    hp = legs.traced_hparams(
        **{n: jnp.full(b, legs.defaults()[n], jnp.float32) for n in legs.traced}
    )
    conformance._prune_keeps_other_poses(legs, cfg, tables, ot, hp)


@pytest.mark.slow
def test_conformance_accepts_a_registered_method():
    conformance.check(methods.get("legs"))


# ------------------------------------------------------------------ pruning


def _random_states(rng, rows, n):
    q = rng.uniform(0.01, 0.99, (rows, n))
    s = rng.choice([0.5, 1.0, 3.0], (rows, 1))
    S = rng.poisson(rng.uniform(0, 6, (rows, n)))
    F = rng.poisson(rng.uniform(0, 12, (rows, n)))
    attempted = (S + F > 0) | (rng.random((rows, n)) < 0.05)
    alpha = 1.0 + s * q + S
    beta = 1.0 + s * (1 - q) + F
    active = rng.random((rows, n)) < 0.8
    active[:, 0] = True
    delta = rng.choice([0.01, 0.05, 0.2], rows)
    gamma = rng.choice([0.1, 0.2, 0.5], rows)
    return alpha, beta, attempted, active, delta, gamma


def _margin(alpha, beta, active, delta, gamma):
    """Smallest distance of a removal comparison to its threshold (float64)."""
    from scipy.special import betaincinv

    lo = betaincinv(alpha, beta, delta)
    up = betaincinv(alpha, beta, 1 - delta)
    x_star = lo[active].max()
    return min(np.abs(up[active] - x_star).min(), np.abs(up[active] - gamma).min())


_prune = jax.jit(prune_mask)
ROWS, ARMS = 300, 40


def _run_prune(alpha, beta, attempted, active, delta, gamma):
    f32 = lambda x: jnp.asarray(x, jnp.float32)  # noqa: E731
    return np.asarray(
        _prune(f32(alpha), f32(beta), jnp.asarray(attempted), jnp.asarray(active),
               f32(delta), f32(gamma))
    )  # fmt: skip


def test_prune_mask_matches_reference_exactly():
    rng = np.random.default_rng(0)
    alpha, beta, attempted, active, delta, gamma = _random_states(rng, ROWS, ARMS)
    got = _run_prune(alpha, beta, attempted, active, delta, gamma)
    compared = removed_total = 0
    for i in range(ROWS):
        a32 = alpha[i].astype(np.float32).astype(np.float64)
        b32 = beta[i].astype(np.float32).astype(np.float64)
        if _margin(a32, b32, active[i], delta[i], gamma[i]) < 1e-4:
            continue  # a comparison within the float32 quantile tolerance
        want = ref.legs_prune(
            a32, b32, attempted[i], active[i], float(delta[i]), float(gamma[i])
        )
        np.testing.assert_array_equal(got[i], want, err_msg=f"row {i}")
        compared += 1
        removed_total += want.sum()
    assert compared >= 250 and removed_total > 1000


def test_prune_never_removes_best_or_untried():
    rng = np.random.default_rng(1)
    alpha, beta, attempted, active, delta, gamma = _random_states(rng, ROWS, ARMS)
    got = _run_prune(alpha, beta, attempted, active, delta, gamma)
    mean = np.where(active, alpha / (alpha + beta), -np.inf)
    best = mean.argmax(1)
    assert not got[np.arange(ROWS), best].any()
    assert not (got & ~attempted).any()
    assert not (got & ~active).any()
    assert got.any()


def _numpy_refill(gid, alpha, beta, attempted, nxt, removed, order, q, n_valid, hp):
    """The LEGS refill of one pose, slot by slot, written plainly."""
    gid, alpha, beta, attempted = (
        gid.copy(),
        alpha.copy(),
        beta.copy(),
        attempted.copy(),
    )
    for j in range(gid.size):
        if not removed[j]:
            continue
        if nxt < n_valid:
            g = order[nxt]
            nxt += 1
            qc = np.clip(q[g], 0.01, 0.99)
            gid[j] = g
            alpha[j] = hp["prior_offset"] + hp["s"] * qc
            beta[j] = hp["prior_offset"] + hp["s"] * (1 - qc)
        else:
            gid[j] = -1
        attempted[j] = False
    return gid, alpha, beta, attempted, nxt


def test_legs_prune_and_refill_from_a_given_state():
    """The LEGS step of one pose from a constructed state: the removal set is the
    reference's, refills take the queue in descending q, slot by slot, and empty
    slots appear once the queue is spent."""
    tables, _ = shared_setup()
    rows, k = 8, 20
    cfg = Config(num_poses=4, num_grasps=160, k=k, n=25)
    ot = jnp.asarray(np.arange(rows) % 2, jnp.int32)
    hp = legs_method.METHOD.traced_hparams(
        **{
            n: jnp.full(rows, v, jnp.float32)
            for n, v in dict(s=1.0, prior_offset=1.0, delta=0.05, gamma=0.3).items()
        }
    )
    ctx = Ctx(tables, ot, hp)
    st = jax.jit(legs_method.METHOD.init, static_argnums=1)(ctx, cfg)
    rng = np.random.default_rng(3)
    s = jnp.asarray(rng.integers(0, 2, rows), jnp.int32)  # poses with grasps
    # fail the slots' grasps a random number of times, succeed a few
    S = rng.poisson(0.3, (rows, 4, k))
    F = rng.poisson(6.0, (rows, 4, k))
    nv = np.asarray(tables.n_valid)[np.asarray(ot)]  # [rows, P]
    # rows 0, 1: the queue is almost spent
    nxt = np.minimum(np.asarray(st.next), nv)
    nxt[0, :] = np.maximum(nv[0] - 3, 0)
    nxt[1, :] = nv[1]
    st = st._replace(
        alpha=st.alpha + jnp.asarray(S, jnp.float32),
        beta=st.beta + jnp.asarray(F, jnp.float32),
        attempted=jnp.asarray((S + F) > 0) & (st.gid >= 0),
        next=jnp.asarray(nxt, jnp.int32),
    )
    live = jnp.ones(rows, bool)
    prune = jax.jit(_slots.prune_refill, static_argnums=2)
    new, n_removed = prune(st, ctx, cfg, s, live)
    st, new = jax.device_get(st), jax.device_get(new)
    order = np.asarray(tables.order)
    q = np.asarray(tables.q)
    total = 0
    for b in range(rows):
        sb, o = int(s[b]), int(ot[b])
        gid = np.asarray(st.gid[b, sb])
        a, be = (
            np.asarray(st.alpha[b, sb], np.float64),
            np.asarray(st.beta[b, sb], np.float64),
        )
        att = np.asarray(st.attempted[b, sb])
        full_a = np.ones(160)
        full_b = np.ones(160)
        full_att = np.zeros(160, bool)
        full_act = np.zeros(160, bool)
        m = gid >= 0
        full_a[gid[m]], full_b[gid[m]] = a[m], be[m]
        full_att[gid[m]], full_act[gid[m]] = att[m], True
        removed_dense = ref.legs_prune(full_a, full_b, full_att, full_act, 0.05, 0.3)
        removed = np.where(m, removed_dense[np.maximum(gid, 0)], False)
        want = _numpy_refill(
            gid, a, be, att, int(nxt[b, sb]), removed, order[o, sb], q[o, sb],
            int(nv[b, sb]), dict(s=1.0, prior_offset=1.0),
        )  # fmt: skip
        np.testing.assert_array_equal(np.asarray(new.gid[b, sb]), want[0])
        keep = want[0] >= 0
        np.testing.assert_allclose(
            np.asarray(new.alpha[b, sb])[keep], want[1][keep], rtol=1e-6
        )
        np.testing.assert_allclose(
            np.asarray(new.beta[b, sb])[keep], want[2][keep], rtol=1e-6
        )
        np.testing.assert_array_equal(np.asarray(new.attempted[b, sb]), want[3])
        assert int(new.next[b, sb]) == want[4]
        assert int(n_removed[b]) == removed.sum()
        total += removed.sum()
        # other poses untouched
        for other in range(4):
            if other != sb:
                np.testing.assert_array_equal(new.gid[b, other], st.gid[b, other])
    assert total > 20
    # the spent queues left empty slots
    assert (np.asarray(new.gid[1, int(s[1])]) == -1).any()
    # a non-live row does not change
    new2, n2 = prune(st, ctx, cfg, s, jnp.zeros(rows, bool))
    assert int(n2.sum()) == 0
    np.testing.assert_array_equal(new2.gid, st.gid)
