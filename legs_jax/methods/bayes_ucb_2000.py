"""Bayes-UCB (K=2000): the grasp of highest posterior quantile over every grasp of
the pose (Kaufmann, Cappé and Garivier, "On Bayesian upper confidence bounds for
bandit problems", AISTATS 2012). An extra row beside the paper's methods, as the
original BORGES code shipped UCB beside Thompson sampling.

At pose s, with t the number of grasp attempts made there so far counting this
one, every candidate's index is the 1 − 1/(t + 1) quantile of its Beta posterior
(SPEC §3; Kaufmann et al.'s c = 0, with t counted per pose); the highest index is
attempted (ties: the lowest grasp id). The choice is deterministic: no random
draw. Recommendation, learning and the stopping estimates are those of BORGES.
:func:`make` builds it over every grasp or over the fixed top by prior
(:mod:`legs_jax.methods.bayes_ucb_100`); :class:`Reference` is its NumPy twin.
"""

from __future__ import annotations

from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from legs_jax import reference as ref
from legs_jax import sampling
from legs_jax.methods import _dense, _slots
from legs_jax.methods.base import TOP_FIXED, Method, argmin_id_of_max, gather_at

__all__ = ["METHOD", "Reference", "UCBState", "make"]


class UCBState(NamedTuple):
    inner: Any  # the BORGES state: _dense.DenseState or _slots.SlotState
    count: jax.Array  # [B, P] i32 grasp attempts made at each pose


def level(count: jax.Array) -> jax.Array:
    """The quantile 1 − 1/(t + 1) for t = count + 1 attempts (this one included)."""
    return 1.0 - 1.0 / (count.astype(jnp.float32) + 2.0)


def make(name: str, top: bool, **declaration) -> Method:
    """Bayes-UCB over the top-100 grasps by prior (``top``) or over all K; its
    description, labels, cost, density and NumPy twin follow from ``top``
    (``declaration`` adds the rest, e.g. its style)."""
    base = _slots if top else _dense
    k = TOP_FIXED if top else 2000
    over = "the top-100" if top else "all K grasps"
    declaration = {
        "description": f"Bayes-UCB (K={k}): highest posterior quantile over {over}",
        "label": f"Bayes-UCB (K_s={k})",
        "short_label": f"BayesUCB-{k}",
        "reference": lambda problem, trial, hp: Reference(
            problem, trial, hp, top=TOP_FIXED if top else None
        ),
        **({"cost": lambda cfg: float(cfg.top)} if top else {"dense": True}),
        # the benchmark's method with the same per-step work (projection)
        "bench_proxy": "legs" if top else "borges_2000",
        **declaration,
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
        if top:
            ids = gather_at(st.inner.gid, s)
            mask = ids >= 0
        else:
            mask = _dense._mask_row(st.inner, ctx, s)
            ids = jax.lax.broadcasted_iota(jnp.int32, a.shape, 1)
        q = jnp.broadcast_to(level(gather_at(st.count, s))[:, None], a.shape)
        index = sampling.beta_ppf(q, jnp.where(mask, a, 1.0), jnp.where(mask, b, 1.0))
        grasp = argmin_id_of_max(index, mask, ids, none=0)  # ties: lowest grasp id
        if top:
            slot = jnp.argmax(ids == grasp[:, None], axis=-1).astype(jnp.int32)
            return grasp, slot, (a, b, ids)
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
        **declaration,
    )


class Reference(ref.Borges):
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


METHOD = make("bayes_ucb_2000", top=False, style=dict(color="#17becf", ls="--", lw=1.6))
