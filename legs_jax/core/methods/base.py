"""The method interface and the pieces every method shares.

A method is a :class:`Method`: a few pure functions over its own state, each taking
and returning arrays with an explicit leading batch axis B (one row per rollout).
The engine (:mod:`legs_jax.core.engine`) owns the loop, the environment, the masks of
padding and empty poses, the metrics and the counters; a method only chooses,
learns, prunes and recommends.

Dimension letters: N (object, trial) pairs held in the tables, B rollouts,
P poses, K grasps per pose, k active-set (slot) size.
"""

from __future__ import annotations

import collections
import dataclasses
import functools
import math
from collections.abc import Callable, Mapping
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from legs_jax.core import beta_sampler, sampling
from legs_jax.core.constants import Q_CLIP, TOP_FIXED
from legs_jax.errors import ConfigError

__all__ = [
    "COUNT",
    "NON_NEGATIVE",
    "PRIOR_RANGES",
    "Q_CLIP",
    "TOP_FIXED",
    "UNIT",
    "UNIT_OPEN",
    "BetaPrior",
    "Card",
    "Config",
    "Ctx",
    "Method",
    "Range",
    "check_declaration",
    "check_prior",
    "every_n_steps",
    "Tables",
    "argmax_first",
    "argmin_id_of_max",
    "best_estimates",
    "gather_rows",
    "gather_at",
    "posterior_prior",
    "prune_mask",
    "thompson_draw",
    "updated_row",
]


class Tables(NamedTuple):
    """Problem data on the device for N (object, trial) pairs; rows index by ``ot``."""

    p: jax.Array  # [N, P, K] f32 ground-truth robustness, 0 on padding
    q: jax.Array  # [N, P, K] f32 raw prior quality, 0 on padding
    valid: jax.Array  # [N, P, K] bool real grasp
    order: jax.Array  # [N, P, K] i32 grasp ids by descending q, valid first
    n_valid: jax.Array  # [N, P] i32 number of valid grasps of each pose
    p_star: jax.Array  # [N, P] f32 best p of each pose (0 with no grasp)
    landing: jax.Array  # [N, P] f32 λ
    landing_cdf: jax.Array  # [N, P] f32 cumulative λ
    topple_cdf: jax.Array  # [N, P, P] f32 cumulative topple rows


class Range(NamedTuple):
    """The valid values of one hyperparameter (an interval, maybe integers only)."""

    low: float = -math.inf
    high: float = math.inf
    low_open: bool = False  # low itself excluded
    high_open: bool = False  # high itself excluded
    integer: bool = False

    def describe(self) -> str:
        """The range in words, as error messages give it ("x must ...")."""
        if self.integer:
            return f"be an integer >= {self.low:g}"
        if math.isinf(self.high):
            return f"be {'>' if self.low_open else '>='} {self.low:g}"
        lo = "(" if self.low_open else "["
        hi = ")" if self.high_open else "]"
        return f"lie in {lo}{self.low:g}, {self.high:g}{hi}"

    def contains(self, x: float) -> bool:
        if self.integer and float(x) != int(x):
            return False
        above = x > self.low if self.low_open else x >= self.low
        below = x < self.high if self.high_open else x <= self.high
        return bool(above and below)


UNIT_OPEN = Range(0.0, 1.0, low_open=True, high_open=True)  # (0, 1)
UNIT = Range(0.0, 1.0)  # [0, 1]
NON_NEGATIVE = Range(0.0)  # [0, inf)
COUNT = Range(1.0, integer=True)  # 1, 2, ...


class BetaPrior(NamedTuple):
    """Hyperparameters of the Beta prior, shared by the Beta methods."""

    s: float = 1.0  # prior strength
    prior_offset: float = 1.0  # the +1


PRIOR_RANGES = {"s": NON_NEGATIVE, "prior_offset": NON_NEGATIVE}


def check_prior(hp: Mapping[str, np.ndarray], num_grasps: int | None) -> None:
    """s = prior_offset = 0 would give Beta(0, 0) for untried grasps."""
    if np.any((np.asarray(hp["s"]) == 0) & (np.asarray(hp["prior_offset"]) == 0)):
        raise ConfigError(
            "s = 0 with prior_offset = 0 gives Beta(0, 0) for untried grasps; "
            "make one of them positive"
        )


class Ctx(NamedTuple):
    """What every method function may read."""

    tables: Tables
    ot: jax.Array  # [B] i32 row of the tables of each rollout
    hp: Any  # the method's traced hyperparameters (its own NamedTuple), each [B]


class Config:
    """Static (shape-setting) configuration; one compile per distinct value.

    ``Config(num_poses=P, num_grasps=K, k=100, n=100)``: P, K and the method's
    static hyperparameters, read as attributes (``cfg.k``).
    """

    __slots__ = ("num_poses", "num_grasps", "static")

    def __init__(self, num_poses: int, num_grasps: int, **static: int):
        object.__setattr__(self, "num_poses", int(num_poses))
        object.__setattr__(self, "num_grasps", int(num_grasps))
        object.__setattr__(
            self, "static", tuple(sorted((k, int(v)) for k, v in static.items()))
        )

    def __getattr__(self, name: str) -> int:
        for k, v in object.__getattribute__(self, "static"):
            if k == name:
                return v
        raise AttributeError(f"no static hyperparameter {name!r} in {self!r}")

    def __setattr__(self, name: str, value: Any) -> None:
        raise AttributeError("Config is immutable")

    def _key(self) -> tuple:
        return (self.num_poses, self.num_grasps, self.static)

    def __eq__(self, other: object) -> bool:
        return isinstance(other, Config) and self._key() == other._key()

    def __hash__(self) -> int:
        return hash(self._key())

    def __repr__(self) -> str:
        extra = "".join(f", {k}={v}" for k, v in self.static)
        return f"Config(num_poses={self.num_poses}, num_grasps={self.num_grasps}" + (
            f"{extra})"
        )

    @property
    def top(self) -> int:
        """Size of the fixed top-by-q candidate set (BORGES K=100, K100 UB)."""
        return min(TOP_FIXED, self.num_grasps)


@dataclasses.dataclass(frozen=True, eq=False)
class Card:
    """What a method is besides its algorithm: how tables, figures, the benchmark
    and the planner treat it. Declared in the method's file, beside its functions.

    ``label`` names it in tables and figures, ``short_label`` in narrow tables,
    ``style`` its line in figures; ``oracle`` marks a row that reads the ground
    truth (not a method, never a competitor, never run on a robot);
    ``cost(cfg)`` is the number of candidate grasps a step touches (planning) and
    ``dense`` says its per-step work and state are O(K) (smaller batches suit it).
    ``reference`` (or None) ``(problem, trial, hp)`` builds its one-rollout NumPy
    twin (:mod:`legs_jax.core.reference`). ``bench`` makes it a row of the benchmark's
    table (``legs_jax.bench``, timed against its NumPy twin); ``bench_proxy`` names
    a method of that table with the same per-step work, whose measured rate
    stands in for this one's when the benchmark projects a sweep. ``prior_only``
    marks a row whose gap the prior and the reservoirs alone decide, by its rule:
    ``"greedy"`` (the grasp of highest q) or ``"top"`` (the best true grasp among
    the top-k by q); :mod:`precompute.analysis` computes those gaps without
    running it.
    """

    label: str = ""
    short_label: str = ""
    style: Mapping[str, Any] = dataclasses.field(default_factory=dict)
    oracle: bool = False
    cost: Callable[[Config], float] = lambda cfg: float(cfg.num_grasps)
    dense: bool = False
    reference: Callable[..., Any] | None = None
    bench: bool = False
    bench_proxy: str = ""
    prior_only: str = ""


@dataclasses.dataclass(frozen=True, eq=False)
class Method:
    """One exploration method: the algorithm (pure functions and hyperparameters)
    and its :class:`Card`.

    Every function takes the method state (a pytree with leading axis B), the
    :class:`Ctx` and the static :class:`Config`; ``s`` is the current pose [B].

    - ``init(ctx, cfg) -> state``.
    - ``select(state, ctx, cfg, s, key) -> (grasp, slot, rows)``: the grasp id [B]
      to execute at pose s, the method's own index of it [B] (the slot for
      active-set methods, else the grasp id), and the rows of pose s it gathered
      (any pytree, or None) for ``recommend_updated``. ``key`` [B] is consumed.
      Only called where pose s has a valid grasp (elsewhere the result is
      ignored).
    - ``update(state, ctx, cfg, s, grasp, slot, reward, live) -> (state, new)``:
      learn from the outcome [B] bool; rows with ``live`` False must not change.
      ``new`` [B] bool: the (pose, grasp) had never been attempted.
    - ``prune`` (or None) ``(state, ctx, cfg, s, live) -> (state, removed)``: called
      after the update of a step where ``prune_due`` says so, for the pose just
      grasped: it changes pose s only (our bound counts the grasps it forgets on
      pose s's rows; :func:`legs_jax.runtime.conformance.check` refuses a
      prune that changes another pose's counts); rows with ``live`` False must
      not change; ``removed`` [B] i32 counts the grasps taken out.
    - ``prune_due`` ``(state, ctx, cfg, s, t) -> [B]`` bool: the method's pruning
      schedule, read after the update of step t (``state`` is the updated one);
      the rows where it is False are passed to ``prune`` as not live. Needed with
      ``prune`` (:func:`every_n_steps` is LEGS's).
    - ``recommend(state, ctx, cfg, s) -> [B]``: π_t(s) for the pose just updated
      (a visited pose), a grasp id.
    - ``recommend_updated`` (or None) ``(rows, ctx, cfg, s, slot, reward, live)
      -> [B]``: the same as ``recommend`` after ``update`` (without pruning),
      computed from the rows ``select`` gathered, so the step reads the state once.
    - ``recommend_init(state, ctx, cfg) -> [B, P]``: π_0 for every pose (no data).
    - ``estimates(state, ctx, cfg) -> ([B, P], [B, P])``: p̂*_s over all candidates
      and over the attempted candidates only (0 where there are none).
    - ``counts`` (or None) ``(state, ctx, cfg) -> (succ, fail, fit, ids)``, each
      [B, P, N] over the method's columns: successes and failures of the
      column's grasp, whether it enters the empirical-Bayes fit of our stopping
      bound (attempted), and its grasp id (-1 none). None: the method keeps no
      per-grasp counts and our bound is NaN (:mod:`legs_jax.core.stopping`).
    - ``candidates(state, ctx, cfg) -> [B, P, K]`` bool: the candidate set, dense
      (for tests and conformance checks; not used in the loop).
    - ``active_set`` (or None) ``(state, ctx, cfg) -> [B, P, k]`` grasp ids, -1 for
      an empty slot; ``active_width(cfg)`` is k, the number of slots a recorded
      active set has (those of a method without one are all -1).

    Besides the functions a method declares its hyperparameters: ``hparams``, a
    NamedTuple class whose fields are their names with their defaults;
    ``ranges``, the valid :class:`Range` of each; ``static``, the names that set
    shapes (read from :class:`Config`, one compile per value; the others are
    traced, one value per rollout, so a grid of them is a batch axis); and
    ``check`` (or None) ``(hp, num_grasps)``, which refuses combinations
    (``hp`` maps every name to an array over the grid points; ``num_grasps`` K is
    None where the problems are not known yet) with a
    :class:`legs_jax.errors.ConfigError`. ``learns`` is False for a constant row
    (its recommendation never changes). Everything about the method that is not
    the algorithm (how it is named and drawn, benchmarked and planned) is its
    :class:`Card`.
    """

    name: str
    description: str
    init: Callable[..., Any]
    select: Callable[..., tuple[jax.Array, jax.Array, Any]]
    update: Callable[..., tuple[Any, jax.Array]]
    recommend: Callable[..., jax.Array]
    recommend_init: Callable[..., jax.Array]
    estimates: Callable[..., tuple[jax.Array, jax.Array]]
    candidates: Callable[..., jax.Array]
    prune: Callable[..., tuple[Any, jax.Array]] | None = None
    prune_due: Callable[..., jax.Array] | None = None
    active_set: Callable[..., jax.Array] | None = None
    active_width: Callable[[Config], int] = lambda cfg: TOP_FIXED
    recommend_updated: Callable[..., jax.Array] | None = None
    counts: Callable[..., tuple] | None = None
    learns: bool = True  # False for the constant rows (Dex-Net, K100 UB)
    hparams: type = BetaPrior
    ranges: Mapping[str, Range] = dataclasses.field(
        default_factory=lambda: dict(PRIOR_RANGES)
    )
    static: tuple[str, ...] = ()
    check: Callable[[Mapping[str, np.ndarray], int | None], None] | None = check_prior
    card: Card = dataclasses.field(default_factory=lambda: Card())

    def defaults(self) -> dict[str, float | int]:
        """Every hyperparameter with its default."""
        return dict(self.hparams()._asdict())

    @property
    def traced(self) -> tuple[str, ...]:
        """The traced hyperparameters, in declaration order."""
        return tuple(n for n in self.hparams._fields if n not in self.static)

    def traced_hparams(self, **arrays: Any) -> Any:
        """The NamedTuple of traced hyperparameters the functions read as
        ``ctx.hp`` (``cfg`` holds the static ones)."""
        return _traced_type(self.hparams, self.static)(**arrays)


@functools.cache
def _traced_type(hparams: type, static: tuple[str, ...]) -> type:
    names = tuple(n for n in hparams._fields if n not in static)
    if names == tuple(hparams._fields):
        return hparams
    return collections.namedtuple(f"{hparams.__name__}Traced", names)


_FUNCTIONS = (
    "init",
    "select",
    "update",
    "recommend",
    "recommend_init",
    "estimates",
    "candidates",
)


def check_declaration(method: Any, where: str = "") -> None:
    """Refuse a malformed method declaration with a :class:`ConfigError`."""
    at = f"method {where or getattr(method, 'name', method)!r}"
    if not isinstance(method, Method):
        raise ConfigError(
            f"{at} is a {type(method).__name__}, not a "
            "legs_jax.core.methods.base.Method"
        )
    if not isinstance(method.name, str) or not method.name.isidentifier():
        raise ConfigError(f"{at}: its name must be an identifier, got {method.name!r}")
    for f in _FUNCTIONS:
        if not callable(getattr(method, f)):
            raise ConfigError(f"{at}: {f} is not callable")
    if not isinstance(method.card, Card):
        raise ConfigError(f"{at}: card must be a legs_jax.core.methods.base.Card")
    optional = ("prune", "prune_due", "active_set", "recommend_updated", "check")
    for f, v in [(f, getattr(method, f)) for f in optional] + [
        ("card.reference", method.card.reference)
    ]:
        if v is not None and not callable(v):
            raise ConfigError(f"{at}: {f} must be callable or None")
    if method.prune is not None and method.prune_due is None:
        raise ConfigError(f"{at}: prune needs prune_due, its schedule")
    if not callable(method.active_width):
        raise ConfigError(f"{at}: active_width is not callable")
    hp = method.hparams
    fields = getattr(hp, "_fields", None)
    if not isinstance(hp, type) or fields is None:
        raise ConfigError(f"{at}: hparams must be a NamedTuple class")
    missing = [n for n in fields if n not in hp._field_defaults]
    if missing:
        raise ConfigError(f"{at}: hyperparameter(s) without a default: {missing}")
    for n in list(method.ranges) + list(method.static):
        if n not in fields:
            raise ConfigError(f"{at}: {n} is not a field of {hp.__name__}")
    for n, v in hp._field_defaults.items():
        if isinstance(v, bool) or not isinstance(v, (int, float)):
            raise ConfigError(f"{at}: the default of {n} must be a number, got {v!r}")
        rng = method.ranges.get(n)
        if not math.isfinite(v) or (rng is not None and not rng.contains(v)):
            raise ConfigError(f"{at}: the default {n} = {v!r} is outside its range")
    for n in method.static:
        rng = method.ranges.get(n)
        if rng is None or not rng.integer:
            raise ConfigError(f"{at}: static {n} needs an integer range")


# ----------------------------------------------------------------------- helpers


def every_n_steps(state: Any, ctx: Ctx, cfg: Config, s: jax.Array, t) -> jax.Array:
    """LEGS's pruning schedule: every step t ≡ 0 (mod n), n the method's static
    hyperparameter ``n`` ([B] bool, the same for every row)."""
    return jnp.broadcast_to(t % cfg.n == 0, s.shape)


#: Index of the maximum along an axis, the lowest one on ties (as np.argmax):
#: :func:`legs_jax.core.sampling.argmax_first`, faster than ``jnp.argmax`` on CPU.
argmax_first = sampling.argmax_first


def best_estimates(
    value: jax.Array, candidate: jax.Array, attempted: jax.Array
) -> tuple[jax.Array, jax.Array]:
    """A method's ``estimates``: the largest ``value`` [B, P, N] over the
    candidates of each pose, and over the attempted candidates only (0 where
    there are none); ([B, P], [B, P])."""
    out = []
    for m in (candidate, candidate & attempted):
        best = jnp.max(jnp.where(m, value, -jnp.inf), axis=-1)
        out.append(jnp.where(jnp.any(m, axis=-1), best, 0.0))
    return out[0], out[1]


def argmin_id_of_max(
    score: jax.Array, mask: jax.Array, ids: jax.Array, none: int = -1
) -> jax.Array:
    """The lowest id among the maxima of ``score`` over ``mask`` (last axis).

    Used where candidates sit in slots whose order is not the grasp order, so that
    ties still go to the lowest grasp index. ``none`` where the mask is empty.
    """
    s = jnp.where(mask, score, -jnp.inf)
    m = jnp.max(s, axis=-1, keepdims=True)
    big = jnp.iinfo(jnp.int32).max
    best = jnp.min(jnp.where(mask & (s == m), ids, big), axis=-1)
    return jnp.where(jnp.any(mask, axis=-1), best, none)


def gather_rows(table: jax.Array, ot: jax.Array, s: jax.Array) -> jax.Array:
    """``table[ot[b], s[b]]`` for every b: [N, P, ...] -> [B, ...]."""
    return table[ot, s]


def gather_at(x: jax.Array, s: jax.Array, j: jax.Array | None = None) -> jax.Array:
    """Per-row gather from state: ``x[b, s[b]]`` (or ``x[b, s[b], j[b]]``)."""
    b = jnp.arange(x.shape[0])
    return x[b, s] if j is None else x[b, s, j]


def updated_row(row: jax.Array, slot: jax.Array, delta: jax.Array) -> jax.Array:
    """``row`` [B, N] with ``delta`` [B] added at column ``slot`` [B] of each row."""
    hit = jax.lax.broadcasted_iota(jnp.int32, row.shape, 1) == slot[:, None]
    return row + jnp.where(hit, delta[:, None], 0.0)


def _col(v: jax.Array, ndim: int) -> jax.Array:
    """[B] -> [B, 1, ..., 1] to broadcast against an array of ``ndim`` dims."""
    return v.reshape(v.shape + (1,) * (ndim - 1))


def posterior_prior(q: jax.Array, hp: Any) -> tuple[jax.Array, jax.Array]:
    """α, β of the prior for grasps of quality q ([B, ...]).

    α = prior_offset + s·q_c, β = prior_offset + s·(1 − q_c), q_c = clip(q).
    """
    qc = jnp.clip(q, *Q_CLIP)
    s = _col(hp.s, q.ndim)
    off = _col(hp.prior_offset, q.ndim)
    return off + s * qc, off + s * (1.0 - qc)


def beta_counts(alpha, beta, q, hp) -> tuple[jax.Array, jax.Array]:
    """Successes and failures of Beta posteriors α, β of grasps of quality q
    (the prior of :func:`posterior_prior` taken off, rounded to integers)."""
    a0, b0 = posterior_prior(q, hp)
    return (
        jnp.maximum(jnp.round(alpha - a0), 0.0),
        jnp.maximum(jnp.round(beta - b0), 0.0),
    )


def thompson_draw(
    key: jax.Array, alpha: jax.Array, beta: jax.Array, mask: jax.Array
) -> jax.Array:
    """Index of the largest exact Beta(α, β) draw over ``mask`` (ties: lowest).

    Args:
      key: [B] keys (consumed).
      alpha, beta: [B, N] shapes; masked entries may hold anything positive.
      mask: [B, N] bool, the candidates (at least one per live row).
    Returns:
      [B] i32 index into N.
    """
    a = jnp.where(mask, alpha, 1.0)
    b = jnp.where(mask, beta, 1.0)
    phi = beta_sampler.beta_rows_v2(key, a, b)
    return argmax_first(jnp.where(mask, phi, -1.0))


def prune_mask(
    alpha: jax.Array,
    beta: jax.Array,
    attempted: jax.Array,
    active: jax.Array,
    delta: jax.Array,
    gamma: jax.Array,
    ids: jax.Array | None = None,
) -> jax.Array:
    """The LEGS removal set B, batched over rows.

    B = { i active : i attempted, i ≠ i*, X_{i,u} < X*_ℓ or X_{i,u} < γ }, with
    X_{i,ℓ} = PPF(Beta(α_i, β_i), δ), X_{i,u} = PPF(Beta(α_i, β_i), 1 − δ),
    X*_ℓ = max over active arms of X_{i,ℓ} and i* = argmax posterior mean over the
    active arms (ties: lowest id).

    Args:
      alpha, beta: [B, N] Beta parameters (prior offset included).
      attempted, active: [B, N] bool.
      delta, gamma: [B].
      ids: [B, N] grasp ids for the tie-break of i* (default: the index in N).
    Returns:
      [B, N] bool, a subset of ``active``.
    """
    if ids is None:
        ids = jax.lax.broadcasted_iota(jnp.int32, alpha.shape, 1)
    a = jnp.where(active, alpha, 1.0)
    b = jnp.where(active, beta, 1.0)
    d = delta[:, None]
    n = a.shape[1]
    # One call for both bounds (one copy of the quantile solver in the program).
    qs = jnp.concatenate(
        [jnp.broadcast_to(d, a.shape), jnp.broadcast_to(1.0 - d, a.shape)], 1
    )
    both = sampling.beta_ppf(qs, jnp.concatenate([a, a], 1), jnp.concatenate([b, b], 1))
    lower, upper = both[:, :n], both[:, n:]  # X_{i,ℓ}, X_{i,u}
    x_star_lower = jnp.max(jnp.where(active, lower, -jnp.inf), axis=1, keepdims=True)
    i_star = argmin_id_of_max(a / (a + b), active, ids)
    bad = (upper < x_star_lower) | (upper < gamma[:, None])
    return active & attempted & (ids != i_star[:, None]) & bad
