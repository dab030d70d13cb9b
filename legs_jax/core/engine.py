"""The rollout engine: every method on a batch of rollouts, in JAX.

One engine owns the loop (a nested ``lax.scan``: checks → blocks of steps → steps),
the environment, the masks, the metrics and the counters;
the methods (:mod:`legs_jax.core.methods`) are small pure functions over their own
state. Every step is written with an explicit batch axis B (one row per rollout)
and gathers only the current pose's row of the method's state.

A method's hyperparameters are traced, one value per rollout, so a grid of them
is part of the batch, except those it declares static; those, K, P, H and the
recording intervals set shapes (one compile per distinct value and method).

Rules of one step t = 1..H (the reference implementation follows the same):
select a grasp of the current pose s → reward r = [u_r < p(s, a)] → the agent's
step (:func:`agent_step`: update → the method's prune of pose s where its schedule
says, LEGS(-AS)'s at t ≡ 0 (mod n) → recommendation of s refreshed) →
transition (after a success a drop s' ~ λ, counted in c_{s'}; after a failure a
topple s' ~ topple[s]). A pose with no valid grasp is a failed attempt that touches
no grasp. The gap is recorded at step 0, every ``record_every`` steps and at H;
the Dirichlet check runs every ``check_every`` steps.

Dimension letters: G grid points, O objects, T trials, R rollouts, B rollouts of a
mini-batch, N (object, trial) pairs, P poses, K grasps, k active-set size,
C1 recorded gap steps, C2 checks.

Why one file: the environment step, the agent step, the Dirichlet checks and
:func:`simulate`, which scans them, make one compiled program. They share the loop's
state types and mean nothing outside :func:`simulate`; the methods' own rules live
in :mod:`legs_jax.core.methods`.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from legs_jax.core import keys as keys_mod
from legs_jax.core import sampling, stopping
from legs_jax.core.constants import (
    DELTA_STOP,
    NUM_DIRICHLET_SAMPLES,
    NUM_EB_SAMPLES,
)
from legs_jax.core.methods.base import Config, Ctx, Method, Tables
from legs_jax.core.problem import ProblemBatch
from legs_jax.errors import ConfigError

__all__ = [
    "DELTA_STOP",
    "NUM_DIRICHLET_SAMPLES",
    "NUM_EB_SAMPLES",
    "EnvState",
    "AgentStep",
    "agent_step",
    "dirichlet_checks",
    "dirichlet_quantiles",
    "env_reset",
    "env_step",
    "forgets",
    "make_tables",
    "simulate",
]


# ------------------------------------------------------------------- the loop


class _Loop(NamedTuple):
    s: jax.Array  # [B] i32 current pose
    rec: jax.Array  # [B, P] i32 recommendation π_t (grasp id, -1 none)
    drops: jax.Array  # [B, P] i32 c_s
    observed: jax.Array  # [B, P] bool landed in or toppled into
    visited: jax.Array  # [B, P] bool grasped in at least once
    forgotten: jax.Array  # [B, P, stopping.CELLS] f32 pruned grasps per (S, F)
    successes: jax.Array  # [B] i32
    distinct: jax.Array  # [B] i32
    replacements: jax.Array  # [B] i32
    mstate: Any  # the method's state


def _next_pose(cdf: jax.Array, u: jax.Array) -> jax.Array:
    """Inverse CDF draw per row: the first pose whose cdf exceeds u·total.

    cdf [B, P], u [B]. Poses of probability 0 are never drawn.
    """
    total = cdf[:, -1:]
    i = jnp.sum(cdf <= u[:, None] * total, axis=-1, dtype=jnp.int32)
    last = jnp.sum(cdf < total, axis=-1, dtype=jnp.int32)
    return jnp.minimum(i, last)


def _uniforms(keys: jax.Array, n: int) -> jax.Array:
    return jax.vmap(lambda k: jax.random.uniform(k, (n,)))(keys)


class EnvState(NamedTuple):
    """The environment for B rollouts: which object and trial (a row of
    the tables) and the pose the object rests in."""

    ot: jax.Array  # [B] i32 row of the tables
    pose: jax.Array  # [B] i32 current pose


def env_reset(key: jax.Array, tables: Tables, ot: jax.Array) -> EnvState:
    """The first drop: pose s0 ~ λ. ``key`` [B] (consumed)."""
    u = _uniforms(key, 1)[:, 0]
    return EnvState(ot, _next_pose(tables.landing_cdf[ot], u))


def env_step(
    key: jax.Array, tables: Tables, state: EnvState, grasp: jax.Array
) -> tuple[EnvState, jax.Array, jax.Array]:
    """One grasp attempt (pure; the environment half of a step, as gymnax's
    ``step_env``).

    The reward is r = [u_r < p(s, grasp)]; after a success the object is dropped
    again (s' ~ λ), after a failure it topples (s' ~ topple[s]). A pose with no
    valid grasp is a failed attempt (not ``live``), whatever ``grasp`` says.

    Args:
      key: [B] keys (consumed: two uniforms each, u_r and the move's).
      state: the current :class:`EnvState`.
      grasp: [B] i32 grasp id to execute at the current pose.
    Returns:
      (next state, reward [B] bool, live [B] bool: the pose had a valid grasp).
    """
    ot, s = state
    live = tables.n_valid[ot, s] > 0
    u = _uniforms(key, 2)
    reward = live & (u[:, 0] < tables.p[ot, s, grasp])
    cdf = jnp.where(reward[:, None], tables.landing_cdf[ot], tables.topple_cdf[ot, s])
    return EnvState(ot, _next_pose(cdf, u[:, 1])), reward, live


def _pose_sum(x: jax.Array) -> jax.Array:
    """Σ over the last (pose) axis, strictly left to right: ((x_0 + x_1) + x_2) + ….

    ``jnp.sum`` leaves the order to XLA, which picks it by shape and by program,
    so a run padded to more poses (zeros last) could differ from the unpadded one
    in the last bit (and did, on two host devices). A loop over the poses fixes
    the order (XLA may turn additions written out into a reduction of its own
    order); padded poses add +0.0 after every real one, which changes no bit.
    x [..., P] -> [...]."""
    cols = jnp.moveaxis(x, -1, 0)
    total, _ = jax.lax.scan(lambda acc, c: (acc + c, None), cols[0], cols[1:])
    return total


def _rec_p(tables: Tables, ot: jax.Array, rec: jax.Array) -> jax.Array:
    """p[s, π(s)] of each pose, 0 where π(s) = -1. rec [B, P] -> [B, P]."""
    P = rec.shape[1]
    p = tables.p[ot[:, None], jnp.arange(P)[None, :], jnp.maximum(rec, 0)]
    return jnp.where(rec >= 0, p, 0.0)


def _performance(tables: Tables, ot: jax.Array, rec: jax.Array) -> jax.Array:
    """Σ_s λ_s p[s, π(s)] per row, poses in order; π(s) = -1 adds 0.

    rec [B, P] -> [B]."""
    return _pose_sum(tables.landing[ot] * _rec_p(tables, ot, rec))


_DOUBLINGS = 16  # terms 2^16 of the series of :func:`_after_failure`


def _after_failure(tables: Tables, ot: jax.Array, rec: jax.Array) -> jax.Array:
    """Mean attempts after a failed attempt at a landing until the next success,
    with the recommendations ``rec`` frozen (what verified stopping spends
    between two samples of its test; :mod:`legs_jax.core.verify`) per row [B].

    From pose s a frozen attempt succeeds with p_s = p[s, π(s)] (0 where π(s) =
    -1); a failure topples the object to t ~ topple[s]. The attempts until a
    success from s solve h = 1 + (1 - p) ⊙ (topple h), and a failure at a
    landing (pose ~ λ, weight λ_s (1 - p_s)) is followed by Σ_t topple[s, t] h_t
    of them. Infinite where a pose can never be left with a success; 0 where no
    attempt fails."""
    p = _rec_p(tables, ot, rec)
    cdf = tables.topple_cdf[ot]  # [B, P, P]
    topple = jnp.diff(cdf, axis=-1, prepend=jnp.zeros_like(cdf[..., :1]))

    # h = Σ_k M^k 1 with M = diag(1 - p) topple, summed by doubling (n terms ->
    # 2n: h += M^n h, M^n -> M^2n): 2^16 terms in 16 small matrix products, and no
    # linear solver (whose library call a program kept on disk may not find). A
    # pose whose chain has not died out by then (success rates below about 2e-4
    # wherever it topples) counts as never left.
    # Products as sums over poses in order (:func:`_pose_sum`), so that padded
    # poses change no bit.
    def double(_, hm):
        h, m = hm
        h = h + _pose_sum(m * h[:, None, :])
        m = _pose_sum(m[:, :, None, :] * jnp.swapaxes(m, 1, 2)[:, None, :, :])
        return h, m

    m = (1.0 - p)[..., None] * topple
    h, m = jax.lax.fori_loop(0, _DOUBLINGS, double, (jnp.ones(p.shape, jnp.float32), m))
    h = jnp.where(jnp.max(m, axis=2) < 1e-6, h, jnp.inf)  # inf: never left
    after = _pose_sum(jnp.where(topple > 0, topple * h[:, None, :], 0.0))
    fail = tables.landing[ot] * (1.0 - p)
    total = _pose_sum(fail)
    mean = _pose_sum(fail * after) / jnp.where(total > 0, total, 1.0)
    mean = jnp.where(jnp.isfinite(mean) & (mean >= 0), mean, jnp.inf)
    return jnp.where(total > 0, mean, 0.0)


def _gap(tables: Tables, ot: jax.Array, rec: jax.Array) -> jax.Array:
    total = _pose_sum(tables.landing[ot] * tables.p_star[ot])
    return total - _performance(tables, ot, rec)


def dirichlet_quantiles(
    keys: jax.Array,
    counts: jax.Array,
    observed: jax.Array,
    values: jax.Array,
    delta: float = DELTA_STOP,
    num_samples: int = NUM_DIRICHLET_SAMPLES,
    draws: jax.Array | None = None,
) -> jax.Array:
    """The δ-quantile of p' = Σ_s v_s λ'_s, λ' ~ Dir(c_s + 1 observed, 1 unseen),
    for V value vectors scored on the same M samples.

    The Dirichlet draws are exact (normalised Gamma draws from
    :func:`legs_jax.core.sampling.gamma_bins`, keyed by pose, so that padding a batch
    with more poses changes no bound); unobserved poses get no bin, the one
    "unseen" bin has value 0. The quantile interpolates linearly between order
    statistics, as ``np.quantile`` does; only the two order statistics needed are
    selected (:func:`legs_jax.core.sampling.order_statistics`), not a full sort.

    Args:
      keys: [B] keys (consumed).
      counts: [B, P] drop counts c_s.
      observed: [B, P] bool.
      values: [B, V, P] p̂*_s per value vector.
      draws: optional [B, M', P] values drawn per sample (our bound,
        :mod:`legs_jax.core.stopping`; M' <= M, ``NUM_EB_SAMPLES`` in the engine),
        scored on the first M' of the same λ' samples as one more row, with its
        own δ-quantile of M' values.
    Returns:
      [B, V] f32 bounds p̂_ℓ ([B, V + 1] with ``draws``, theirs last).
    """
    B, P = counts.shape
    M = num_samples
    if P >= sampling.MAX_BIN_ID:
        raise ConfigError(f"at most {sampling.MAX_BIN_ID - 1} poses, got {P}")
    shape = jnp.concatenate(
        [jnp.where(observed, counts + 1.0, 1.0), jnp.ones((B, 1))], axis=1
    )  # [B, P + 1]
    # Pose s is bin s, the unseen bin has an id of its own: a pose's draws do not
    # depend on how many poses the batch is padded to.
    ids = list(range(P)) + [sampling.MAX_BIN_ID]
    g = sampling.gamma_bins(keys, shape, ids, M)  # [B, M, P + 1]
    keep = jnp.concatenate([observed, jnp.ones((B, 1), bool)], axis=1)
    g = jnp.where(keep[:, None, :], g, 0.0)
    # Sums in a fixed order, written out, so that padded poses (g = 0) leave every
    # bit unchanged.
    total = sum(g[:, :, s] for s in range(P + 1))  # [B, M]
    v = jnp.where(observed[:, None, :], values, 0.0)  # [B, V, P]
    # Σ_s v_s g_s in a fixed order, written out: XLA fuses it into one pass
    # (a dot or a reduction over a broadcast was 4x slower on CPU here).
    rows = [
        sum(g[:, :, s] * v[:, i, s : s + 1] for s in range(P)) / total
        for i in range(values.shape[1])
    ]
    lo = _quantile(jnp.stack(rows, axis=1), delta) if rows else jnp.zeros((B, 0))
    if draws is None:
        return lo
    # Ours on the first M' of the same λ' samples (M' = draws.shape[1] <= M).
    m2 = draws.shape[1]
    if m2 > M:
        raise ConfigError(f"{m2} value draws for {M} Dirichlet samples")
    ours = (
        sum(
            g[:, :m2, s] * jnp.where(observed[:, s : s + 1], draws[:, :, s], 0.0)
            for s in range(P)
        )
        / total[:, :m2]
    )  # [B, M']
    return jnp.concatenate([lo, _quantile(ours[:, None], delta)], axis=1)


def _quantile(p: jax.Array, delta: float) -> jax.Array:
    """[B, V, M] -> [B, V]: the δ-quantile of each row's M values, interpolated
    linearly between the two order statistics around δ (M - 1), as
    ``np.quantile`` does."""
    M = p.shape[-1]
    pos = delta * (M - 1)
    lo = int(math.floor(pos))
    hi = min(lo + 1, M - 1)
    frac = jnp.float32(pos - lo)
    v_lo, v_hi = sampling.order_statistics(p, lo)  # [B, V] each
    if hi == lo:
        v_hi = v_lo
    return v_lo + frac * (v_hi - v_lo)


# Rows of one pass of the Dirichlet bounds: M (P + 1) draws a row, so that a
# block's draws stay in cache (on CPU 64 rows ran about 1.3x faster a row than
# 512, and since our bound's draws are one pass, 32 rows 1.1-1.2x faster than
# 64; 8 and 16 as 32). A row's bounds do not depend on the rows beside it (the
# same bits for blocks of 8 to 512 rows).
_CHECK_ROWS = 32


def _in_row_blocks(fn: Callable, *arrays):
    """``fn(*arrays)`` computed over blocks of at most ``_CHECK_ROWS`` rows (the
    leading axis), one block after another; the result is the same."""
    rows = arrays[0].shape[0]
    if rows <= _CHECK_ROWS:
        return fn(*arrays)
    n = -(-rows // _CHECK_ROWS)
    pad = n * _CHECK_ROWS - rows

    def blocks(x):
        if pad:
            x = jnp.concatenate([x, jnp.repeat(x[:1], pad, axis=0)], axis=0)
        return x.reshape((n, _CHECK_ROWS) + x.shape[1:])

    out = jax.lax.map(lambda xs: fn(*xs), tuple(blocks(x) for x in arrays))
    return out.reshape((n * _CHECK_ROWS,) + out.shape[2:])[:rows]


def dirichlet_checks(
    rollout_keys: jax.Array, out: dict[str, jax.Array]
) -> dict[str, jax.Array]:
    """Replace the check inputs of a :func:`simulate` output by the bounds.

    Check c (1-based) of a rollout draws from ``fold_in(check_key, c)``; both
    variants (p̂* over all candidates, over attempted ones) use the same samples.
    Adds ``check_p_lower`` and ``check_p_lower_attempted`` [B, C2] (NaN when the
    attempted values are absent) and removes the inputs. With ``check_eb_post``
    (the empirical-Bayes posteriors of :func:`legs_jax.core.stopping.eb_posterior`,
    [B, C2, P, GRID]) it also adds our bound ``check_p_lower_eb`` [B, C2] on the
    same λ' draws (NaN rows of the input give NaN).
    """
    out = dict(out)
    counts = out.pop("check_counts")  # [B, C2, P]
    observed = out.pop("check_observed")
    v_all = out.pop("check_values")
    v_att = out.pop("check_values_attempted", None)
    post = out.pop("check_eb_post", None)
    B, C2, _ = counts.shape
    ck = keys_mod.check_key(rollout_keys)

    def one(args):
        idx, c, o, va, vt, pe = args
        v = va[:, None] if vt is None else jnp.stack([va, vt], axis=1)

        def bounds(ck, c, o, v, *pe):
            k = keys_mod.step_keys(ck, idx)
            draws = None
            if pe:
                ok = jnp.all(jnp.isfinite(pe[0]), axis=(1, 2))
                safe = jnp.where(ok[:, None, None], pe[0], 1.0 / stopping.GRID)
                draws = stopping.draw_values(k, safe, NUM_EB_SAMPLES)
            lo = dirichlet_quantiles(
                k, c, o, v, DELTA_STOP, NUM_DIRICHLET_SAMPLES, draws=draws
            )
            if pe:
                lo = lo.at[:, -1].set(jnp.where(ok, lo[:, -1], jnp.nan))
            return lo

        extra = () if pe is None else (pe,)
        lo = _in_row_blocks(bounds, ck, c, o, v, *extra)
        nan = jnp.full(B, jnp.nan, jnp.float32)
        eb = nan if pe is None else lo[:, -1]
        att = nan if vt is None else lo[:, 1]
        return lo[:, 0], att, eb

    swap = lambda x: None if x is None else jnp.moveaxis(x, 1, 0)  # noqa: E731
    idx = jnp.arange(1, C2 + 1, dtype=jnp.int32)
    lo, lo_att, lo_eb = jax.lax.map(
        one, (idx, swap(counts), swap(observed), swap(v_all), swap(v_att), swap(post))
    )
    out["check_p_lower"] = jnp.moveaxis(lo, 0, 1).astype(jnp.float32)
    out["check_p_lower_attempted"] = jnp.moveaxis(lo_att, 0, 1).astype(jnp.float32)
    if post is not None:
        out["check_p_lower_eb"] = jnp.moveaxis(lo_eb, 0, 1).astype(jnp.float32)
    return out


class AgentStep(NamedTuple):
    """What :func:`agent_step` returns."""

    state: Any  # the method's state after the step
    rec: jax.Array  # [B, P] i32 π_t, the grasped pose's entry refreshed
    new: jax.Array  # [B] bool the (pose, grasp) had never been attempted
    removed: jax.Array  # [B] i32 grasps the prune took out
    forgotten: jax.Array  # [B, P, CELLS] f32 every grasp a prune has taken out
    # so far, per (S, F) cell: ``forgotten`` plus this step's (no cells unless
    # :func:`forgets`)


def forgets(method: Method) -> bool:
    """Whether our bound keeps count of the grasps a prune of ``method`` forgets
    (it has per-grasp counts and prunes)."""
    return method.counts is not None and method.prune is not None


def agent_step(
    method: Method,
    state: Any,
    rec: jax.Array,
    ctx: Ctx,
    cfg: Config,
    s: jax.Array,
    grasp: jax.Array,
    slot: jax.Array,
    rows: Any,
    reward: jax.Array,
    live: jax.Array,
    t: jax.Array,
    forgotten: jax.Array | None = None,
) -> AgentStep:
    """The agent's half of step t after the world answered (pure): the method's
    update → its prune of pose s where its ``prune_due`` says so → the
    recommendation of pose s refreshed. One step of :func:`simulate` and one
    ``tell`` of the online session (:mod:`legs_jax.online`) are this function.

    Args:
      state, rec: the method's state and π_{t-1} [B, P].
      s, grasp, slot, rows: the pose [B] and what ``method.select`` returned
        (``rows`` None: the recommendation reads the updated state).
      reward, live: [B] bool outcome, pose has a valid grasp (reward implies live).
      t: i32 scalar, the step (1-based).
      forgotten: [B, P, CELLS] f32 the grasps earlier prunes forgot (our bound's
        counts, :func:`legs_jax.core.stopping.forgotten_cells`); None: none yet.
        A prune is of pose s: only its row of the counts changes. Returned
        unchanged by a method that does not :func:`forgets`.
    """
    m = method
    B, P = rec.shape
    bi = jnp.arange(B)
    removed = jnp.zeros(B, jnp.int32)
    track = forgets(m)
    lost = jnp.zeros((B, stopping.CELLS if track else 0), jnp.float32)
    state, new = m.update(state, ctx, cfg, s, grasp, slot, reward, live)
    due = None
    if m.prune is not None:
        due = m.prune_due(state, ctx, cfg, s, t)

        def prune(st):
            st2, n = m.prune(st, ctx, cfg, s, live & due)
            if not track:
                return st2, n, lost
            # our bound fits every grasp attempted so far: keep count of those it
            # forgets (a prune is of pose s: its rows only)
            gone = stopping.forgotten_cells(
                tuple(x[bi, s] for x in m.counts(st, ctx, cfg)),
                tuple(x[bi, s] for x in m.counts(st2, ctx, cfg)),
            )
            return st2, n, gone

        state, removed, lost = jax.lax.cond(
            jnp.any(due), prune, lambda st: (st, removed, lost), state
        )
    if forgotten is None:
        forgotten = jnp.zeros((B, P, stopping.CELLS if track else 0), jnp.float32)
    if track:
        # added in place each step (zeros where nothing was pruned): cheaper
        # than passing the [B, P, CELLS] counts through the prune's cond
        forgotten = forgotten.at[bi, s].add(lost)
    if m.learns:
        if m.recommend_updated is None or rows is None:
            rec_s = m.recommend(state, ctx, cfg, s)
        else:
            rec_s = m.recommend_updated(rows, ctx, cfg, s, slot, reward, live)
            if due is not None:  # after a prune, read the pruned state
                rec_s = jax.lax.cond(
                    jnp.any(due), lambda: m.recommend(state, ctx, cfg, s), lambda: rec_s
                )
        rec = rec.at[bi, s].set(jnp.where(live, rec_s, rec[bi, s]))
    return AgentStep(state, rec, new, removed, forgotten)


def simulate(
    tables: Tables,
    ot: jax.Array,
    rollout_keys: jax.Array,
    hp: Any,
    *,
    method: Method,
    cfg: Config,
    horizon: int,
    record_every: int = 10,
    check_every: int | None = 100,
    attempted_variant: bool = True,
    record_active_set: bool = False,
    trajectory: bool = False,
    dirichlet: bool = True,
    eb_leave_out_rec: bool = True,
    eb_fit_start: str = "pooled",
    eb_replicates: int = 0,
    our_bound: bool = True,
) -> dict[str, jax.Array]:
    """Run B rollouts of ``method`` for ``horizon`` steps (pure; jit- and vmap-able).

    Args:
      tables: problem data of N (object, trial) pairs (:func:`make_tables`).
      ot: [B] i32 row of ``tables`` of each rollout.
      rollout_keys: [B] typed keys from :func:`legs_jax.core.keys.rollout_keys`.
      hp: the method's traced hyperparameters (``method.traced_hparams``), each
        [B].
      method: a :class:`legs_jax.core.methods.base.Method`; cfg, horizon,
        record_every, check_every: static.
      attempted_variant: also compute the Dirichlet bound over attempted grasps.
      record_active_set: return the active set at each check.
      trajectory: also return per-step ``pose``, ``grasp``, ``reward``, ``live`` and
        ``in_candidates`` [B, H] (for tests: costs a dense candidate set a step).
      dirichlet: compute the Dirichlet bounds inside (else return their inputs
        ``check_counts``, ``check_observed``, ``check_values`` and
        ``check_values_attempted`` [B, C2, P] for :func:`dirichlet_checks`, which
        :func:`legs_jax.runtime.run` compiles once and shares between methods).
      eb_leave_out_rec: our bound with G_s fitted without the recommended
        grasp's own outcomes (``leave_out_rec`` of
        :func:`legs_jax.core.stopping.eb_posterior`; the default; False: the
        earlier fit, with them).
      eb_fit_start: where our bound's fit of G_s starts (``start`` of
        :func:`legs_jax.core.stopping.eb_posterior`: ``"pooled"``, the default,
        or ``"uniform"``, the earlier bound).
      eb_replicates: 0 (the default): G_s is the plug-in fit; R > 0: the
        posterior is averaged over R Bayesian-bootstrap fits of G_s
        (:func:`legs_jax.core.stopping.bootstrap_posterior`; check c's weights
        come from ``fold_in(check_key, c)``).
      our_bound: compute our bound at the checks (the default; False: only the
        paper's bound, without our bound's fit, e.g. to time it).
    Returns:
      dict of arrays with leading axis B: ``gaps`` [B, 1 + H // L] (steps 0, L,
      2L, ...; L = gcd(record_every, check_every)), ``final_gap``,
      ``final_performance``, ``successes``, ``distinct_grasps``, ``replacements``
      [B], and when checks run ``check_p_lower``, ``check_p_lower_attempted``,
      ``check_p_lower_eb`` (our bound, with ``our_bound``),
      ``check_true_performance`` and ``check_after_failure`` (what verified
      stopping spends after a failure, :func:`_after_failure`) [B, C2]
      (and ``active_set`` [B, C2, P, k]).
    """
    m = method
    B = ot.shape[0]
    P = cfg.num_poses
    ctx = Ctx(tables, ot, hp)
    env_k = keys_mod.env_key(rollout_keys)
    met_k = keys_mod.method_key(rollout_keys)
    has_grasp = tables.n_valid > 0  # [N, P]
    bi = jnp.arange(B)

    ms = m.init(ctx, cfg)
    track = forgets(m)
    s0 = env_reset(keys_mod.step_keys(env_k, 0), tables, ot).pose
    zeros_bp = jnp.zeros((B, P), jnp.int32)
    loop = _Loop(
        s=s0,
        rec=m.recommend_init(ms, ctx, cfg).astype(jnp.int32),
        drops=zeros_bp.at[bi, s0].add(1),
        observed=jnp.zeros((B, P), bool).at[bi, s0].set(True),
        visited=jnp.zeros((B, P), bool),
        forgotten=jnp.zeros((B, P, stopping.CELLS if track else 0), jnp.float32),
        successes=jnp.zeros(B, jnp.int32),
        distinct=jnp.zeros(B, jnp.int32),
        replacements=jnp.zeros(B, jnp.int32),
        mstate=ms,
    )

    def step(c: _Loop, t):
        s = c.s
        live = has_grasp[ot, s]
        grasp, slot, rows = m.select(
            c.mstate, ctx, cfg, s, keys_mod.step_keys(met_k, t)
        )
        env, reward, _ = env_step(
            keys_mod.step_keys(env_k, t), tables, EnvState(ot, s), grasp
        )
        traj = None
        if trajectory:
            inside = m.candidates(c.mstate, ctx, cfg)[bi, s, grasp]
            traj = (s, jnp.where(live, grasp, -1), reward, live, inside | ~live)
        a = agent_step(
            m, c.mstate, c.rec, ctx, cfg, s, grasp, slot, rows, reward, live, t,
            c.forgotten,
        )  # fmt: skip
        s_next = env.pose
        c = _Loop(
            s=s_next,
            rec=a.rec,
            drops=c.drops.at[bi, s_next].add(reward.astype(jnp.int32)),
            observed=c.observed.at[bi, s_next].set(True),
            visited=c.visited.at[bi, s].set(c.visited[bi, s] | live),
            forgotten=a.forgotten,
            successes=c.successes + reward,
            distinct=c.distinct + a.new,
            replacements=c.replacements + a.removed,
            mstate=a.state,
        )
        return c, traj

    def run_steps(c: _Loop, t0, nsteps: int):
        ts = t0 + 1 + jnp.arange(nsteps, dtype=jnp.int32)
        return jax.lax.scan(step, c, ts)

    L = math.gcd(record_every, check_every) if check_every else record_every
    n_checks = horizon // check_every if check_every else 0
    bpc = check_every // L if check_every else 0  # blocks per check period
    n_blocks = horizon // L
    rem_blocks = n_blocks - n_checks * bpc
    tail = horizon - n_blocks * L

    def block(c: _Loop, blk):
        c, traj = run_steps(c, blk * L, L)
        return c, (_gap(tables, ot, c.rec), traj)

    def _eb_post(c: _Loop, idx):
        """Our bound's posteriors of the recommended grasps [B, P, GRID] at check
        ``idx`` (NaN for a method without per-grasp counts)."""
        if m.counts is None:
            return jnp.full((B, P, stopping.GRID), jnp.nan, jnp.float32)
        succ, fail, fit, ids = m.counts(c.mstate, ctx, cfg)
        rec = (ids == c.rec[..., None]) & (c.rec[..., None] >= 0)
        lost = c.forgotten if track else None
        k = keys_mod.step_keys(keys_mod.check_key(rollout_keys), idx)  # R > 0 only
        return stopping.bootstrap_posterior(
            k, succ, fail, fit, rec, lost, eb_replicates, eb_leave_out_rec,
            eb_fit_start,
        )  # fmt: skip

    def check(c: _Loop, idx):
        v_all, v_att = m.estimates(c.mstate, ctx, cfg)
        out = dict(
            check_counts=c.drops.astype(jnp.float32),
            check_observed=c.observed,
            check_values=v_all.astype(jnp.float32),
            check_true_performance=_performance(tables, ot, c.rec),
            check_after_failure=_after_failure(tables, ot, c.rec),
        )
        if attempted_variant:
            out["check_values_attempted"] = v_att.astype(jnp.float32)
        if our_bound:
            out["check_eb_post"] = _eb_post(c, idx)
        if record_active_set:
            if m.active_set is None:
                act = jnp.full((B, P, m.active_width(cfg)), -1, jnp.int32)
            else:
                act = m.active_set(c.mstate, ctx, cfg)
                act = jnp.where(c.visited[..., None], act, -1).astype(jnp.int32)
            out["active_set"] = act
        return out

    def period(c: _Loop, j):
        c, (gaps, traj) = jax.lax.scan(block, c, j * bpc + jnp.arange(bpc))
        return c, (gaps, traj, check(c, j + 1))

    gap0 = _gap(tables, ot, loop.rec)
    gap_parts = [gap0[None]]
    traj_parts = []
    checks = None
    c = loop
    if n_checks:
        c, (g1, tr1, checks) = jax.lax.scan(period, c, jnp.arange(n_checks))
        gap_parts.append(g1.reshape(-1, B))
        traj_parts.append(tr1)
    if rem_blocks:
        c, (g2, tr2) = jax.lax.scan(block, c, n_checks * bpc + jnp.arange(rem_blocks))
        gap_parts.append(g2)
        traj_parts.append(tr2)
    if tail:
        c, tr3 = run_steps(c, n_blocks * L, tail)
        traj_parts.append(tr3)

    out = dict(
        gaps=jnp.concatenate(gap_parts, axis=0).T,
        final_gap=_gap(tables, ot, c.rec),
        final_performance=_performance(tables, ot, c.rec),
        successes=c.successes,
        distinct_grasps=c.distinct,
        replacements=c.replacements,
    )
    if checks is not None:
        for name, v in checks.items():
            out[name] = jnp.moveaxis(v, 0, 1)  # [C2, B, ...] -> [B, C2, ...]
        if dirichlet:
            out = dirichlet_checks(rollout_keys, out)
    if trajectory:
        flat = []
        for tr in traj_parts:
            flat.append(jax.tree.map(lambda x: x.reshape(-1, B).T, tr))
        names = ("pose", "grasp", "reward", "live", "in_candidates")
        for i, name in enumerate(names):
            out[name] = jnp.concatenate([f[i] for f in flat], axis=1)
    return out


# ------------------------------------------------------------------ tables


def make_tables(batch: ProblemBatch, trials: Sequence[int], pad_to: int | None = None):
    """Tables for every (object, trial) pair, row o·T' + i for trial ``trials[i]``.

    Returns NumPy arrays in a :class:`Tables` (padded with copies of row 0 up to
    ``pad_to`` rows).
    """
    tr = np.asarray(trials, np.int64)
    O = batch.robustness.shape[0]
    T = len(tr)
    P, K = batch.robustness.shape[2:]
    valid = batch.valid[:, tr] & batch.pose_valid[:, None, :, None]  # [O, T, P, K]
    p = np.where(valid, batch.robustness[:, tr], 0.0).astype(np.float32)
    q = np.where(valid, batch.prior[:, tr], 0.0).astype(np.float32)
    key = np.where(valid, -q.astype(np.float64), np.inf)
    order = np.argsort(key, axis=-1, kind="stable").astype(np.int32)
    n_valid = valid.sum(-1).astype(np.int32)
    p_star = p.max(-1)
    landing = np.where(batch.pose_valid, batch.landing, 0.0).astype(np.float64)
    topple = np.where(batch.pose_valid[:, None, :], batch.topple, 0.0).astype(
        np.float64
    )
    landing_cdf = np.cumsum(landing, axis=-1).astype(np.float32)  # [O, P]
    topple_cdf = np.cumsum(topple, axis=-1).astype(np.float32)  # [O, P, P]

    def per_ot(x):  # [O, ...] -> [O*T, ...]
        return np.repeat(x, T, axis=0)

    def flat(x):  # [O, T, ...] -> [O*T, ...]
        return x.reshape((O * T,) + x.shape[2:])

    out = Tables(
        p=flat(p),
        q=flat(q),
        valid=flat(valid),
        order=flat(order),
        n_valid=flat(n_valid),
        p_star=flat(p_star),
        landing=per_ot(landing.astype(np.float32)),
        landing_cdf=per_ot(landing_cdf),
        topple_cdf=per_ot(topple_cdf),
    )
    N = O * T
    if pad_to is not None and pad_to > N:
        idx = np.concatenate([np.arange(N), np.zeros(pad_to - N, np.int64)])
        out = Tables(*(x[idx] for x in out))
    assert out.p.shape[1:] == (P, K)
    return out
