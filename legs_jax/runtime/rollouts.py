"""Running the pure rollout loop on devices: :func:`run`, the host half of the
engine.

The core (:mod:`legs_jax.core.engine`) defines one rollout step and the whole
loop (:func:`~legs_jax.core.engine.simulate`) as pure functions and never jits.
This module is where they are made into programs and run: validation of the
request, the layout of rollouts into rows and mini-batches, ``jax.jit`` and, over
several devices, ``shard_map``; the programs kept on disk
(:mod:`legs_jax.runtime.programs`), the progress bar, and the collection of the
results into NumPy arrays (:class:`RunResult`). Results never depend on the
devices, the batch size or the chunking.
"""

from __future__ import annotations

import functools
import inspect
import math
import numbers
from collections import Counter
from collections.abc import Callable, Mapping, Sequence
from typing import Any, NamedTuple

import jax
import numpy as np

from legs_jax.core import keys as keys_mod
from legs_jax.core import methods as methods_mod
from legs_jax.core.engine import dirichlet_checks, make_tables, simulate
from legs_jax.core.methods.base import Config, Method, Tables
from legs_jax.core.problem import ProblemBatch
from legs_jax.errors import ConfigError
from legs_jax.runtime import programs

__all__ = [
    "RunResult",
    "compile_seconds",
    "compiled",
    "compiled_checks",
    "mini_batch_rows",
    "run",
    "table_rows",
    "trace_counts",
]

_TRACES: Counter = Counter()


def trace_counts() -> dict[tuple, int]:
    """How many times the engine traced each (method name, static configuration)."""
    return dict(_TRACES)


class RunResult(NamedTuple):
    """Results of :func:`run`, NumPy arrays with leading axes [G, O, T, R]."""

    final_gap: np.ndarray  # [G, O, T, R] f32 gap Δ_H
    final_performance: np.ndarray  # [G, O, T, R] f32 Σ_s λ_s p[s, π_H(s)]
    successes: np.ndarray  # [G, O, T, R] i64 successful grasps
    distinct_grasps: np.ndarray  # [G, O, T, R] i64 distinct (pose, grasp) tried
    replacements: np.ndarray  # [G, O, T, R] i64 grasps removed by pruning
    curve_steps: np.ndarray  # [C1] 0, record_every, ..., H
    gap_curve: np.ndarray  # [G, O, T, R, C1] f32
    check_steps: np.ndarray  # [C2] check_every, 2·check_every, ... <= H
    check_p_lower: np.ndarray  # [G, O, T, R, C2] f32 p̂_ℓ (p̂* over all candidates)
    check_p_lower_attempted: np.ndarray  # [G, O, T, R, C2] f32 (attempted only)
    check_true_performance: np.ndarray  # [G, O, T, R, C2] f32
    active_set: np.ndarray | None  # [G, O, T, R, C2, P, k] i32 grasp ids, -1 empty
    # [G, O, T, R, C2] f32 our bound (legs_jax.core.stopping); NaN for a method
    # without per-grasp counts
    check_p_lower_eb: np.ndarray | None = None
    # [G, O, T, R, C2] f32 mean attempts after a failed attempt at a landing until
    # the next success, the recommendations frozen (verified stopping's cost)
    check_after_failure: np.ndarray | None = None


def _is_int(x: Any) -> bool:
    return isinstance(x, numbers.Integral) and not isinstance(x, bool)


def table_rows(pairs: int) -> int:
    """Rows of the tables for ``pairs`` (object, trial) pairs: the next power of
    two (fewer distinct shapes to compile)."""
    return 1 << max(0, (pairs - 1).bit_length())


def mini_batch_rows(
    method: Method,
    cfg: Config,
    rows: int,
    n_dev: int,
    platform: str,
    batch_size: int | None = None,
) -> int:
    """Rollouts per device of each mini-batch of a run of ``rows`` rollouts
    (``batch_size``: the user's largest, else the method's default)."""
    largest = batch_size or _default_batch_size(method, platform, cfg)
    quantum = 1 if batch_size or largest <= 64 else 16
    return _batch_rows(-(-rows // n_dev), largest, quantum)


def _default_batch_size(method: Method, platform: str, cfg: Config) -> int:
    # On CPU a step pays a fixed cost per operation (a few microseconds each,
    # whatever the batch) besides its O(B K) work: at K = 2000, 50 rollouts a
    # device ran 1.07-1.42x faster than 13 (real chunks of 100 rollouts on two
    # devices, BENCHMARKS.md; least for the objects with the most poses, whose
    # rollout state then no longer fits in cache).
    if platform == "cpu":
        return 64 if method.card.dense else 512
    return 2048 if method.card.dense else 16384


def _batch_rows(rows_per_device: int, largest: int, quantum: int) -> int:
    """Rollouts per device per mini-batch: the work split evenly into as few
    mini-batches of at most ``largest`` as it takes, each rounded up to a multiple
    of ``quantum`` (fewer distinct shapes to compile). A chunk of 100 rollouts on
    two devices at 16 a batch runs as 4 x 13 per device (4 % padding) rather than
    4 x 16 (28 %)."""
    n_batches = -(-rows_per_device // largest)
    per = -(-rows_per_device // n_batches)  # <= largest, so no clamp is needed
    return -(-per // quantum) * quantum


def _simulate_options() -> dict[str, Any]:
    """The keyword options of :func:`simulate` and their defaults."""
    params = inspect.signature(simulate).parameters.values()
    return {
        p.name: p.default
        for p in params
        if p.kind is p.KEYWORD_ONLY and p.default is not p.empty
    }


def compiled(
    method: Method | str,
    cfg: Config,
    horizon: int,
    *,
    grid: bool = False,
    devices: tuple | None = None,
    raw_keys: bool = False,
    **options: Any,
) -> Callable:
    """The jitted :func:`simulate` for one static configuration (cached).

    ``method`` is a :class:`Method` or a name (:func:`legs_jax.core.methods.resolve`);
    ``options`` are :func:`simulate`'s keyword options (``record_every``,
    ``check_every``, ...; the others keep their defaults). Returns
    ``f(tables, ot, rollout_keys, hp) -> dict``. With ``grid=True`` the function is
    ``jit(vmap(simulate))`` over a leading axis G of ``rollout_keys`` [G, B] and of
    every ``hp`` leaf [G, B]. With several ``devices`` the batch axis is sharded
    over them (``shard_map``); the tables are replicated. With ``raw_keys`` the
    keys come as their raw uint32 words [..., 2]
    (:func:`legs_jax.core.keys.rollout_key_data`).
    """
    defaults = _simulate_options()
    unknown = sorted(set(options) - set(defaults))
    if unknown:
        raise TypeError(f"compiled() got unknown simulate options {unknown}")
    opts = tuple(sorted({**defaults, **options}.items()))
    return _compiled(
        methods_mod.resolve(method), cfg, horizon, grid, devices, raw_keys, opts
    )


@functools.lru_cache(maxsize=64)
def _compiled(m, cfg, horizon, grid, devices, raw_keys, opts) -> Callable:
    fn = _counted(
        functools.partial(simulate, method=m, cfg=cfg, horizon=horizon, **dict(opts)),
        (m.name, cfg, horizon, dict(opts)["record_every"], dict(opts)["check_every"]),
    )
    if grid:
        plain = fn
        fn = lambda tables, ot, ks, hp: jax.vmap(  # noqa: E731
            lambda k, h: plain(tables, ot, k, h)
        )(ks, hp)
    if raw_keys:
        fn = _wrapping_keys(fn, 2)
    xla = programs.cpu_vector_options(devices)
    return programs.describe(
        _jit_rows(fn, devices, (None, "b", "b", "b"), grid, xla),
        programs.method_fingerprint(m),
        "simulate",
        cfg, horizon, opts, grid, raw_keys,
        programs.devices_fingerprint(devices),
        compiler_options=xla,
    )  # fmt: skip


@functools.lru_cache(maxsize=8)
def compiled_checks(devices: tuple | None = None, raw_keys: bool = False) -> Callable:
    """The jitted :func:`dirichlet_checks` (one program for every method)."""
    fn = _wrapping_keys(dirichlet_checks, 0) if raw_keys else dirichlet_checks
    return programs.describe(
        _jit_rows(fn, devices, ("b", "b"), False),
        "dirichlet_checks",
        raw_keys,
        programs.devices_fingerprint(devices),
    )


def _counted(fn: Callable, key: tuple) -> Callable:
    """``fn(tables, ot, ...)`` that counts, each time it is traced, under ``key``
    and the rows of ``ot`` it is traced for (:func:`trace_counts`)."""

    def counting(tables, ot, *args):
        _TRACES[(*key, ot.shape[0])] += 1
        return fn(tables, ot, *args)

    return counting


def _wrapping_keys(fn: Callable, at: int) -> Callable:
    """``fn`` taking raw key words at argument ``at`` instead of typed keys."""

    def wrapped(*args):
        args = list(args)
        args[at] = jax.random.wrap_key_data(args[at])
        return fn(*args)

    return wrapped


def compile_seconds() -> float:
    """Seconds this process has spent tracing, lowering and compiling (or loading
    from the caches) the programs of :func:`run`."""
    return programs.compile_seconds()


def _jit_rows(
    fn: Callable, devices, in_axes, grid: bool, compiler_options=None
) -> Callable:
    """jit ``fn`` (with XLA's ``compiler_options``); with several devices, shard
    the rows (axis "b") over them."""
    jit = functools.partial(jax.jit, compiler_options=compiler_options or None)
    if devices is None or len(devices) == 1:
        return jit(fn)
    from jax.sharding import Mesh
    from jax.sharding import PartitionSpec as Pspec

    mesh = Mesh(np.array(devices), ("b",))
    row = Pspec(None, "b") if grid else Pspec("b")
    specs = tuple(Pspec() if a is None else row for a in in_axes)
    sharded = jax.shard_map(
        fn, mesh=mesh, in_specs=specs, out_specs=row, check_vma=False
    )
    return jit(sharded)


def _check_int(name: str, value: Any, minimum: int) -> int:
    if not _is_int(value) or value < minimum:
        raise ConfigError(f"{name} must be an integer >= {minimum}, got {value!r}")
    return int(value)


def run(
    batch: ProblemBatch,
    method: Method | str,
    *,
    object_ids: Sequence[int],
    trials: Sequence[int] | None = None,
    num_rollouts: int = 10,
    horizon: int = 3000,
    hparams: Mapping[str, float | Sequence[float]] | None = None,
    seed: int = 0,
    rollout_offset: int = 0,
    record_every: int = 10,
    check_every: int | None = 100,
    stop_variant_attempted: bool = True,
    record_active_set: bool = False,
    eb_leave_out_rec: bool = True,
    eb_fit_start: str = "pooled",
    eb_replicates: int = 0,
    our_bound: bool = True,
    devices: Sequence[jax.Device] | None = None,
    batch_size: int | None = None,
    progress: bool | Callable[[int], Any] | None = None,
    shape_of: tuple[int, int] | None = None,
) -> RunResult:
    """Run ``method`` on every object and trial of ``batch``, R rollouts each.

    Args:
      batch: the problems (:func:`legs_jax.core.problem.stack`), axes [O, T, P, K].
      method: a :class:`legs_jax.core.methods.base.Method`, a registered name
        (:func:`legs_jax.core.methods.names`) or ``module.path:ATTRIBUTE``.
      object_ids: [O] stable integer id of each object (seeds its rollouts).
      trials: indices into the batch's T axis (default: all).
      num_rollouts: R.
      horizon: H, steps per rollout.
      hparams: overrides of the method's own defaults (``method.hparams``); a
        value may be a sequence (all sequences of one length G: a zipped grid, not
        a product). Grid points share the random numbers of a rollout.
      seed: non-negative integer.
      rollout_offset: rollout r uses key index ``rollout_offset + r`` (to split a
        run into pieces that join into the same results).
      record_every: gap recorded every this many steps (and at H).
      check_every: Dirichlet check every this many steps; None or 0: no checks.
      stop_variant_attempted: also compute the bound over attempted grasps only
        (else that field is NaN).
      record_active_set: return each pose's active set at each check.
      eb_leave_out_rec: our bound's G_s fitted without the recommended grasp's
        own outcomes (:func:`simulate`; the default).
      eb_fit_start: where our bound's fit of G_s starts: ``"pooled"`` (the
        default) or ``"uniform"`` (the earlier bound, kept to compare).
      eb_replicates: 0: our bound's G_s is the plug-in fit; R > 0: averaged over
        R Bayesian-bootstrap fits (:func:`simulate`).
      our_bound: compute our bound at the checks (the default); False: the
        paper's bound only (``check_p_lower_eb`` is NaN), which saves its fit.
      devices: devices to shard the rollouts over (default: all local devices).
        On CPU, JAX shows one device unless ``XLA_FLAGS`` holds
        ``--xla_force_host_platform_device_count=<cores>`` before JAX starts;
        with it every core runs its own share of the rollouts.
      batch_size: rollouts per device per mini-batch (default: by method and
        platform). Results do not depend on it.
      progress: True for a progress bar over rollouts, False for none, None for a
        bar when the job is large, or a callable given the number of rollouts done
        after each mini-batch.
      shape_of: (object-trial pairs, rollouts) of a larger run whose program
        shapes this run takes (its tables and mini-batches padded to them), so
        that the runs of a sweep share compiled programs; results do not
        depend on it.
    Returns:
      a :class:`RunResult`.
    Raises:
      ConfigError: invalid input, before any computation.
    """
    # ---------------------------------------------------------------- validation
    if not isinstance(batch, ProblemBatch):
        raise ConfigError(
            f"batch must be a legs_jax.core.problem.ProblemBatch (see stack()), "
            f"got {type(batch).__name__}"
        )
    O, T_all, P, K = batch.shape
    m = methods_mod.resolve(method)
    G, hp = methods_mod.parse_grid(m, hparams, K)
    obj = np.asarray(object_ids).reshape(-1).tolist() if object_ids is not None else []
    if len(obj) != O:
        raise ConfigError(
            f"object_ids has {len(obj)} entries, the batch has {O} objects"
        )
    for x in obj:
        if not _is_int(x) or not 0 <= x < 2**31:
            raise ConfigError(f"object ids must be integers in [0, 2**31), got {x!r}")
    trials = (
        list(range(T_all))
        if trials is None
        else np.asarray(trials).reshape(-1).tolist()
    )
    if not trials:
        raise ConfigError("trials is empty")
    for x in trials:
        if not _is_int(x) or not 0 <= x < T_all:
            raise ConfigError(f"trial {x!r} out of range: the batch has {T_all} trials")
    R = _check_int("num_rollouts", num_rollouts, 1)
    H = _check_int("horizon", horizon, 1)
    seed = _check_int("seed", seed, 0)
    rollout_offset = _check_int("rollout_offset", rollout_offset, 0)
    record_every = _check_int("record_every", record_every, 1)
    if check_every is None or (_is_int(check_every) and check_every == 0):
        check_every = None
    else:
        check_every = _check_int("check_every", check_every, 1)
        if check_every > H:
            check_every = None
    if devices is None:
        devices = jax.local_devices()
    devices = tuple(devices)
    if not devices:
        raise ConfigError("devices is empty")
    if batch_size is not None:
        batch_size = _check_int("batch_size", batch_size, 1)
    width = 0  # active-set slots (the method's, the same at every grid point)
    if record_active_set:
        widths = sorted(
            {
                int(m.active_width(Config(P, K, **{n: hp[n][g] for n in m.static})))
                for g in range(G)
            }
        )
        if len(widths) > 1:
            raise ConfigError(
                f"record_active_set needs a single active-set width, not a grid "
                f"over it ({', '.join(map(str, widths))} slots)"
            )
        width = widths[0]

    # ---------------------------------------------------------------- layout
    T = len(trials)
    N = O * T
    rows = G * O * T * R
    like_pairs, like_rows = shape_of if shape_of is not None else (N, rows)
    n_pad = table_rows(max(N, like_pairs))
    tables_np = make_tables(batch, trials, pad_to=n_pad)
    g_i, o_i, t_i, r_i = (a.reshape(-1) for a in np.indices((G, O, T, R)))
    ot_rows = (o_i * T + t_i).astype(np.int32)
    obj_rows = np.asarray(obj, np.int64)[o_i]
    trial_rows = np.asarray(trials, np.int64)[t_i]
    key_rows = keys_mod.rollout_key_data(
        seed, obj_rows, trial_rows, rollout_offset + r_i
    )

    curve_steps = np.unique(np.append(np.arange(0, H + 1, record_every), H))
    check_steps = (
        np.arange(check_every, H + 1, check_every) if check_every else np.zeros(0, int)
    )
    C2 = check_steps.size
    L = math.gcd(record_every, check_every) if check_every else record_every
    gap_steps = np.arange(0, H // L + 1) * L
    # column of each curve step in the engine's gaps (H itself is final_gap)
    gap_cols = np.searchsorted(gap_steps, curve_steps)

    n_dev = len(devices)
    platform = devices[0].platform
    # Group grid points by the method's static hyperparameters (one compile each).
    groups: dict[tuple[int, ...], list[int]] = {}
    for g in range(G):
        groups.setdefault(tuple(int(hp[n][g]) for n in m.static), []).append(g)

    if n_dev == 1:
        put_tables = jax.device_put(Tables(*tables_np), devices[0])
    else:
        from jax.sharding import Mesh, NamedSharding
        from jax.sharding import PartitionSpec as Pspec

        mesh = Mesh(np.array(devices), ("b",))
        put_tables = jax.device_put(Tables(*tables_np), NamedSharding(mesh, Pspec()))
        row_sharding = NamedSharding(mesh, Pspec("b"))

    results: dict[str, np.ndarray] = {}

    def store(name: str, idx: np.ndarray, value: np.ndarray) -> None:
        if name not in results:
            results[name] = np.zeros((rows,) + value.shape[1:], value.dtype)
        results[name][idx] = value

    bar = None
    callback = progress if callable(progress) else None
    show = progress is True or (progress is None and rows * H >= 2_000_000)
    if show and callback is None:
        from tqdm.auto import tqdm

        bar = tqdm(total=rows, desc=m.name, unit="rollout", leave=False)
    done = 0
    for statics, gs in groups.items():
        static = dict(zip(m.static, statics, strict=True))
        cfg = Config(num_poses=P, num_grasps=K, **static)
        sel = np.flatnonzero(np.isin(g_i, gs))
        like = max(sel.size, like_rows * len(gs) // G)
        per_dev = mini_batch_rows(m, cfg, like, n_dev, platform, batch_size)
        Bc = per_dev * n_dev
        fn = compiled(
            m, cfg, H, devices=devices, raw_keys=True, dirichlet=False,
            record_every=record_every, check_every=check_every,
            attempted_variant=bool(stop_variant_attempted),
            record_active_set=bool(record_active_set),
            eb_leave_out_rec=bool(eb_leave_out_rec),
            eb_fit_start=str(eb_fit_start), eb_replicates=int(eb_replicates),
            our_bound=bool(our_bound),
        )  # fmt: skip
        checks_fn = compiled_checks(devices, True) if check_every else None
        pending = []
        for start in range(0, sel.size, Bc):
            idx = sel[start : start + Bc]
            pad = Bc - idx.size
            full = np.concatenate([idx, np.full(pad, idx[0])]) if pad else idx
            # NumPy until the device: an eager jax.numpy operation would compile
            # a program of its own for each new shape.
            hp_b = m.traced_hparams(
                **{
                    name: np.asarray(hp[name][g_i[full]], np.float32)
                    for name in m.traced
                }
            )
            args = (ot_rows[full], key_rows[full], hp_b)
            if n_dev > 1:
                args = jax.device_put(args, row_sharding)
            else:
                args = jax.device_put(args, devices[0])
            out = programs.call(fn, put_tables, *args)
            if checks_fn is not None:
                out = programs.call(checks_fn, args[1], out)
            pending.append((idx, out))
            if len(pending) > 1:
                done += _collect(pending.pop(0), store, gap_cols, curve_steps, H)
                _report(bar, callback, done)
        while pending:
            done += _collect(pending.pop(0), store, gap_cols, curve_steps, H)
            _report(bar, callback, done)
    if bar is not None:
        bar.close()

    shape = (G, O, T, R)

    def get(name, dtype=None, extra=(), missing=0):
        if name not in results:
            return np.full(shape + extra, missing, dtype or np.float32)
        a = results[name]
        return a.reshape(shape + a.shape[1:]).astype(dtype or a.dtype, copy=False)

    return RunResult(
        final_gap=get("final_gap", np.float32),
        final_performance=get("final_performance", np.float32),
        successes=get("successes", np.int64),
        distinct_grasps=get("distinct_grasps", np.int64),
        replacements=get("replacements", np.int64),
        curve_steps=curve_steps,
        gap_curve=get("gap_curve", np.float32),
        check_steps=check_steps,
        check_p_lower=get("check_p_lower", np.float32, (C2,)),
        check_p_lower_attempted=get("check_p_lower_attempted", np.float32, (C2,)),
        check_true_performance=get("check_true_performance", np.float32, (C2,)),
        active_set=(
            get("active_set", np.int32, (C2, P, width)) if record_active_set else None
        ),
        check_p_lower_eb=get("check_p_lower_eb", np.float32, (C2,), np.nan),
        check_after_failure=get("check_after_failure", np.float32, (C2,), np.nan),
    )


def _report(bar, callback, done: int) -> None:
    if bar is not None:
        bar.n = done
        bar.refresh()
    if callback is not None:
        callback(done)


def _collect(item, store, gap_cols, curve_steps, H) -> int:
    idx, out = item
    n = idx.size
    out = jax.device_get(out)
    gaps = np.asarray(out.pop("gaps"))[:n]
    final = np.asarray(out["final_gap"])[:n]
    curve = np.empty((n, curve_steps.size), np.float32)
    inner = curve_steps < H
    curve[:, inner] = gaps[:, gap_cols[inner]]
    curve[:, ~inner] = final[:, None]
    store("gap_curve", idx, curve)
    for name, value in out.items():
        store(name, idx, np.asarray(value)[:n])
    return n
