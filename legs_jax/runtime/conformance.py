"""Conformance checks every method passes, ours and the user's.

:func:`legs_jax.core.methods.base.check_declaration` looks at a
:class:`~legs_jax.core.methods.base.Method` without running it (the functions are
callables, the hyperparameters a NamedTuple with defaults inside their declared
ranges, the static ones among them); :func:`check` runs it on a small synthetic
problem with padded poses and grasps, invalid grasps and a pose without any valid
grasp, under ``jit`` and under ``jit(vmap)`` over a grid of hyperparameters, and
checks that one program serves new keys and values (it compiles once), that it never
selects a masked grasp or one outside its own candidate set, that its outputs
are finite and its counters consistent, and that its prune (if any) changes the
pruned pose's per-grasp counts only. :func:`legs_jax.core.methods.resolve` runs the
first on a method from the user's module; the sweep runs both.

The cheapest check that can fail runs first, and each program's outputs are checked
before the next program is compiled, so a broken method is refused in seconds. The
rollouts are compiled as the sweep compiles them: the Dirichlet bounds in their own
program, shared by every method (:func:`legs_jax.runtime.compiled_checks`).
"""

from __future__ import annotations

import dataclasses
import functools

import numpy as np

from legs_jax.core import engine, keys
from legs_jax.core.methods.base import Config, Ctx, Method, check_declaration
from legs_jax.core.problem import stack
from legs_jax.errors import ConfigError
from legs_jax.runtime import rollouts as runner
from legs_jax.synthetic import make_problem

__all__ = ["check"]


@functools.cache
def _setup():
    """Tables of a padded problem: 3 real poses (one without any valid grasp)
    padded to 4, 150 grasps padded to 160, 30 % invalid grasps, 2 trials."""
    import jax
    import jax.numpy as jnp

    pb = make_problem(
        5, num_poses=3, num_grasps=150, num_trials=2, invalid_fraction=0.3,
        topple_stay=0.5, good_fraction=0.05,
    )  # fmt: skip
    valid = pb.valid.copy()
    valid[:, 2] = False
    pb = dataclasses.replace(
        pb,
        valid=valid,
        robustness=np.where(valid, pb.robustness, 0).astype(np.float32),
        prior=np.where(valid, pb.prior, 0).astype(np.float32),
    ).validate()
    batch = stack([pb], num_poses=4, num_grasps=160)
    return jax.tree.map(jnp.asarray, engine.make_tables(batch, [0, 1]))


def _fail(method: Method, what: str) -> None:
    raise ConfigError(f"method {method.name} fails its conformance check: {what}")


def check(method: Method, horizon: int = 120, rollouts: int = 8) -> None:
    """Run ``method`` and refuse it (:class:`ConfigError` naming what failed)
    unless it conforms (module docstring)."""
    import jax
    import jax.numpy as jnp

    check_declaration(method)
    tables = _setup()
    defaults = method.defaults()
    static = {n: min(int(defaults[n]), 20) for n in method.static}
    cfg = Config(num_poses=4, num_grasps=160, **static)
    b = rollouts
    ot = jnp.asarray(np.arange(b) % 2, jnp.int32)

    def hparams(g: int | None):
        vals = {}
        for n in method.traced:
            v = np.float32(defaults[n])
            vals[n] = jnp.full((b,) if g is None else (g, b), v, jnp.float32)
        return method.traced_hparams(**vals)

    if method.prune is not None and method.counts is not None:
        _prune_keeps_other_poses(method, cfg, tables, ot, hparams(None))
    checks = runner.compiled_checks()  # one program for every method
    try:
        fn = runner.compiled(
            method, cfg, horizon, check_every=40, trajectory=True, dirichlet=False
        )
        before = sum(runner.trace_counts().values())
        for i in range(2):
            ks = keys.rollout_keys(i, np.full(b, 7), np.arange(b) % 2, np.arange(b))
            _check_outputs(
                method,
                tables,
                ot,
                jax.device_get(checks(ks, fn(tables, ot, ks, hparams(None)))),
            )
        if sum(runner.trace_counts().values()) - before > 1 or fn._cache_size() != 1:
            _fail(method, "new keys or hyperparameter values recompiled it")
        vfn = runner.compiled(
            method, cfg, horizon, check_every=40, trajectory=True, grid=True,
            dirichlet=False,
        )  # fmt: skip
        r = np.arange(2 * b)
        ks = keys.rollout_keys(2, np.full(2 * b, 7), r % 2, r).reshape(2, b)
        out = jax.device_get(vfn(tables, ot, ks, hparams(2)))
        for g in range(2):  # each grid point as a batch of the plain program's
            one = {k: v[g] for k, v in out.items()}
            _check_outputs(method, tables, ot, jax.device_get(checks(ks[g], one)))
    except ConfigError:
        raise
    except Exception as e:  # noqa: BLE001 - any failure of user code, in one line
        _fail(method, f"running it raised {type(e).__name__}: {e}")


def _check_outputs(method: Method, tables, ot, o: dict) -> None:
    """Refuse ``method`` unless the outputs ``o`` of one batch of rollouts (the
    Dirichlet bounds added) are as the contract says (module docstring)."""
    valid = np.asarray(tables.valid)
    o = {k: np.asarray(v) for k, v in o.items()}
    for k, v in o.items():
        if k == "check_p_lower_eb" and method.counts is None:
            continue  # our bound is NaN by contract without per-grasp counts
        if v.dtype.kind == "f" and not np.all(np.isfinite(v)):
            _fail(method, f"{k} is not finite")
    pose, grasp, live = o["pose"], o["grasp"], o["live"]
    ot_ = np.broadcast_to(np.asarray(ot)[:, None], pose.shape)
    if not np.array_equal(live, valid[ot_, pose].any(-1)):
        _fail(method, "a step was live at a pose without a valid grasp")
    out_of_range = live & ((grasp < 0) | (grasp >= valid.shape[-1]))
    if np.any(out_of_range):
        bad = int(grasp[out_of_range].flat[0])
        _fail(
            method,
            f"it selected grasp {bad}, outside 0..{valid.shape[-1] - 1} "
            "(the grasp ids of the padded tables)",
        )
    g = np.where(live, grasp, 0)
    if not np.all(valid[ot_, pose, g][live]):
        _fail(method, "it selected a masked (invalid or padded) grasp")
    if not np.all(o["in_candidates"]):
        _fail(method, "it selected a grasp outside its own candidate set")
    if np.any(o["reward"][~live]):
        _fail(method, "a reward at a pose without a valid grasp")
    if not np.all(o["successes"] == o["reward"].sum(-1)):
        _fail(method, "its successes do not match its rewards")
    if not np.all(o["gaps"] >= -1e-6):
        _fail(method, "a negative gap")
    est = (o["check_p_lower"], o["check_true_performance"])
    if any(np.any((x < 0) | (x > 1 + 1e-6)) for x in est):
        _fail(method, "a stopping bound or performance outside [0, 1]")


def _prune_keeps_other_poses(method: Method, cfg, tables, ot, hp) -> None:
    """Refuse a prune of pose s that changes another pose's per-grasp counts:
    our bound counts the grasps a prune forgets on pose s's rows only
    (:func:`legs_jax.core.engine.agent_step`)."""
    import jax
    import jax.numpy as jnp

    B, P = ot.shape[0], cfg.num_poses
    ctx = Ctx(tables, ot, hp)

    @jax.jit
    def run():
        def step(st, t):  # every pose in turn, a success every third step
            s = jnp.full(B, t % P, jnp.int32)
            k = jax.random.split(jax.random.fold_in(jax.random.key(11), t), B)
            grasp, slot, _ = method.select(st, ctx, cfg, s, k)
            live = tables.n_valid[ot, s] > 0
            st, _ = method.update(
                st, ctx, cfg, s, grasp, slot, (t % 3 == 0) & live, live
            )
            return st, None

        st, _ = jax.lax.scan(step, method.init(ctx, cfg), jnp.arange(24 * P))
        s = jnp.zeros(B, jnp.int32)
        st2, _ = method.prune(st, ctx, cfg, s, jnp.ones(B, bool))
        return method.counts(st, ctx, cfg), method.counts(st2, ctx, cfg)

    try:
        before, after = jax.device_get(run())
    except Exception as e:  # noqa: BLE001 - any failure of user code, in one line
        _fail(
            method,
            f"running select, update and prune raised {type(e).__name__}: {e}",
        )
    for x, y in zip(before, after, strict=True):
        if not np.array_equal(np.asarray(x)[:, 1:], np.asarray(y)[:, 1:]):
            _fail(method, "its prune of pose 0 changed another pose's counts")
