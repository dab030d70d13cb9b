"""Bayes-UCB (K=2000): the grasp of highest posterior quantile over every grasp of
the pose (Kaufmann, Cappé and Garivier, "On Bayesian upper confidence bounds for
bandit problems", AISTATS 2012). An extra row beside the paper's methods, as the
original BORGES code shipped UCB beside Thompson sampling.

At pose s, with t the number of grasp attempts made there so far counting this
one, every candidate's index is the 1 − 1/(t + 1) quantile of its Beta posterior
(Kaufmann et al.'s c = 0, with t counted per pose); the highest index is
attempted (ties: the lowest grasp id). Over all K grasps only the quantiles that
can win are computed (:func:`choose_few`): grasps with the same numbers of
successes and failures differ only by their prior, so in each such group one
grasp dominates the others (α at least theirs, β at most), and only the groups'
dominant grasps (and the grasps of many attempts) need a quantile. The choice is
deterministic: no random draw. Recommendation, learning and the stopping
estimates are those of BORGES.
:func:`make` builds it over every grasp or over the fixed top by prior
(:mod:`legs_jax.core.methods.bayes_ucb_100`); :class:`Reference` is its NumPy twin.
"""

from __future__ import annotations

from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from legs_jax.core import sampling
from legs_jax.core.methods import _beta_twin as twin
from legs_jax.core.methods import _dense, _slots
from legs_jax.core.methods.base import (
    TOP_FIXED,
    Card,
    Method,
    argmin_id_of_max,
    beta_counts,
    gather_at,
    gather_rows,
)

__all__ = ["METHOD", "Reference", "UCBState", "make"]


class UCBState(NamedTuple):
    inner: Any  # the BORGES state: _dense.DenseState or _slots.SlotState
    count: jax.Array  # [B, P] i32 grasp attempts made at each pose


def level(count: jax.Array) -> jax.Array:
    """The quantile 1 − 1/(t + 1) for t = count + 1 attempts (this one included)."""
    return 1.0 - 1.0 / (count.astype(jnp.float32) + 2.0)


def choose_dense(lv, a, b, mask, ids) -> jax.Array:
    """The highest quantile at level ``lv`` [B] of every arm of ``mask`` [B, N]
    (α ``a``, β ``b``, grasp ``ids``), ties to the lowest id: N quantiles a row."""
    q = jnp.broadcast_to(lv[:, None], a.shape)
    index = sampling.beta_ppf(q, jnp.where(mask, a, 1.0), jnp.where(mask, b, 1.0))
    return argmin_id_of_max(index, mask, ids, none=0)


# Groups of equal counts (S, F) with S, F below this; an arm of more attempts is
# always a candidate.
GROUP_COUNTS = 16


def dominated(a, b, mask, succ, fail) -> jax.Array:
    """[B, K] bool: arms of ``mask`` whose index cannot be the row's highest, by
    groups of equal counts (``succ``, ``fail`` [B, K], integers as floats).

    Within a group the arms share their counts and differ by their prior q: the
    arm of largest α, then smallest β, is the group's top, and an arm is
    dominated when the top's α is at least its α and the top's β at most its β,
    and the two are not equal (checked arm by arm, so that a group whose α and β
    do not run together keeps its other arms). The Beta quantile rises with α and
    falls with β, so a dominated arm's exact index is at most the top's; the arms
    equal to the top stay candidates, and the lowest id of them wins as in the
    dense argmax. Arms of GROUP_COUNTS or more successes or failures are never
    dominated here.
    """
    B = a.shape[0]
    g = GROUP_COUNTS
    grouped = mask & (succ < g) & (fail < g)
    gid = jnp.where(grouped, succ.astype(jnp.int32) * g + fail.astype(jnp.int32), g * g)
    bi = jnp.arange(B)[:, None]
    # per group: the largest α, then the smallest β of the arms of that α
    a_top = jnp.full((B, g * g + 1), -jnp.inf).at[bi, gid].max(a)[bi, gid]
    b_of_top = jnp.where(a == a_top, b, jnp.inf)
    b_top = jnp.full((B, g * g + 1), jnp.inf).at[bi, gid].min(b_of_top)[bi, gid]
    equal = (a == a_top) & (b == b_top)
    return grouped & (a <= a_top) & (b >= b_top) & ~equal


# Arms whose quantile one pass of :func:`choose_few` computes, a row; where a
# row of the batch has more candidates than DENSE_FROM K, every arm's quantile is
# computed in one pass (and the non-candidates' ignored) instead.
FEW = 64
DENSE_FROM = 0.5


def choose_few(lv, a, b, mask, succ, fail) -> jax.Array:
    """:func:`choose_dense` over grasp ids 0..K-1, computing only the quantiles
    that can win: those of the arms that are not :func:`dominated`.

    The candidates are packed, in id order, into blocks of ``FEW`` a row and their
    quantiles computed block by block until every row's are done; each value is
    the one the dense computation gets (:func:`legs_jax.core.sampling.beta_ppf` gives an
    element a value that depends on its own (q, α, β) only), and ties go to the
    lowest id. The choice equals the dense one's whenever the float32 quantile
    is monotone across an arm and the arm dominating it (see README, Bayes-UCB).
    """
    B, K = a.shape
    ids = jax.lax.broadcasted_iota(jnp.int32, (B, K), 1)
    cand = mask & ~dominated(a, b, mask, succ, fail)
    most = jnp.max(jnp.sum(cand, axis=-1, dtype=jnp.int32))
    return jax.lax.cond(
        most > DENSE_FROM * K,
        lambda: choose_dense(lv, a, b, cand, ids),
        lambda: _blocks(lv, a, b, cand),
    )


def _blocks(lv, a, b, pending) -> jax.Array:
    """:func:`choose_dense` over the arms of ``pending``, ``FEW`` a row at a time."""
    B, K = a.shape
    bi = jnp.arange(B)[:, None]
    pack = jax.vmap(lambda m: sampling._pending_slots(m, FEW))

    def body(carry):
        pending, best, grasp = carry
        slots = pack(pending)  # [B, FEW] ascending ids, K past the last
        real = slots < K
        g = jnp.minimum(slots, K - 1)
        q = jnp.broadcast_to(lv[:, None], g.shape)
        index = sampling.beta_ppf(
            q, jnp.where(real, a[bi, g], 1.0), jnp.where(real, b[bi, g], 1.0)
        )
        index = jnp.where(real, index, -jnp.inf)
        m = jnp.max(index, axis=-1)
        at = jnp.min(jnp.where(real & (index == m[:, None]), g, K), axis=-1)
        # blocks come in ascending ids: an equal value later loses (lowest id)
        better = m > best
        best = jnp.where(better, m, best)
        grasp = jnp.where(better, at, grasp)
        pending = pending.at[bi, slots].set(False, mode="drop")
        return pending, best, grasp

    init = (pending, jnp.full(B, -jnp.inf), jnp.zeros(B, jnp.int32))
    _, _, grasp = jax.lax.while_loop(lambda c: jnp.any(c[0]), body, init)
    return grasp


def make(name: str, top: bool, description: str, **card) -> Method:
    """Bayes-UCB over the top-100 grasps by prior (``top``) or over all K; its
    cost, density and NumPy twin follow from ``top`` (``card`` adds the rest of
    its :class:`Card`: its labels and style)."""
    base = _slots if top else _dense
    card = {
        "reference": lambda problem, trial, hp: Reference(
            problem, trial, hp, top=TOP_FIXED if top else None
        ),
        # K=100: the benchmark's method with the same per-step work (projection);
        # K=2000 computes few quantiles a step, however many arms: its own row
        **(
            {"cost": lambda cfg: float(cfg.top), "bench_proxy": "legs"}
            if top
            else {"dense": True, "bench": True}
        ),
        **card,
    }

    def init(ctx, cfg):
        if top:
            inner = _slots.init(ctx, cfg, cfg.top, refill=False)
        else:
            inner = _dense.init(ctx, cfg, removable=False)
        count = jnp.zeros(ctx.tables.n_valid[ctx.ot].shape, jnp.int32)
        return UCBState(inner, count)

    def select(st, ctx, cfg, s, key):  # key unused: the choice is deterministic
        a = gather_at(st.inner.alpha, s)
        b = gather_at(st.inner.beta, s)
        lv = level(gather_at(st.count, s))
        if top:
            ids = gather_at(st.inner.gid, s)
            mask = ids >= 0
            grasp = choose_dense(lv, a, b, mask, ids)
            slot = jnp.argmax(ids == grasp[:, None], axis=-1).astype(jnp.int32)
            return grasp, slot, (a, b, ids)
        mask = _dense._mask_row(st.inner, ctx, s)
        succ, fail = beta_counts(a, b, gather_rows(ctx.tables.q, ctx.ot, s), ctx.hp)
        grasp = choose_few(lv, a, b, mask, succ, fail)
        return grasp, grasp, (a, b, mask)

    def update(st, ctx, cfg, s, grasp, slot, reward, live):
        inner, new = base.update(st.inner, ctx, cfg, s, grasp, slot, reward, live)
        bi = jnp.arange(s.shape[0])
        return UCBState(inner, st.count.at[bi, s].add(live.astype(jnp.int32))), new

    return Method(
        name=name,
        init=init,
        select=select,
        update=update,
        recommend=lambda st, ctx, cfg, s: base.recommend(st.inner, ctx, cfg, s),
        recommend_updated=base.recommend_updated,
        recommend_init=lambda st, ctx, cfg: base.recommend_init(st.inner, ctx, cfg),
        estimates=lambda st, ctx, cfg: base.estimates(st.inner, ctx, cfg),
        counts=lambda st, ctx, cfg: base.counts(st.inner, ctx, cfg),
        candidates=lambda st, ctx, cfg: base.candidates(st.inner, ctx, cfg),
        description=description,
        card=Card(**card),
    )


class Reference(twin.Borges):
    """The NumPy twin: BORGES's posterior, the Bayes-UCB choice."""

    def __init__(self, problem, trial, hp, top: int | None):
        super().__init__(problem, trial, hp, top)
        self.count = np.zeros(self.q.shape[0], int)  # [P] attempts per pose

    def select(self, s: int, rng: np.random.Generator) -> int:
        idx = np.flatnonzero(self.cand[s])  # ascending ids: argmax takes the lowest
        q = 1.0 - 1.0 / (self.count[s] + 2.0)
        from scipy.special import betaincinv  # the NumPy twin only

        return int(idx[np.argmax(betaincinv(self.alpha[s, idx], self.beta[s, idx], q))])

    def update(self, s: int, a: int, r: bool) -> None:
        super().update(s, a, r)
        self.count[s] += 1


METHOD = make(
    "bayes_ucb_2000",
    top=False,
    description="Bayes-UCB (K=2000): highest posterior quantile over all K grasps",
    label="Bayes-UCB (K_s=2000)",
    short_label="BayesUCB-2000",
    style=dict(color="#17becf", ls="--", lw=1.6),
)
