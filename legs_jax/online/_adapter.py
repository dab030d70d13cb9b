"""The one place where the online session touches the engine and the methods.

A session is one rollout (B = 1) of the batched engine's step, cut at the point
where the world answers: :meth:`Loop.select` is the engine's ``select`` and
:meth:`Loop.tell` its :func:`legs_jax.core.engine.agent_step` (update → prune where the
method's schedule says → recommendation of the pose just grasped), with the
engine's key streams
(method draws of step t from ``fold_in(method_key, t)``, check c from
``fold_in(check_key, c)``). The Dirichlet bound is
:func:`legs_jax.core.engine.dirichlet_quantiles`. Every function is jitted once per
(method, pose capacity P, reservoir size K, the method's static hyperparameters).

Hyperparameters are the method's own (``method.hparams``), validated by the
registry's rules (:func:`legs_jax.core.methods.parse_grid`, as
:func:`legs_jax.runtime.run` does): the static ones set :class:`Config`, the
traced ones are the method's ``traced_hparams`` NamedTuple with one row.

Poses appear during a session. The tables hold a fixed capacity of P poses; a
pose without a reservoir has no valid grasp. When a pose gets its reservoir the
method's state is initialised again on the new tables and that pose's rows (every
state leaf whose axis 1 has length P) are copied into the running state; the rest
of the state is kept. For the registered methods this equals having known the
pose's reservoir from step 0, since ``init`` treats poses independently.
"""

from __future__ import annotations

import functools
from collections.abc import Mapping

import jax
import jax.numpy as jnp
import numpy as np

from legs_jax.core import engine, stopping
from legs_jax.core import keys as keys_mod
from legs_jax.core import methods as methods_mod
from legs_jax.core.methods.base import Config, Ctx, Method, Tables
from legs_jax.errors import ConfigError

__all__ = ["ORACLES", "Loop", "default_method", "method_names", "check_hparams"]

# Methods that read the ground truth p (declared ``oracle``): they cannot run on a
# robot.
ORACLES = tuple(m for m in methods_mod.names() if methods_mod.get(m).card.oracle)


def default_method() -> str:
    """The method run where none is named (the registry's ``DEFAULT``)."""
    return methods_mod.DEFAULT


def method_names() -> tuple[str, ...]:
    """Registered methods that can run online (every one but the oracles)."""
    return tuple(m for m in methods_mod.names() if not methods_mod.get(m).card.oracle)


def _method(method: str) -> Method:
    """The registered method ``method``, refusing oracles and unknown names."""
    if method in methods_mod.names() and methods_mod.get(method).card.oracle:
        raise ConfigError(
            f"{method} reads the ground-truth success probabilities and cannot run "
            f"on a robot; choose one of {', '.join(method_names())}"
        )
    if method not in method_names():
        raise ConfigError(
            f"unknown method {method!r}; choose one of {', '.join(method_names())}"
        )
    return methods_mod.get(method)


def check_hparams(method: str, hparams: Mapping | None, K: int) -> dict:
    """Validated hyperparameters of ``method`` (the engine's rules), one value
    each: every one of the method's own, the integer ones as int."""
    m = _method(method)
    for name, v in (hparams or {}).items():
        if not isinstance(v, (int, float)) or isinstance(v, bool):
            raise ConfigError(f"hyperparameter {name} must be a number, got {v!r}")
    _, hp = methods_mod.parse_grid(m, dict(hparams or {}), K)
    return {
        name: (
            int(hp[name][0])
            if name in m.static or np.issubdtype(hp[name].dtype, np.integer)
            else float(hp[name][0])
        )
        for name in m.defaults()
    }


def _own(method: str, hparams: Mapping | None) -> dict:
    """``hparams`` without the hyperparameters of other methods.

    A session recorded before each method declared its own hyperparameters holds
    every method's (s, prior_offset, δ, γ, ε, η, k, n); the others were ignored
    then and are dropped here, so that such a session resumes. Names no method
    has are kept (and refused by :func:`check_hparams`).
    """
    own = set(_method(method).defaults())
    every = set(methods_mod.column_defaults())
    return {n: v for n, v in (hparams or {}).items() if n in own or n not in every}


def _order(q: np.ndarray, valid: np.ndarray) -> np.ndarray:
    key = np.where(valid, -q.astype(np.float64), np.inf)
    return np.argsort(key, axis=-1, kind="stable").astype(np.int32)


@functools.lru_cache(maxsize=32)
def _programs(method: str, cfg: Config, bound_replicates: int = 0):
    m = _method(method)
    P = cfg.num_poses

    def ctx(tables, hp):
        return Ctx(tables, jnp.zeros(1, jnp.int32), hp)

    def init(tables, hp):
        c = ctx(tables, hp)
        ms = m.init(c, cfg)
        rec = m.recommend_init(ms, c, cfg).astype(jnp.int32)
        return ms, rec

    def reinit_pose(ms, rec, tables, hp, s):
        c = ctx(tables, hp)
        fresh = m.init(c, cfg)
        rec0 = m.recommend_init(fresh, c, cfg).astype(jnp.int32)

        def splice(old, new):
            if old.ndim >= 2 and old.shape[1] == P:
                return old.at[:, s].set(new[:, s])
            return old

        return jax.tree.map(splice, ms, fresh), rec.at[:, s].set(rec0[:, s])

    def select(ms, tables, hp, s, method_key, t):
        # the step's key is folded in here, inside the jit: eagerly (a vmap of
        # fold_in traced at every call) it cost more than the method's select
        key = keys_mod.step_keys(method_key, t)
        grasp, slot, _ = m.select(ms, ctx(tables, hp), cfg, s, key)
        return grasp, slot

    def tell(ms, rec, tables, hp, s, grasp, slot, reward, t, forgotten):
        live = tables.n_valid[0, s] > 0
        # the grasps a prune forgets, kept for our bound (passed through
        # unchanged by a method that forgets none)
        a = engine.agent_step(
            m, ms, rec, ctx(tables, hp), cfg, s, grasp, slot, None, reward & live,
            live, t, forgotten,
        )  # fmt: skip
        return a.state, a.rec, a.new, a.removed, a.forgotten

    def estimates(ms, tables, hp):
        return m.estimates(ms, ctx(tables, hp), cfg)

    def ours(key, counts, observed, ms, rec, forgotten, tables, hp):
        """Our stopping bound (legs_jax.core.stopping), NaN without per-grasp counts."""
        if m.counts is None:
            return jnp.full(1, jnp.nan, jnp.float32)
        succ, fail, fit, ids = m.counts(ms, ctx(tables, hp), cfg)
        hit = (ids == rec[..., None]) & (rec[..., None] >= 0)
        post = stopping.bootstrap_posterior(
            key, succ, fail, fit, hit, forgotten, bound_replicates
        )
        draws = stopping.draw_values(key, post, engine.NUM_EB_SAMPLES)
        values = jnp.zeros(counts.shape[:1] + (1,) + counts.shape[1:], jnp.float32)
        return bound(key, counts, observed, values, draws)[:, -1]

    def bound(key, counts, observed, values, draws=None):
        """The Dirichlet bound (δ = DELTA_STOP, NUM_DIRICHLET_SAMPLES samples;
        ours, with ``draws``, on the first NUM_EB_SAMPLES of them)."""
        return engine.dirichlet_quantiles(key, counts, observed, values, draws=draws)

    return dict(
        init=jax.jit(init),
        reinit_pose=jax.jit(reinit_pose),
        select=jax.jit(select),
        tell=jax.jit(tell),
        estimates=jax.jit(estimates),
        bound=jax.jit(bound),
        ours=jax.jit(ours),
    )


class Loop:
    """One rollout of ``method`` on P pose slots of K grasps each (host side).

    Args:
      method: a registered method (not an oracle).
      num_poses: the pose capacity P.
      num_grasps: the reservoir size K.
      hparams: overrides of the method's defaults (``method.hparams``); those of
        other methods are ignored (:func:`_own`).
      rollout_key: a typed key (:func:`legs_jax.core.keys.rollout_key`).
      bound_replicates: our bound's fit of G_s: 0 (the default) the plug-in
        fit; R > 0 averaged over R Bayesian-bootstrap fits
        (:func:`legs_jax.core.stopping.bootstrap_posterior`).
    """

    def __init__(
        self, method, num_poses, num_grasps, hparams, rollout_key, bound_replicates=0
    ):
        self.method = method
        m = _method(method)
        self.hp_values = check_hparams(method, _own(method, hparams), num_grasps)
        self.cfg = Config(
            num_poses=int(num_poses),
            num_grasps=int(num_grasps),
            **{name: self.hp_values[name] for name in m.static},
        )
        self.hp = m.traced_hparams(
            **{
                name: jnp.full(1, self.hp_values[name], jnp.float32)
                for name in m.traced
            }
        )
        P, K = self.cfg.num_poses, self.cfg.num_grasps
        self.q = np.zeros((P, K), np.float32)
        self.valid = np.zeros((P, K), bool)
        self._fn = _programs(method, self.cfg, int(bound_replicates))
        self._method_key = keys_mod.method_key(rollout_key[None])
        self._check_key = keys_mod.check_key(rollout_key[None])
        self._tables = self._make_tables()
        self.state, self.rec = self._fn["init"](self._tables, self.hp)
        # grasps a prune forgot, per (S, F) cell, for our bound
        self.forgotten = jnp.zeros((1, P, stopping.CELLS), jnp.float32)

    def _make_tables(self) -> Tables:
        P, K = self.q.shape
        q = np.where(self.valid, self.q, 0.0).astype(np.float32)
        zeros_p = np.zeros((1, P), np.float32)
        return Tables(
            p=jnp.zeros((1, P, K), jnp.float32),  # unknown on a robot; never read
            q=jnp.asarray(q[None]),
            valid=jnp.asarray(self.valid[None]),
            order=jnp.asarray(_order(q, self.valid)[None]),
            n_valid=jnp.asarray(self.valid.sum(-1).astype(np.int32)[None]),
            p_star=jnp.asarray(zeros_p),
            landing=jnp.asarray(zeros_p),
            landing_cdf=jnp.asarray(zeros_p),
            topple_cdf=jnp.zeros((1, P, P), jnp.float32),
        )

    def set_reservoir(self, s: int, q: np.ndarray, valid: np.ndarray) -> None:
        """Give pose slot ``s`` its reservoir: prior qualities q [K], valid [K]."""
        self.q[s] = np.where(valid, q, 0.0)
        self.valid[s] = valid
        self._tables = self._make_tables()
        self.state, self.rec = self._fn["reinit_pose"](
            self.state, self.rec, self._tables, self.hp, jnp.int32(s)
        )

    def n_valid(self, s: int) -> int:
        return int(self.valid[s].sum())

    def select(self, s: int, t: int) -> tuple[int, int]:
        """(grasp id, method slot) to execute at step t in pose s."""
        g, slot = self._fn["select"](
            self.state,
            self._tables,
            self.hp,
            np.full(1, s, np.int32),
            self._method_key,
            np.int32(t),
        )
        return int(g[0]), int(slot[0])

    def tell(self, s: int, grasp: int, slot: int, success: bool, t: int) -> dict:
        """Learn the outcome of step t; returns the engine's counters of the step."""
        self.state, self.rec, new, removed, self.forgotten = self._fn["tell"](
            self.state,
            self.rec,
            self._tables,
            self.hp,
            np.full(1, s, np.int32),
            np.full(1, grasp, np.int32),
            np.full(1, slot, np.int32),
            np.full(1, bool(success)),
            np.int32(t),
            self.forgotten,
        )
        return {"new": bool(new[0]), "removed": int(removed[0])}

    def recommendation(self) -> np.ndarray:
        """[P] π_t: the recommended grasp id of each pose (-1 none)."""
        return np.asarray(self.rec[0])

    def estimates(self) -> tuple[np.ndarray, np.ndarray]:
        """([P], [P]) p̂*_s over all candidates and over attempted ones."""
        a, b = self._fn["estimates"](self.state, self._tables, self.hp)
        return np.asarray(a[0]), np.asarray(b[0])

    def bound(self, counts: np.ndarray, observed: np.ndarray, check: int) -> tuple:
        """(p̂_ℓ over all candidates, over attempted ones) from drop counts [P] and
        the observed poses [P]; check number ``check`` picks the draws."""
        v_all, v_att = self._fn["estimates"](self.state, self._tables, self.hp)
        key = keys_mod.step_keys(self._check_key, check)
        values = jnp.stack([v_all, v_att], axis=1).astype(jnp.float32)
        lo = self._fn["bound"](
            key,
            jnp.asarray(counts, jnp.float32)[None],
            jnp.asarray(observed, bool)[None],
            values,
        )
        return float(lo[0, 0]), float(lo[0, 1])

    def bound_ours(self, counts: np.ndarray, observed: np.ndarray, check: int) -> float:
        """Our stopping bound (:mod:`legs_jax.core.stopping`) on the same λ' draws as
        :meth:`bound`; NaN for a method without per-grasp counts."""
        key = keys_mod.step_keys(self._check_key, check)
        lo = self._fn["ours"](
            key,
            jnp.asarray(counts, jnp.float32)[None],
            jnp.asarray(observed, bool)[None],
            self.state,
            self.rec,
            self.forgotten,
            self._tables,
            self.hp,
        )
        return float(lo[0])
