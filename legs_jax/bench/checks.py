"""What a stopping check costs: the paper's bound and ours side by side, on the
same problem, and LEGS's time without checks, with the paper's bound only and
with both. The paper's bound takes its quantile over M Dirichlet samples; ours
over the first M' of the same samples (``NUM_EB_SAMPLES``).

One check of one rollout, per bound alone:

- the paper's: M Dirichlet draws of λ' (:func:`legs_jax.core.sampling.gamma_bins`)
  and the δ_stop quantile of Σ_s λ'_s p̂*_s
  (:func:`legs_jax.core.engine.dirichlet_quantiles`, one value vector);
- ours: the empirical-Bayes fit of every pose's G_s and the recommended grasps'
  posteriors (:func:`legs_jax.core.stopping.eb_posterior`), M' draws p'_s from
  them (:func:`legs_jax.core.stopping.draw_values`), the first M' of the same
  Dirichlet draws and the quantile of Σ_s λ'_s p'_s;
- ours with its fit bootstrapped (``BOOT_REPLICATES`` Bayesian-bootstrap fits of
  G_s, :func:`legs_jax.core.stopping.bootstrap_posterior`), the rest as ours.

Their inputs are a LEGS rollout's at a check (its slot counts, a recommended
grasp a pose): the cost depends on the shapes (rollouts, poses, slots, M), not
on the values. The engine computes both on the same λ' draws, so a run that
records both pays the Dirichlet draws once.

JAX and the modules that load it are imported inside the functions: JAX must
start after the benchmark has set one host device per core
(:func:`legs_jax.bench.common._set_host_devices`).
"""

from __future__ import annotations

from typing import Any

import numpy as np

from legs_jax.bench.common import (
    CHECK_EVERY,
    Settings,
    _interleaved_rates,
    _say,
)

# Rollouts of one timed call of the function-level comparison: one block of the
# engine's checks (``engine._CHECK_ROWS``).
CHECK_ROWS = 32
# Bootstrap replicates of our bound's fit in the timed variant.
BOOT_REPLICATES = 8


def _check_inputs(rows: int, poses: int, slots: int, seed: int = 0):
    """LEGS-like inputs of a check: [rows, poses, slots] counts, about half of
    the slots attempted, one recommended slot a pose, every pose observed, and
    the pruned grasps' [rows, poses, CELLS] cell counts."""
    rng = np.random.default_rng(seed)
    shape = (rows, poses, slots)
    tries = np.where(rng.uniform(size=shape) < 0.5, rng.integers(1, 12, shape), 0)
    p = rng.beta(2.0, 2.0, shape)
    succ = rng.binomial(tries, p).astype(np.float32)
    fail = (tries - succ).astype(np.float32)
    fit = tries > 0
    rec = np.zeros(shape, bool)
    rec[:, :, 0] = True
    fit[:, :, 0] = True
    counts = rng.integers(1, 200, (rows, poses)).astype(np.float32)
    observed = np.ones((rows, poses), bool)
    values = rng.uniform(0.3, 0.9, (rows, 1, poses)).astype(np.float32)
    # grasps an active set pruned: a quarter of the (S, F) cells hold a few
    from legs_jax.core.stopping import CELLS

    cells = (rows, poses, CELLS)
    lost = np.where(rng.uniform(size=cells) < 0.25, rng.integers(1, 6, cells), 0)
    return succ, fail, fit, rec, counts, observed, values, lost.astype(np.float32)


def bench_check_cost(cfg: Settings, poses: int, quiet: bool) -> dict[str, Any]:
    """Checks per CPU second of each bound alone, same shapes and M, timed in
    turns (:func:`legs_jax.bench.common._interleaved_rates`)."""
    import jax
    import jax.numpy as jnp

    from legs_jax.core import engine, stopping
    from legs_jax.core.constants import (
        DELTA_STOP,
        NUM_DIRICHLET_SAMPLES,
        NUM_EB_SAMPLES,
    )

    M, M2 = NUM_DIRICHLET_SAMPLES, NUM_EB_SAMPLES
    slots = 100  # LEGS's active set, k
    succ, fail, fit, rec, counts, observed, values, lost = (
        jnp.asarray(x) for x in _check_inputs(CHECK_ROWS, poses, slots)
    )
    keys = jax.random.split(jax.random.key(0), CHECK_ROWS)

    @jax.jit
    def paper(keys, counts, observed, values):
        return engine.dirichlet_quantiles(keys, counts, observed, values, DELTA_STOP, M)

    def ours_with(replicates):
        """Our check with ``replicates`` bootstrap fits of G_s (0: plug-in)."""

        @jax.jit
        def ours(keys, succ, fail, fit, rec, counts, observed):
            post = stopping.bootstrap_posterior(
                keys, succ, fail, fit, rec, lost, replicates
            )
            draws = stopping.draw_values(keys, post, M2)
            none = jnp.zeros((CHECK_ROWS, 0, poses), jnp.float32)
            return engine.dirichlet_quantiles(
                keys, counts, observed, none, DELTA_STOP, M2, draws=draws
            )

        return ours

    ours, boot = ours_with(0), ours_with(BOOT_REPLICATES)

    @jax.jit
    def fit_only(succ, fail, fit, rec):
        return stopping.eb_posterior(succ, fail, fit, rec, lost)

    def block(x):
        return lambda: jax.block_until_ready(x())

    fns = {
        "paper": block(lambda: paper(keys, counts, observed, values)),
        "ours": block(lambda: ours(keys, succ, fail, fit, rec, counts, observed)),
        "ours_fit": block(lambda: fit_only(succ, fail, fit, rec)),
        "ours_boot": block(lambda: boot(keys, succ, fail, fit, rec, counts, observed)),
    }
    _say(f"checks: the two bounds, {poses} poses, M = {M}", quiet)
    rates = _interleaved_rates(fns, CHECK_ROWS, cfg.repeats, cfg.min_seconds)
    us = {k: 1e6 / r["per_cpu_s"] for k, r in rates.items()}
    return {
        "check_cost_setup": dict(
            rows=CHECK_ROWS,
            poses=poses,
            slots=slots,
            M=M,
            M_ours=M2,
            boot_replicates=BOOT_REPLICATES,
        ),
        "check_cost_us_per_cpu": us,
        "check_cost_ours_over_paper": us["ours"] / us["paper"],
    }


def bench_legs_checks(cfg: Settings, problem, quiet: bool) -> dict[str, Any]:
    """LEGS's rollout steps per CPU second on ``problem``: without checks, with
    the paper's bound at every check, with both bounds (as the sweep records
    them) and with both, ours with its fit bootstrapped, timed in turns."""
    from legs_jax import runtime
    from legs_jax.core.problem import stack

    batch = stack([problem])
    per_trial = max(1, cfg.rollouts_sparse // 4 // cfg.trials)
    steps = cfg.trials * per_trial * cfg.horizon

    def variant(check_every, our_bound, replicates=0):
        def once():
            runtime.run(
                batch,
                "legs",
                object_ids=[0],
                num_rollouts=per_trial,
                horizon=cfg.horizon,
                check_every=check_every,
                our_bound=our_bound,
                eb_replicates=replicates,
                progress=False,
            )

        return once

    fns = {
        "none": variant(None, True),
        "paper": variant(CHECK_EVERY, False),
        "both": variant(CHECK_EVERY, True),
        "both_boot": variant(CHECK_EVERY, True, BOOT_REPLICATES),
    }
    _say("checks: LEGS without checks, with the paper's bound, with both", quiet)
    for fn in fns.values():
        fn()  # compile
    rates = _interleaved_rates(fns, steps, cfg.repeats, cfg.min_seconds)
    per_cpu = {k: r["per_cpu_s"] for k, r in rates.items()}
    checks = steps // CHECK_EVERY
    # CPU seconds a check of one rollout adds: (time with - time without) / checks
    added = {
        "paper": steps / per_cpu["paper"] - steps / per_cpu["none"],
        "ours": steps / per_cpu["both"] - steps / per_cpu["paper"],
        "ours_boot": steps / per_cpu["both_boot"] - steps / per_cpu["paper"],
    }
    return {
        "legs_checks_steps_per_cpu_s": per_cpu,
        "legs_checks_rollouts": cfg.trials * per_trial,
        "legs_checks_added_us_per_check": {
            k: 1e6 * v / checks for k, v in added.items()
        },
        "legs_checks_both_over_none": per_cpu["none"] / per_cpu["both"],
    }
