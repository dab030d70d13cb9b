"""Our stopping bound: the Dirichlet bound on an empirical-Bayes posterior.

The paper's bound (Section 4.4, :func:`legs_jax.core.engine.dirichlet_quantiles`)
plugs p̂*_s, the largest posterior mean among a pose's candidates, into
Σ_s λ'_s p̂*_s. With about a hundred candidates on a few attempts each the
largest mean is the winner's curse: it overstates the true p of the recommended
grasp, and the bound is valid at far fewer than 95 % of the checks.

Ours keeps the Dirichlet part (λ' ~ Dir(c_s + 1 observed, 1 unseen), the same
draws) and replaces the plug-in value by a draw p'_s from the posterior of the
recommended grasp's success probability under an empirical-Bayes prior:

- Model: within pose s, the success probabilities of the method's candidate
  grasps are independent draws from one distribution G_s (q, which is barely
  correlated with p inside the top 100 of a pose, is not used); grasp a's
  outcomes are Bernoulli(p_a).
- G_s is a histogram of ``GRID`` equal bins on [0, 1], fitted by maximum marginal
  likelihood (EM, ``EM_ITERATIONS`` steps from the uniform histogram) to the
  successes S_a and failures F_a of every grasp of pose s attempted so far
  **except the recommended one** (the grasp's likelihood S log θ + F log(1 − θ)
  taken at the bin centre θ): the attempted candidates in the method's state,
  and those an active set pruned, which the engine keeps as counts per (S, F)
  cell (:func:`forgotten_cells`; fitting the survivors only would see the good
  grasps and make G_s optimistic).
- The posterior of the recommended grasp is G_s reweighted by its own
  likelihood; p'_s is drawn from it exactly (a bin by its posterior weight, then
  uniform inside the bin; one uniform does both).
- Why the recommended grasp is left out of the fit (``leave_out_rec``, the
  default): most other grasps have one or two attempts, which identify little
  more than G_s's mean, so a G_s fitted with the recommendation has an upper
  tail that is mostly the recommended grasp itself, and its posterior then
  uses the same outcomes twice (an over-confident posterior). Measured on the
  Dex-Net design set (``experiments/early_stopping/bound_design.py``, LEGS,
  10 trials x 2 rollouts): valid at 82.3 % of the checks with it, 95.1 %
  without it.
- Why the fit starts narrow (``start="pooled"``, the default): a grasp tried
  once tells the fit only its pose's mean success rate; how widely p varies
  between grasps is told only by grasps tried several times. Most grasps are
  tried once or twice, so the data leave the spread of G_s open, and EM keeps
  much of the spread it starts from. From the uniform histogram (the earlier
  start, ``"uniform"``) G_s stays wide, the recommended grasp's posterior follows
  its own few outcomes, and the winner's curse returns: on hard objects its
  posterior mean overstated its true p by about 0.08. Started at the pose's
  pooled success rate, G_s widens only as far as the outcomes demand; where they
  cannot tell, the recommended grasp is shrunk toward its pose's mean, which can
  only lower the bound. Measured on reference LEGS rollouts (10 trials x 2
  rollouts, H = 3000; the same posterior recomputed in NumPy): valid at 95.8 %
  (Dex-Net) and 85.0 % (EGAD, worst object 26 %) of the checks with the uniform
  start, at 98.9 % and 98.3 % (worst object 92 %) with the pooled start.
  ``START_FLOOR`` from 1e-2 to 1e-4 and 25 or 100 EM steps gave 96-97 % on an
  EGAD subsample: the start matters, not its floor.
- The bound is the δ_stop quantile of p' = Σ_{observed s} λ'_s p'_s.

Why it should hold: given G_s the posterior of p_rec is exact whatever rule
picked the recommendation and however adaptively the grasps were tried (the
selection and the sampling read only observed data, so they drop out of the
likelihood): there is no winner's curse in a posterior under the right prior.
λ and p are independent a priori and their likelihoods factorise, so the joint
posterior is the product and p' is a draw of the true performance
Σ_s λ_s p_{s, rec} (unobserved poses count 0, which only lowers it). Its δ_stop
quantile is therefore below the truth with probability 1 − δ_stop under the
model. What is not exact: G_s is estimated (plug-in empirical Bayes, its own
uncertainty ignored; :func:`bootstrap_posterior` carries it, at about four times
the cost of a check), and a forgotten grasp with more than ``CAP - 1`` successes
or failures is counted at the cap. Ground truth never enters.
"""

from __future__ import annotations

import math

import jax
import jax.numpy as jnp

from legs_jax.core import sampling

__all__ = [
    "CAP",
    "EM_ITERATIONS",
    "FIT_STARTS",
    "GRID",
    "START_FLOOR",
    "UNIFORM_STREAM",
    "BOOT_STREAM",
    "bootstrap_posterior",
    "draw_values",
    "eb_posterior",
    "forgotten_cells",
]

GRID = 16  # histogram bins of the prior G_s
EM_ITERATIONS = 25
# Where the EM fit of G_s starts: "pooled" (the default) puts G_s at the bin of
# the pose's pooled success rate, every other bin at START_FLOOR (EM multiplies
# weights, so a bin at zero would stay at zero); "uniform" is the earlier start.
FIT_STARTS = ("pooled", "uniform")
START_FLOOR = 1e-3
UNIFORM_STREAM = 1 << 30  # fold_in data of the p' uniforms (apart from pose ids)
BOOT_STREAM = 1 << 29  # fold_in data of the bootstrap weights of G_s's fit
# Forgotten grasps (pruned from an active set) are kept as a count per (S, F)
# cell, S and F clipped to CAP - 1.
CAP = 8
CELLS = CAP * CAP


def forgotten_cells(before, after) -> jax.Array:
    """[..., CELLS] counts of the grasps a prune made the method forget.

    ``before``, ``after``: the method's ``counts`` (succ, fail, fit, ids), each
    [..., N], before and after the prune (all poses [B, P, N], or one pose's rows
    [B, N]). A fitted column whose grasp id changed or that is no longer fitted
    is forgotten (a dense method keeps its pruned grasps' counts, so it forgets
    none)."""
    succ, fail, fit, ids = before
    _, _, fit2, ids2 = after
    gone = fit & ((ids2 != ids) | ~fit2)
    cell = jnp.minimum(succ, CAP - 1).astype(jnp.int32) * CAP + jnp.minimum(
        fail, CAP - 1
    ).astype(jnp.int32)
    # A scatter-add of the forgotten columns, row by row (exact integer counts;
    # a one-hot [..., N, CELLS] cost 64 passes over the columns).
    lead, n = cell.shape[:-1], cell.shape[-1]
    rows = math.prod(lead)
    r = jnp.arange(rows)[:, None]
    out = jnp.zeros((rows, CELLS), jnp.float32)
    gone = gone.reshape(rows, n).astype(jnp.float32)
    out = out.at[r, cell.reshape(rows, n)].add(gone)
    return out.reshape(lead + (CELLS,))


def _log_lik(succ: jax.Array, fail: jax.Array) -> jax.Array:
    """[..., N] counts -> [..., N, GRID] log-likelihood at the bin centres."""
    theta = (jnp.arange(GRID, dtype=jnp.float32) + 0.5) / GRID
    return succ[..., None] * jnp.log(theta) + fail[..., None] * jnp.log1p(-theta)


def eb_posterior(
    succ: jax.Array,
    fail: jax.Array,
    fit: jax.Array,
    rec: jax.Array,
    forgotten: jax.Array | None = None,
    leave_out_rec: bool = True,
    start: str = "pooled",
    weights: jax.Array | None = None,
    cell_weights: jax.Array | None = None,
) -> jax.Array:
    """Posterior bin weights of the recommended grasp of every pose.

    Args:
      succ, fail: [B, P, N] successes and failures of each column.
      fit: [B, P, N] bool: the column's grasp enters the fit of G_s (attempted).
      rec: [B, P, N] bool: the column of the recommendation (at most one; none:
        the posterior is G_s itself).
      forgotten: optional [B, P, CELLS] counts of forgotten grasps per (S, F)
        cell (:func:`forgotten_cells`); they enter the fit like the others.
      leave_out_rec: fit G_s without the recommended grasp's own outcomes (the
        default; False: with them, the earlier fit, kept to
        compare in ``experiments/early_stopping/bound_design.py``). Fitted with
        them, G_s's upper tail is mostly the recommended grasp itself, and its
        posterior then uses the same outcomes twice (module docstring).
      start: where the fit starts (``FIT_STARTS``): ``"pooled"`` (the default),
        G_s at the pose's pooled success rate, as narrow as the histogram allows;
        ``"uniform"``, the earlier start (module docstring).
      weights, cell_weights: optional [B, P, N] and [B, P, CELLS] weights of the
        fitted grasps and of the forgotten cells in the fit of G_s (default 1 a
        grasp, the count a cell; :func:`bootstrap_posterior` draws them).
    Returns:
      [B, P, GRID] f32 posterior weights (sum 1; G_s uniform where pose s has no
      attempted grasp).
    """
    ll = _log_lik(succ.astype(jnp.float32), fail.astype(jnp.float32))
    own = jnp.sum(jnp.where(rec[..., None], ll, 0.0), axis=2)  # [B, P, J]
    m = (fit & ~rec if leave_out_rec else fit).astype(jnp.float32)
    if weights is not None:
        m = m * weights
    lik = jnp.exp(ll - jnp.max(ll, axis=-1, keepdims=True))  # [B, P, N, J]
    n = jnp.sum(m, axis=-1)
    if forgotten is not None:
        # The cells' likelihoods are one [CELLS, J] matrix shared by every pose.
        cs = jnp.arange(CELLS) // CAP
        cf = jnp.arange(CELLS) % CAP
        cell_ll = _log_lik(cs.astype(jnp.float32), cf.astype(jnp.float32))
        cell_lik = jnp.exp(cell_ll - jnp.max(cell_ll, axis=-1, keepdims=True))
        mc = forgotten.astype(jnp.float32)
        if cell_weights is not None:
            mc = jnp.where(mc > 0, cell_weights, 0.0)
        n = n + jnp.sum(mc, axis=-1)
    any_fit = n > 0
    n_fit = jnp.maximum(n, 1.0)[..., None]

    def ratio(weight, denom):  # weight / denom, 0 where nothing is weighed
        return jnp.where(weight > 0, weight / jnp.where(weight > 0, denom, 1.0), 0.0)

    def em(w, _):  # w [B, P, J]
        # w'_j = w_j Σ_i m_i L_ij / (Σ_k L_ik w_k) / n: two matrix-vector
        # products a pose instead of the responsibilities [B, P, N, J] (one
        # division a column, not one a column and bin).
        d = jnp.einsum("bpnj,bpj->bpn", lik, w)
        g = jnp.einsum("bpn,bpnj->bpj", ratio(m, d), lik)
        if forgotten is not None:
            dc = jnp.einsum("cj,bpj->bpc", cell_lik, w)
            g = g + jnp.einsum("bpc,cj->bpj", ratio(mc, dc), cell_lik)
        return w * g / n_fit, None

    flat = jnp.full(succ.shape[:2] + (GRID,), 1.0 / GRID, jnp.float32)
    if start == "uniform":
        w0 = flat
    elif start == "pooled":
        # the pooled success rate of the fitted grasps (forgotten ones included)
        wins = jnp.sum(m * succ, axis=-1)
        tries = jnp.sum(m * (succ + fail), axis=-1)
        if forgotten is not None:
            wins = wins + mc @ cs.astype(jnp.float32)
            tries = tries + mc @ (cs + cf).astype(jnp.float32)
        rate = jnp.where(tries > 0, wins / jnp.maximum(tries, 1.0), 0.5)
        j = jnp.clip(jnp.floor(rate * GRID), 0, GRID - 1).astype(jnp.int32)
        w0 = jnp.where(jnp.arange(GRID) == j[..., None], 1.0, START_FLOOR)
        w0 = (w0 / jnp.sum(w0, axis=-1, keepdims=True)).astype(jnp.float32)
    else:
        raise ValueError(f"start must be one of {FIT_STARTS}, got {start!r}")
    w, _ = jax.lax.scan(em, w0, None, length=EM_ITERATIONS)
    w = jnp.where(any_fit[..., None], w, flat)
    post = w * jnp.exp(own - jnp.max(own, axis=-1, keepdims=True))
    return post / jnp.sum(post, axis=-1, keepdims=True)


def bootstrap_posterior(
    keys: jax.Array,
    succ: jax.Array,
    fail: jax.Array,
    fit: jax.Array,
    rec: jax.Array,
    forgotten: jax.Array | None = None,
    replicates: int = 16,
    leave_out_rec: bool = True,
    start: str = "pooled",
) -> jax.Array:
    """The posterior of :func:`eb_posterior` averaged over a Bayesian bootstrap
    of the fit of G_s: [B, P, GRID].

    Replicate r of row b reweights every fitted grasp of every pose by an
    independent Exp(1) weight (a forgotten cell of c grasps by a Gamma(c, 1)
    weight, the sum of its grasps' weights), fits G_s to the weighted grasps and
    takes the recommended grasp's posterior under it; the result is the mean of
    the ``replicates`` posteriors, so a draw from it is a draw of G_s from the
    bootstrap, then of p_rec given G_s. ``keys``: [B] typed keys (row b's weights
    come from ``fold_in(keys[b], BOOT_STREAM)``: Exp(1) draws for the grasps,
    exact Gamma draws of :func:`legs_jax.core.sampling.gamma_rows` for the
    cells). ``replicates=0`` is the plug-in fit, :func:`eb_posterior` itself
    (``keys`` unused), so that callers choose the fit by one number.
    """
    B, P, N = succ.shape
    R = int(replicates)
    if R < 0:
        raise ValueError(f"replicates must be at least 0, got {replicates}")
    if R == 0:
        return eb_posterior(succ, fail, fit, rec, forgotten, leave_out_rec, start)
    k = jax.vmap(lambda k: jax.random.split(jax.random.fold_in(k, BOOT_STREAM)))(keys)
    w = jax.vmap(lambda k: jax.random.exponential(k, (R, P, N), jnp.float32))(k[:, 0])
    cw = None
    if forgotten is not None:
        c = jnp.broadcast_to(forgotten.astype(jnp.float32)[:, None], (B, R, P, CELLS))
        g = sampling.gamma_rows(k[:, 1], jnp.maximum(c, 1.0).reshape(B, -1))
        cw = jnp.where(c > 0, g.reshape(c.shape), 0.0)  # [B, R, P, CELLS]

    def one(w, cw):
        return eb_posterior(
            succ, fail, fit, rec, forgotten, leave_out_rec, start,
            weights=w, cell_weights=cw,
        )  # fmt: skip

    post = jax.vmap(one, in_axes=(1, None if cw is None else 1))(w, cw)  # [R, B, P, J]
    return jnp.mean(post, axis=0)


def draw_values(keys: jax.Array, post: jax.Array, num_samples: int) -> jax.Array:
    """p'_s draws from the histogram posteriors ``post`` [B, P, J]: [B, M, P].

    Pose s of row b draws M uniforms from ``fold_in(fold_in(keys[b],
    UNIFORM_STREAM), s)`` (padding a batch with poses changes no draw); the bin is
    the first whose cumulative weight exceeds u, the position inside it the
    remainder (u − cdf_before) / w (uniform in [0, 1) given the bin).
    """
    B, P, J = post.shape

    def row(k):
        k = jax.random.fold_in(k, UNIFORM_STREAM)
        return jax.vmap(
            lambda s: jax.random.uniform(jax.random.fold_in(k, s), (num_samples,))
        )(jnp.arange(P))  # [P, M]

    u = jax.vmap(row)(keys)  # [B, P, M]
    cdf = jnp.cumsum(post, axis=-1)  # [B, P, J]
    # The bin, the cumulative weight before it and its own weight, by a count, a
    # max and a min over the J bins (exact whatever their order; no gathers), one
    # bin after another on [B, P, M] arrays, M contiguous: one pass. The same
    # reductions over a trailing J axis of [B, M, P, J] made the check program
    # of LEGS's checks about 2x as long on CPU.
    count = jnp.zeros(u.shape, jnp.int32)
    before = jnp.zeros(u.shape, jnp.float32)
    upto = jnp.full(u.shape, jnp.inf, jnp.float32)
    for i in range(J):
        c = cdf[:, :, i, None]  # [B, P, 1]
        below = c <= u
        count = count + below
        before = jnp.maximum(before, jnp.where(below, c, 0.0))
        upto = jnp.minimum(upto, jnp.where(below, jnp.inf, c))
    j = jnp.minimum(count, J - 1)
    wj = jnp.where(jnp.isfinite(upto), upto - before, 1.0)
    frac = jnp.clip((u - before) / jnp.maximum(wj, 1e-30), 0.0, 1.0)
    return jnp.swapaxes((j.astype(jnp.float32) + frac) / J, 1, 2)
