"""Pooled Bayes-UCB, ours: Bayes-UCB over every grasp, each grasp's posterior also
fed by the outcomes of the other grasps of its pose, without that pool once the
object's outcomes say that the prior ranks nothing.

Why the pool. Every Beta method here starts a grasp at the prior Beta(1 + q,
2 − q), three pseudo-attempts centred on the prior quality q, whatever the
object. When the pose is harder than q says (q above the true rates), every
untried grasp keeps an optimistic index, and Bayes-UCB spends its attempts trying
many grasps once instead of telling the best few apart; when it is easier, the
reverse. The outcomes of the pose's other grasps say which: they are draws from
the same pose, whose grasps' success rates scatter around one level (the
distribution G_s that our stopping bound fits). The pool lets them speak. Over
all 2000 grasps it is what keeps the search from spreading thin: once the pose's
level is known, an untried grasp is judged at that level, not at its q alone; a
cut to the prior's top 100 is then not needed, and the best grasp of a pose is
often outside it (the K=100 upper bound is 0.046 on the Dex-Net set).

Why the switch. A pool fitted to the bulk of a pose hides its few excellent
grasps where q does not point at them: the untried ones sink to the bulk's level.
Where q ranks nothing, the paper's prior (wide, the same for every grasp) keeps
them in reach. Which case holds is told by the object's own outcomes: an
empirical-Bayes fit of how q maps to the success rates, the same fit on every
pose of the object.

How. At pose s, let S_g, F_g be grasp g's own successes and failures and
S_o = Σ_{h≠g} S_h, F_o = Σ_{h≠g} F_h those of the pose's other valid grasps,
N_o = S_o + F_o. The candidates are every valid grasp; while the prior ranks,
grasp g's posterior is

    Beta(1 + q_g + S_g + c·S_o,  2 − q_g + F_g + c·F_o),   c = min(1, M / N_o),

the paper's prior and the grasp's own outcomes plus the pose's pooled success
rate S_o / N_o as a pseudo-observation worth min(N_o, M) attempts (nothing before
any other grasp of the pose was tried). M = POOL_ATTEMPTS = 10 caps it: the pool
tells the level of the pose's grasps, not this grasp's own rate, so it never
weighs more than ten of the grasp's own attempts. Once the prior is found to rank
nothing, the posterior is the paper's (Beta(1 + q_g + S_g, 2 − q_g + F_g), no
pool): this method is then Bayes-UCB (K=2000). The choice is Bayes-UCB's on these
posteriors (the 1 − 1/(t + 1) quantile, t the attempts at the pose counting this
one; deterministic, ties to the lowest grasp id); the recommendation is the
highest posterior mean.

The test of the prior. Success rates are modelled as p_g ~ Beta(κ m_g,
κ (1 − m_g)) with m_g = σ(a + b·logit q_g), (a, b, κ) on a grid (:data:`CELLS`:
a from −2 to 2, b from 0 to 2, κ from 1 to 1024), beside the paper's prior as
its own cell. Every outcome adds its log predictive probability under each cell
(one log a cell a step, :func:`cell_loglik`): the marginal likelihood of the
object's outcomes. The best cell by the Bayesian information criterion (the
paper's prior free, every other cell penalised by 3/2 log n for its three
parameters, n the object's attempts) is read at every step; the prior ranks
nothing when that cell has b = 0 (q does not enter its m_g).

How it was chosen, on the Dex-Net Adversarial set and the generated problems of
the regimes map (the design sets): a first version pooled over the prior's top
100 and the tried grasps only (mean final gap 0.086 on the Dex-Net set); every
valid grasp as a candidate lowered it to 0.078 (paired over the 13 objects
−0.008 ± 0.004). With every grasp a candidate, M = 3, 10 and 30 were measured
again: 0.085 for both 3 and 30 against 0.078 for 10 (paired +0.008 ± 0.005 and
+0.007 ± 0.002; 10 lower on 10 and 11 of the 13 objects). The switch was
designed on the generated problems (without it three of the four of C-index 0.5
lose 0.025-0.038 to Bayes-UCB (K=2000)); on the Dex-Net set it rarely fires. The
grid and the criterion are standard choices, not fitted. EGAD! was run with the
first version, and once with this one, after it was chosen.
:class:`Reference` is its NumPy twin.
"""

from __future__ import annotations

from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from legs_jax.core.methods import _dense
from legs_jax.core.methods import bayes_ucb_2000 as ucb
from legs_jax.core.methods.base import (
    Q_CLIP,
    Card,
    Method,
    best_estimates,
    beta_counts,
    gather_at,
    gather_rows,
)

__all__ = [
    "CELLS",
    "METHOD",
    "POOL_ATTEMPTS",
    "PooledState",
    "Reference",
    "cell_loglik",
    "pooled",
    "ranks_nothing",
]

# M: the most attempts the pose's pooled outcomes count for in a grasp's prior.
POOL_ATTEMPTS = 10.0
# The grid of priors p ~ Beta(κ m, κ (1 − m)), m = σ(a + b·logit q): rows (a, b, κ).
CELLS = (
    np.array(
        np.meshgrid(
            np.arange(-2.0, 2.01, 0.5),
            np.array([0.0, 0.5, 1.0, 1.5, 2.0]),
            2.0 ** np.arange(0, 11),
            indexing="ij",
        )
    )
    .reshape(3, -1)
    .T
)
# The information criterion's penalty: half a log n per free parameter.
PENALTY = 1.5
NUM_CELLS = len(CELLS) + 1  # cell 0: the paper's prior


class PooledState(NamedTuple):
    inner: Any  # _dense.DenseState: the paper's prior plus each grasp's own outcomes
    count: jax.Array  # [B, P] i32 grasp attempts made at each pose
    loglik: jax.Array  # [B, NUM_CELLS] f32 log marginal likelihood of each cell


def _logit(q):
    qc = jnp.clip(q, *Q_CLIP)
    return jnp.log(qc) - jnp.log1p(-qc)


def cell_priors(q):
    """α0, β0 [..., NUM_CELLS] of every cell for grasps of quality q [...]."""
    a, b, k = (jnp.asarray(CELLS[:, i], jnp.float32) for i in range(3))
    m = jax.nn.sigmoid(a + b * _logit(q)[..., None])
    qc = jnp.clip(q, *Q_CLIP)[..., None]
    return (
        jnp.concatenate([1.0 + qc, k * m], axis=-1),
        jnp.concatenate([2.0 - qc, k * (1.0 - m)], axis=-1),
    )


def cell_loglik(q, succ, fail, reward):
    """[B, NUM_CELLS] log predictive probability of ``reward`` [B] for a grasp of
    quality q [B] with ``succ``, ``fail`` [B] earlier outcomes, under each cell."""
    a0, b0 = cell_priors(q)
    hit = jnp.where(reward[:, None], a0 + succ[:, None], b0 + fail[:, None])
    return jnp.log(hit) - jnp.log(a0 + b0 + (succ + fail)[:, None])


def ranks_nothing(loglik, attempts) -> jax.Array:
    """[B] bool: the best cell by the information criterion has b = 0
    (``loglik`` [B, NUM_CELLS], ``attempts`` [B] the object's attempts)."""
    n = jnp.maximum(attempts.astype(jnp.float32), 1.0)
    pen = jnp.where(jnp.arange(NUM_CELLS) == 0, 0.0, PENALTY * jnp.log(n)[:, None])
    best = jnp.argmax(loglik - pen, axis=-1)
    flat = jnp.asarray(np.concatenate([[False], CELLS[:, 1] == 0.0]))
    return flat[best]


def pooled(alpha, beta, succ, fail, mask):
    """The pooled posteriors (α', β') of a pose's candidates [..., N] from their
    own posteriors ``alpha``, ``beta`` and own counts ``succ``, ``fail``
    (``mask``: the candidates; the others are returned unchanged)."""
    s = jnp.where(mask, succ, 0.0)
    f = jnp.where(mask, fail, 0.0)
    so = jnp.sum(s, axis=-1, keepdims=True) - s
    fo = jnp.sum(f, axis=-1, keepdims=True) - f
    no = so + fo
    c = jnp.where(no > 0, jnp.minimum(1.0, POOL_ATTEMPTS / jnp.maximum(no, 1.0)), 0.0)
    c = jnp.where(mask, c, 0.0)
    return alpha + c * so, beta + c * fo


def _posterior(alpha, beta, succ, fail, valid, flat):
    """Posteriors over the last axis, whose candidates are the ``valid`` grasps:
    pooled, or (``flat`` [B], broadcast) the paper's, unpooled."""
    flat = flat.reshape(flat.shape + (1,) * (alpha.ndim - 1))
    a, b = pooled(alpha, beta, succ, fail, valid)
    return jnp.where(flat, alpha, a), jnp.where(flat, beta, b), valid


def _row(st: PooledState, ctx, s):
    a, b = gather_at(st.inner.alpha, s), gather_at(st.inner.beta, s)
    succ, fail = beta_counts(a, b, gather_rows(ctx.tables.q, ctx.ot, s), ctx.hp)
    valid = gather_rows(ctx.tables.valid, ctx.ot, s)
    flat = ranks_nothing(st.loglik, jnp.sum(st.count, axis=-1))
    a, b, mask = _posterior(a, b, succ, fail, valid, flat)
    return a, b, succ, fail, mask


def init(ctx, cfg) -> PooledState:
    inner = _dense.init(ctx, cfg, removable=False)
    count = jnp.zeros(ctx.tables.n_valid[ctx.ot].shape, jnp.int32)
    loglik = jnp.zeros((count.shape[0], NUM_CELLS), jnp.float32)
    return PooledState(inner, count, loglik)


def select(st: PooledState, ctx, cfg, s, key):  # key unused: deterministic
    a, b, succ, fail, mask = _row(st, ctx, s)
    grasp = ucb.choose_few(ucb.level(gather_at(st.count, s)), a, b, mask, succ, fail)
    return grasp, grasp, None  # the pool changes every grasp: recommend reads the state


def update(st: PooledState, ctx, cfg, s, grasp, slot, reward, live):
    bi = jnp.arange(s.shape[0])
    q = ctx.tables.q[ctx.ot, s, grasp]
    succ, fail = beta_counts(
        st.inner.alpha[bi, s, grasp], st.inner.beta[bi, s, grasp], q, ctx.hp
    )
    ll = jnp.where(live[:, None], cell_loglik(q, succ, fail, reward), 0.0)
    inner, new = _dense.update(st.inner, ctx, cfg, s, grasp, slot, reward, live)
    count = st.count.at[bi, s].add(live.astype(jnp.int32))
    return PooledState(inner, count, st.loglik + ll), new


def recommend(st: PooledState, ctx, cfg, s):
    a, b, _, _, mask = _row(st, ctx, s)
    return _dense.best_mean(a, b, mask)


def _all(st: PooledState, ctx):
    """Posteriors and candidates [B, P, K] of every pose."""
    inner = st.inner
    q = ctx.tables.q[ctx.ot]
    succ, fail = beta_counts(inner.alpha, inner.beta, q, ctx.hp)
    flat = ranks_nothing(st.loglik, jnp.sum(st.count, axis=-1))
    valid = ctx.tables.valid[ctx.ot]
    return _posterior(inner.alpha, inner.beta, succ, fail, valid, flat)


def estimates(st: PooledState, ctx, cfg):
    a, b, mask = _all(st, ctx)
    return best_estimates(a / (a + b), mask, st.inner.attempted)


class Reference(ucb.Reference):
    """The NumPy twin: the same test of the prior, the pooled posteriors
    (float64) and the Bayes-UCB choice."""

    def __init__(self, problem, trial, hp):
        super().__init__(problem, trial, hp, top=None)
        self.succ = np.zeros(self.q.shape)
        self.fail = np.zeros(self.q.shape)
        self.loglik = np.zeros(NUM_CELLS)
        self._sync()

    def _sync(self) -> None:
        """The test of the prior after an update (``flat``: no pool). The
        candidates are every valid grasp throughout (``cand``, set with
        ``top=None``)."""
        n = max(self.count.sum(), 1)
        pen = np.where(np.arange(NUM_CELLS) == 0, 0.0, PENALTY * np.log(n))
        best = int(np.argmax(self.loglik - pen))
        self.flat = best > 0 and CELLS[best - 1, 1] == 0.0

    def update(self, s: int, a: int, r: bool) -> None:
        qc = float(np.clip(self.q[s, a], *Q_CLIP))
        ca, cb, ck = CELLS.T
        m = 1.0 / (1.0 + np.exp(-(ca + cb * np.log(qc / (1.0 - qc)))))
        a0 = np.concatenate([[1.0 + qc], ck * m])
        b0 = np.concatenate([[2.0 - qc], ck * (1.0 - m)])
        sg, fg = self.succ[s, a], self.fail[s, a]
        hit = a0 + sg if r else b0 + fg
        self.loglik += np.log(hit) - np.log(a0 + b0 + sg + fg)
        super().update(s, a, r)
        (self.succ if r else self.fail)[s, a] += 1.0
        self._sync()

    def _pooled(self, s: int, idx: np.ndarray):
        if self.flat:
            return self.alpha[s, idx], self.beta[s, idx]
        succ, fail = self.succ[s, idx], self.fail[s, idx]
        so, fo = succ.sum() - succ, fail.sum() - fail
        no = so + fo
        c = np.where(no > 0, np.minimum(1.0, POOL_ATTEMPTS / np.maximum(no, 1.0)), 0.0)
        return self.alpha[s, idx] + c * so, self.beta[s, idx] + c * fo

    def select(self, s: int, rng: np.random.Generator) -> int:
        from scipy.special import betaincinv  # the NumPy twin only

        idx = np.flatnonzero(self.cand[s])  # ascending ids: argmax takes the lowest
        a, b = self._pooled(s, idx)
        lv = 1.0 - 1.0 / (self.count[s] + 2.0)
        return int(idx[np.argmax(betaincinv(a, b, lv))])

    def _score(self) -> np.ndarray:
        out = np.full(self.q.shape, -np.inf)
        for s in range(self.q.shape[0]):
            idx = np.flatnonzero(self.cand[s])
            if idx.size:
                a, b = self._pooled(s, idx)
                out[s, idx] = a / (a + b)
        return out

    def _recommend_pose(self, s: int) -> int:
        idx = np.flatnonzero(self.cand[s])
        if idx.size == 0:
            return -1
        if not self.visited[s]:
            return int(idx[np.argmax(self.q[s, idx])])
        a, b = self._pooled(s, idx)
        return int(idx[np.argmax(a / (a + b))])


METHOD = Method(
    name="pooled_ucb",
    description=(
        "Pooled Bayes-UCB, ours: Bayes-UCB over every grasp, each grasp's prior "
        "fed by its pose's other outcomes (at most 10 attempts' worth), without "
        "that pool once the object's outcomes say the prior ranks nothing"
    ),
    init=init,
    select=select,
    update=update,
    recommend=recommend,
    recommend_init=lambda st, ctx, cfg: _dense.recommend_init(st.inner, ctx, cfg),
    estimates=estimates,
    counts=lambda st, ctx, cfg: _dense.counts(st.inner, ctx, cfg),
    candidates=lambda st, ctx, cfg: _all(st, ctx)[2],
    card=Card(
        label="Pooled Bayes-UCB (ours)",
        short_label="PooledUCB",
        style=dict(color="#e377c2", ls="-", lw=2.4),
        dense=True,
        bench=True,
        reference=Reference,
    ),
)
