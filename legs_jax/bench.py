"""Speed benchmark: exact Beta sampling and rollout throughput, side by side.

    python -m legs_jax.bench            # the full table (several minutes)
    python -m legs_jax.bench --quick    # a smaller, faster run
    python -m legs_jax.bench --json     # one JSON object on stdout instead

Everything is measured in one run on this machine, after a warm-up, as the median
of several repeats; compile time is reported apart.

- Exact Beta samples per second: this project's sampler
  (:func:`legs_jax.core.sampling.beta_rows`), ``jax.random.beta`` and NumPy's
  ``Generator.beta``, on the same posterior-like shapes.
- The engine's sampler against its successor
  (:func:`legs_jax.core.beta_sampler.beta_rows_v2`) and NumPy, timed in turns on
  one device, per CPU second (per core) and per wall second, on the shapes of a
  K = 2000 Thompson step; and one Thompson draw step (draw and argmax) with each.
- Rollout steps per second of BORGES (K=2000), LEGS (k=100) and TQL: the JAX engine
  (:func:`legs_jax.runtime.run`) against the NumPy reference implementation
  (:mod:`legs_jax.core.reference`) of the same method with the same settings, and the
  ratio.
- The projected wall time of ``python -m legs_jax.sweep --all`` from those rates:
  in a full run with the problem files present, every method is timed again at
  each pose count the sweep pads its chunks to (8, 16, 32) and the sweep's own
  chunks are charged at those rates, the chunks it copies from an earlier
  experiment free (:func:`projection_by_chunk`); otherwise every object at the
  table's pose count (:func:`projection`).
- The raw figures behind the physical limits: random words per second, words per
  exact Beta draw, memory bandwidth.

Like the sweep, the benchmark gives the JAX engine one host device per core (an
``--xla_force_host_platform_device_count`` already in ``XLA_FLAGS`` wins).
"""

from __future__ import annotations

import argparse
import json
import math
import os
import platform
import statistics
import sys
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

_PROG = "python -m legs_jax.bench"
_DESCRIPTION = (
    "Measure exact Beta samples/s (legs_jax vs jax.random.beta vs NumPy), "
    "rollout steps/s of the JAX engine vs the NumPy reference, and project "
    "the wall time of the full sweep (python -m legs_jax.sweep --all)."
)


def _all_methods() -> tuple[str, ...]:
    """Every registered method (legs_jax.core.methods), in registry order (imported
    late: JAX must start after the device flags are set)."""
    from legs_jax.core import methods

    return methods.names()


def table_methods() -> tuple[str, ...]:
    """Methods of the table (their declaration's ``bench``); the others get a rate
    in the full run (for the projection) or borrow the rate of their
    ``bench_proxy``, a method with the same per-step work."""
    from legs_jax.core import methods

    return tuple(m for m in methods.names() if methods.get(m).card.bench)


def proxy() -> dict[str, str]:
    """Method -> the table's method whose rate stands in for it (``bench_proxy``)."""
    from legs_jax.core import methods

    out = {}
    for m in methods.names():
        if methods.get(m).card.bench_proxy:
            out[m] = methods.get(m).card.bench_proxy
    return out


# Dirichlet checks every this many steps for the methods the main sweep checks
# (experiments.main.CHECK_METHODS); the others run without, as in the sweep.
CHECK_EVERY = 100
# The object sets (used when the mesh catalogue is not installed).
SET_SIZES = {"dexnet_adv": 13, "egad_eval": 49}
MAX_HOST_DEVICES = 8


@dataclass(frozen=True)
class Settings:
    quick: bool
    repeats: int
    min_seconds: float  # shortest timed stretch of one sampler repeat
    sampler_rows: int
    sampler_arms: int
    poses: int
    grasps: int
    trials: int
    horizon: int
    rollouts_dense: int  # rollouts of a JAX run of a dense method
    rollouts_sparse: int  # of the other methods
    reference_horizon: int
    reference_seconds: float  # shortest timed stretch of one reference repeat
    methods: tuple[str, ...]
    numpy_all_cores: bool


def _with_table(methods: Sequence[str]) -> tuple[str, ...]:
    """The table's methods always run (the projection borrows their rates)."""
    return tuple(m for m in _all_methods() if m in methods or m in table_methods())


# Sizes of a run: (--quick, full).
_SIZES = dict(
    repeats=(2, 3),
    min_seconds=(0.2, 1.0),
    sampler_rows=(16, 64),
    sampler_arms=(2000, 2000),
    poses=(4, 8),
    grasps=(2000, 2000),
    trials=(2, 8),
    horizon=(100, 1000),
    rollouts_dense=(32, 128),
    rollouts_sparse=(256, 2048),
    reference_horizon=(100, 1000),
    reference_seconds=(0.3, 3.0),
)


def settings(quick: bool, methods: Sequence[str] | None) -> Settings:
    """A quick run times the table's methods by default, a full run all of them;
    the NumPy reference also runs on every core in a full run."""
    default = table_methods() if quick else _all_methods()
    return Settings(
        quick=quick,
        **{k: v[0 if quick else 1] for k, v in _SIZES.items()},
        methods=_with_table(methods or default),
        numpy_all_cores=not quick,
    )


# ----------------------------------------------------------------------- helpers


def _set_host_devices() -> None:
    """One XLA host device per core (at most 8), before JAX starts."""
    flags = os.environ.get("XLA_FLAGS", "")
    n = min(os.cpu_count() or 1, MAX_HOST_DEVICES)
    if n >= 2 and "xla_force_host_platform_device_count" not in flags:
        os.environ["XLA_FLAGS"] = (
            flags + f" --xla_force_host_platform_device_count={n}"
        ).strip()


def _say(msg: str, quiet: bool) -> None:
    if not quiet:
        print(msg, file=sys.stderr, flush=True)


def _timed_rate(
    fn: Callable[[], Any], work: float, repeats: int, min_seconds: float
) -> float:
    """Median over ``repeats`` of work per second; each repeat calls ``fn`` until
    at least ``min_seconds`` have passed."""
    return statistics.median(
        _timed_calls(fn, work, min_seconds)[0] for _ in range(repeats)
    )


def _timed_calls(
    fn: Callable[[], Any], work: float, min_seconds: float
) -> tuple[float, float]:
    """(work per wall second, work per CPU second of this process) of calling
    ``fn`` until at least ``min_seconds`` have passed."""
    calls = 0
    start, cpu0 = time.perf_counter(), time.process_time()
    while True:
        fn()
        calls += 1
        elapsed = time.perf_counter() - start
        if elapsed >= min_seconds:
            break
    used = max(time.process_time() - cpu0, 1e-9)
    return work * calls / elapsed, work * calls / used


def _cpu_model() -> str:
    try:
        with open("/proc/cpuinfo") as f:
            for line in f:
                if line.startswith("model name"):
                    return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or platform.machine()


def _load() -> list[float] | None:
    try:
        return [round(x, 2) for x in os.getloadavg()]
    except OSError:
        return None


# ----------------------------------------------------------------------- sampler


def _posterior_shapes(rows: int, arms: int) -> tuple[np.ndarray, np.ndarray]:
    """Thompson-like Beta shapes: prior 1 + q, 1 + (1 - q), 30 % of arms tried."""
    rng = np.random.default_rng(0)
    q = rng.uniform(0.01, 0.99, (rows, arms))
    tried = rng.uniform(size=(rows, arms)) < 0.3
    wins = np.where(tried, rng.poisson(2.0, (rows, arms)), 0)
    losses = np.where(tried, rng.poisson(20.0, (rows, arms)), 0)
    a = (1.0 + q + wins).astype(np.float32)
    b = (1.0 + (1.0 - q) + losses).astype(np.float32)
    return a, b


def _thompson_shapes(rows: int, arms: int) -> tuple[np.ndarray, np.ndarray]:
    """Shapes of a K = ``arms`` Thompson step: 70 % of grasps at the prior
    α = 1 + q, β = 1 + (1 − q), 25 % tried a few to tens of times, 5 % with
    hundreds of counts (successes at the grasp's quality q)."""
    rng = np.random.default_rng(1)
    q = rng.uniform(0.01, 0.99, (rows, arms))
    kind = rng.uniform(size=(rows, arms))
    tries = np.where(
        kind < 0.70,
        0,
        np.where(
            kind < 0.95,
            rng.integers(1, 40, (rows, arms)),
            rng.integers(100, 1000, (rows, arms)),
        ),
    )
    wins = rng.binomial(tries, q)
    a = (1.0 + q + wins).astype(np.float32)
    b = (1.0 + (1.0 - q) + tries - wins).astype(np.float32)
    return a, b


def _interleaved_rates(
    fns: dict[str, Callable[[], Any]], work: float, repeats: int, min_seconds: float
) -> dict[str, dict[str, float]]:
    """Work per second of each of ``fns``, timed in turns (repeat r of every one
    before repeat r + 1 of any), so that a change of machine load hits them
    alike. For each: the median over repeats of work per wall second and of work
    per CPU second of this process (all its threads: a per-core rate however
    many cores a program used)."""
    wall: dict[str, list[float]] = {k: [] for k in fns}
    cpu: dict[str, list[float]] = {k: [] for k in fns}
    for fn in fns.values():
        fn()  # warm-up (compiled already)
    for _ in range(repeats):
        for name, fn in fns.items():
            per_s, per_cpu_s = _timed_calls(fn, work, min_seconds)
            wall[name].append(per_s)
            cpu[name].append(per_cpu_s)
    return {
        k: {"per_s": statistics.median(wall[k]), "per_cpu_s": statistics.median(cpu[k])}
        for k in fns
    }


def _sharded(fn, devices):
    """``fn`` over rows split across ``devices`` (each device its own program)."""
    import jax
    from jax.sharding import Mesh, NamedSharding
    from jax.sharding import PartitionSpec as Pspec

    if len(devices) == 1:
        jitted = jax.jit(fn)

        def put(*xs):
            return jax.device_put(xs, devices[0])

        return jitted, put
    mesh = Mesh(np.array(devices), ("b",))
    row = Pspec("b")
    jitted = jax.jit(
        jax.shard_map(fn, mesh=mesh, in_specs=row, out_specs=row, check_vma=False)
    )

    def put(*xs):
        return jax.device_put(xs, NamedSharding(mesh, row))

    return jitted, put


def bench_sampler(cfg: Settings, quiet: bool) -> dict[str, Any]:
    import jax
    import jax.numpy as jnp

    from legs_jax.core import sampling

    rows, arms = cfg.sampler_rows, cfg.sampler_arms
    a, b = _posterior_shapes(rows, arms)
    keys = jax.random.split(jax.random.key(0), rows)
    devices = jax.local_devices()
    n = rows * arms
    out: dict[str, Any] = {"shape": [rows, arms], "devices": len(devices)}

    def jax_rate(name: str, fn, devs) -> float:
        jitted, put = _sharded(fn, devs)
        args = put(keys, jnp.asarray(a), jnp.asarray(b))
        start = time.perf_counter()
        jax.block_until_ready(jitted(*args))
        first = time.perf_counter() - start
        rate = _timed_rate(
            lambda: jax.block_until_ready(jitted(*args)),
            n,
            cfg.repeats,
            cfg.min_seconds,
        )
        out[f"{name}_compile_s"] = round(max(first - n / rate, 0.0), 2)
        return rate

    _say("sampler: legs_jax.core.sampling.beta_rows", quiet)
    # XLA already spreads one device's large fusions over the cores, so rows split
    # over devices are not always faster: both are measured, the better one is the
    # machine's figure.
    one = jax_rate("sampler_one_device", sampling.beta_rows, devices[:1])
    out["sampler_samples_per_s_one_device"] = one
    out["sampler_samples_per_s"] = one
    out["sampler_compile_s"] = out["sampler_one_device_compile_s"]
    if len(devices) > 1:
        split = jax_rate("sampler_all_devices", sampling.beta_rows, devices)
        out["sampler_samples_per_s_all_devices"] = split
        out["sampler_samples_per_s"] = max(one, split)

    _say("sampler: jax.random.beta", quiet)

    def jax_beta(k, a_, b_):
        return jax.vmap(lambda kk, aa, bb: jax.random.beta(kk, aa, bb))(k, a_, b_)

    out["jax_random_beta_samples_per_s"] = jax_rate(
        "jax_random_beta", jax_beta, devices
    )

    _say("sampler: numpy Generator.beta", quiet)
    a64, b64 = a.astype(np.float64), b.astype(np.float64)
    gen = np.random.default_rng(0)
    out["numpy_beta_samples_per_s"] = _timed_rate(
        lambda: gen.beta(a64, b64), n, cfg.repeats, cfg.min_seconds
    )

    out.update(bench_sampler_versions(cfg, quiet))

    # Random words: the Threefry-2x32 of the sampler, on its own.
    def words(k, ctr):
        w0, w1 = sampling.threefry2x32(k[:, 0:1], k[:, 1:2], ctr, jnp.uint32(7))
        return w0 ^ w1

    ctr = jnp.arange(arms * 8, dtype=jnp.uint32)[None]
    kd = jax.random.key_data(keys)
    fn = jax.jit(words)
    jax.block_until_ready(fn(kd, ctr))
    out["random_words_per_s_one_device"] = _timed_rate(
        lambda: jax.block_until_ready(fn(kd, ctr)),
        2 * rows * arms * 8,
        cfg.repeats,
        cfg.min_seconds,
    )
    # Random words per Beta draw at these shapes: try 0 of both gammas costs 4
    # words; an element with a rejected gamma is redrawn in a retry round (try 0
    # again and 3 more tries of each gamma, 2 words a try).
    k0, k1 = sampling.key_words(keys)
    aj, bj = jnp.asarray(a), jnp.asarray(b)
    da, ca = sampling._shape_dc(aj)
    db, cb = sampling._shape_dc(bj)
    i = jnp.arange(arms, dtype=jnp.uint32)[None]
    ga, gb = sampling._beta_first_tries(k0, k1, i, da, ca, db, cb)
    pending = float(jnp.mean((ga < 0) | (gb < 0)))
    out["beta_retry_fraction"] = pending
    out["random_words_per_beta"] = 4 + pending * (4 + 2 * 3 * 2)
    return out


def bench_sampler_versions(cfg: Settings, quiet: bool) -> dict[str, Any]:
    """The engine's exact Beta sampler against its successor
    (:func:`legs_jax.core.beta_sampler.beta_rows_v2`) and NumPy's
    ``Generator.beta``, on the shapes of a K = 2000 Thompson step
    (:func:`_thompson_shapes`), on one JAX device, timed in turns in this run;
    and one Thompson draw step (the [B, 2000] draw and its argmax, as BORGES K=2000
    takes it) with each sampler. Rates per wall second and per CPU second (the
    per-core figure: XLA may run one device's program on several threads)."""
    import jax
    import jax.numpy as jnp

    from legs_jax.core import beta_sampler, sampling

    rows, arms = cfg.sampler_rows, cfg.sampler_arms
    a, b = _thompson_shapes(rows, arms)
    dev = jax.local_devices()[0]
    keys = jax.device_put(jax.random.split(jax.random.key(2), rows), dev)
    aj, bj = jax.device_put((jnp.asarray(a), jnp.asarray(b)), dev)
    n = rows * arms
    samplers = {"old": sampling.beta_rows, "new": beta_sampler.beta_rows_v2}
    out: dict[str, Any] = {
        "sampler_versions": {
            "old": beta_sampler.PREVIOUS_SAMPLER_VERSION,
            "new": beta_sampler.SAMPLER_VERSION,
        },
        "sampler_versions_shape": [rows, arms],
    }

    def step(sampler):
        def draw(k, a_, b_):
            return sampling.argmax_first(sampler(k, a_, b_))

        return draw

    fns: dict[str, Callable[[], Any]] = {}
    steps: dict[str, Callable[[], Any]] = {}
    for name, sampler in samplers.items():
        _say(f"sampler versions: {name} (compiling)", quiet)
        draw = jax.jit(sampler)
        pick = jax.jit(step(sampler))
        start = time.perf_counter()
        jax.block_until_ready(draw(keys, aj, bj))
        out[f"sampler_{name}_compile_s"] = round(time.perf_counter() - start, 2)
        jax.block_until_ready(pick(keys, aj, bj))
        fns[name] = lambda draw=draw: jax.block_until_ready(draw(keys, aj, bj))
        steps[name] = lambda pick=pick: jax.block_until_ready(pick(keys, aj, bj))
    a64, b64 = a.astype(np.float64), b.astype(np.float64)
    gen = np.random.default_rng(0)
    fns["numpy"] = lambda: gen.beta(a64, b64)
    _say("sampler versions: timing old, new and NumPy in turns", quiet)
    rates = _interleaved_rates(fns, n, cfg.repeats, cfg.min_seconds)
    for name, r in rates.items():
        out[f"sampler_{name}_samples_per_s"] = r["per_s"]
        out[f"sampler_{name}_samples_per_cpu_s"] = r["per_cpu_s"]
    _say("sampler versions: Thompson draw steps, old and new in turns", quiet)
    step_rates = _interleaved_rates(steps, 1.0, cfg.repeats, cfg.min_seconds)
    for name, r in step_rates.items():
        out[f"thompson_step_{name}_per_s"] = r["per_s"]
        out[f"thompson_step_{name}_per_cpu_s"] = r["per_cpu_s"]
    cpu = {k: r["per_cpu_s"] for k, r in rates.items()}
    out["sampler_new_over_old_per_cpu_s"] = cpu["new"] / cpu["old"]
    out["sampler_new_over_numpy_per_cpu_s"] = cpu["new"] / cpu["numpy"]
    out["sampler_old_over_numpy_per_cpu_s"] = cpu["old"] / cpu["numpy"]
    out["thompson_step_new_over_old_per_cpu_s"] = (
        step_rates["new"]["per_cpu_s"] / step_rates["old"]["per_cpu_s"]
    )
    return out


def bench_memory(cfg: Settings) -> dict[str, float]:
    """Streaming bandwidth: NumPy copy (one core) and a JAX elementwise pass."""
    import jax
    import jax.numpy as jnp

    n = (1 << 23) if cfg.quick else (1 << 25)  # 32 MiB or 128 MiB of float32
    src = np.ones(n, np.float32)
    dst = np.empty_like(src)
    out = {
        "numpy_copy_gb_per_s": _timed_rate(
            lambda: np.copyto(dst, src), 2 * src.nbytes / 1e9, cfg.repeats, 0.3
        )
    }
    # In place (the input buffer is donated), so no page faults of fresh memory.
    fn = jax.jit(lambda v: v * 0.5 + 1.0, donate_argnums=0)
    state = [jax.block_until_ready(fn(jnp.ones(n, jnp.float32)))]

    def step():
        state[0] = jax.block_until_ready(fn(state[0]))

    out["jax_stream_gb_per_s_one_device"] = _timed_rate(
        step, 2 * src.nbytes / 1e9, cfg.repeats, 0.3
    )
    return out


# ----------------------------------------------------------------------- engine


def _problem(cfg: Settings, poses: int | None = None):
    from legs_jax import synthetic

    return synthetic.make_problem(
        0,
        num_poses=poses or cfg.poses,
        num_grasps=cfg.grasps,
        num_trials=cfg.trials,
        name="bench",
    )


def _checked(method: str) -> bool:
    import experiments

    return method in experiments.get("main").CHECK_METHODS


def bench_jax_engine(method: str, cfg: Settings, problem) -> dict[str, float]:
    from legs_jax import runtime
    from legs_jax.core.problem import stack

    batch = stack([problem])
    from legs_jax.core import methods

    dense = methods.get(method).card.dense  # per-step work O(K): fewer rollouts
    total = cfg.rollouts_dense if dense else cfg.rollouts_sparse
    per_trial = max(1, total // cfg.trials)
    steps = cfg.trials * per_trial * cfg.horizon

    def once():
        runtime.run(
            batch,
            method,
            object_ids=[0],
            num_rollouts=per_trial,
            horizon=cfg.horizon,
            check_every=CHECK_EVERY if _checked(method) else None,
            progress=False,
        )

    start = time.perf_counter()
    once()
    first = time.perf_counter() - start
    rate = _timed_rate(once, steps, cfg.repeats, 0.0)
    return {
        "jax": rate,
        "compile_s": round(max(first - steps / rate, 0.0), 2),
        "rollouts": cfg.trials * per_trial,
        "horizon": cfg.horizon,
    }


def _reference_rollouts(args) -> int:
    """Worker: run ``count`` reference rollouts; returns the steps done."""
    problem, method, horizon, trial, first, count = args
    from legs_jax.core import reference

    reference.run(
        problem,
        method,
        trials=[trial],
        num_rollouts=count,
        horizon=horizon,
        seed=first,
        check_every=CHECK_EVERY if _checked(method) else horizon + 1,
    )
    return count * horizon


def bench_reference(method: str, cfg: Settings, problem) -> float:
    """NumPy reference steps per second, one process (one rollout at a time)."""
    from legs_jax.core import reference

    horizon = cfg.reference_horizon
    rates = []
    for rep in range(cfg.repeats):
        steps = 0
        start = time.perf_counter()
        while True:
            reference.run(
                problem,
                method,
                trials=[rep % cfg.trials],
                num_rollouts=1,
                horizon=horizon,
                seed=steps,
                check_every=CHECK_EVERY if _checked(method) else horizon + 1,
            )
            steps += horizon
            elapsed = time.perf_counter() - start
            if elapsed >= cfg.reference_seconds:
                break
        rates.append(steps / elapsed)
    return statistics.median(rates)


def bench_reference_all_cores(method: str, cfg: Settings, problem, one: float) -> float:
    """NumPy reference with one worker process per core, rollouts in parallel."""
    import multiprocessing as mp

    workers = os.cpu_count() or 1
    horizon = cfg.reference_horizon
    # Enough rollouts for each worker to run about reference_seconds.
    per_worker = max(1, math.ceil(cfg.reference_seconds * one / horizon))
    jobs = [
        (problem, method, horizon, i % cfg.trials, i, per_worker)
        for i in range(workers)
    ]
    ctx = mp.get_context("spawn")
    with ctx.Pool(workers) as pool:
        pool.map(_reference_rollouts, [(problem, method, 10, 0, 0, 1)] * workers)
        rates = []
        for _ in range(cfg.repeats):
            start = time.perf_counter()
            steps = sum(pool.map(_reference_rollouts, jobs))
            rates.append(steps / (time.perf_counter() - start))
    return statistics.median(rates)


# ----------------------------------------------------------------------- projection


def _count_objects(names: Sequence[str]) -> int:
    try:
        from precompute import catalog

        sizes = {s: len(catalog.objects(s)) for s in SET_SIZES}
    except Exception:  # the catalogue is optional here
        sizes = dict(SET_SIZES)
    return sum(sizes.get(n, 1) for n in names)


def projection(rates: dict[str, float]) -> dict[str, Any]:
    """Minutes of ``--all`` from rollout-steps per second of each method, every
    object charged at the benchmark's pose count (the projection without the
    problem files: :func:`projection_by_chunk` is the one used with them).

    Work of an arm = objects x trials x rollouts x horizon x grid points, charged
    at the measured rate of its method (with the Dirichlet checks where the main
    sweep records them, as the table measures it). Compilation and precompute are
    not included.
    """
    import experiments

    proxies = proxy()
    per_exp = {}
    steps_total = 0.0
    seconds = 0.0
    for name in experiments.EXPERIMENTS:
        mod = experiments.get(name)
        n_obj = _count_objects(mod.OBJECTS)
        exp_s = 0.0
        for method, _variant, hp in mod.ARMS:
            grid = max([len(v) for v in hp.values() if isinstance(v, tuple)] or [1])
            steps = n_obj * mod.TRIALS * mod.ROLLOUTS * mod.HORIZON * grid
            rate = rates.get(method) or rates[proxies[method]]
            steps_total += steps
            exp_s += steps / rate
        per_exp[name] = round(exp_s / 60.0, 2)
        seconds += exp_s
    return {
        "projection": "by experiment, every object at the benchmark's pose count",
        "projected_all_minutes": round(seconds / 60.0, 2),
        "projected_minutes_per_experiment": per_exp,
        "all_rollout_steps": steps_total,
    }


def sweep_plans() -> tuple[list | None, str | None]:
    """The plans of ``--all`` (chunks, pose buckets, padding), or None and the
    reason when they cannot be made here (problem files missing)."""
    try:
        from legs_jax.sweep import shapes

        return shapes.plan_all(), None
    except Exception as e:  # noqa: BLE001 - the projection falls back
        return None, str(e).splitlines()[0] if str(e) else type(e).__name__


def pose_buckets(plans: Sequence[Any]) -> tuple[int, ...]:
    """The pose counts the sweep's chunks are padded to."""
    return tuple(sorted({c.num_poses for plan in plans for c in plan.chunks}))


def projection_by_chunk(
    rates_by_poses: dict[int, dict[str, float]], plans: Sequence[Any], n_dev: int
) -> dict[str, Any]:
    """Minutes of ``--all`` chunk by chunk, as the sweep runs them: each chunk's
    rollouts as the engine runs them (mini-batch padding included) times the
    horizon, at its method's rate for the chunk's pose bucket (``rates_by_poses[P]``;
    a bucket not measured takes the nearest measured one, a method not measured
    its ``bench_proxy``). A chunk whose rollouts an earlier experiment already
    made is copied by the sweep, not run, and costs nothing here. Compilation,
    loading and writing are not included."""
    from legs_jax.sweep import shapes
    from legs_jax.sweep.store import donor_keys

    proxies = proxy()
    measured = sorted(rates_by_poses)

    def rate(method: str, poses: int) -> float:
        p = min(measured, key=lambda m: (abs(m - poses), m))
        got = rates_by_poses[p]
        return got.get(method) or got[proxies[method]]

    made: set = set()
    per_exp: dict[str, float] = {}
    steps_total = seconds = 0.0
    for plan in plans:
        exp_s = 0.0
        new: set = set()
        for c in plan.chunks:
            keys = donor_keys(plan, c)
            if keys is not None and set(keys) <= made:
                continue  # copied from an earlier experiment
            new |= set(keys or ())
            for key, _rows, run in shapes._chunk_programs(plan, c, n_dev):
                steps = run * plan.horizon
                steps_total += steps
                exp_s += steps / rate(key[0], c.num_poses)
        made |= new
        per_exp[plan.name] = round(exp_s / 60.0, 2)
        seconds += exp_s
    return {
        "projection": "chunk by chunk, at each pose bucket's rates, copies free",
        "projected_all_minutes": round(seconds / 60.0, 2),
        "projected_minutes_per_experiment": per_exp,
        "all_rollout_steps": steps_total,
    }


# ----------------------------------------------------------------------- main


def run(cfg: Settings, quiet: bool = False) -> dict[str, Any]:
    import jax

    result: dict[str, Any] = {
        "quick": cfg.quick,
        "machine": {
            "cpu": _cpu_model(),
            "cores": os.cpu_count(),
            "platform": jax.default_backend(),
            "devices": [str(d) for d in jax.local_devices()],
            "jax": jax.__version__,
            "numpy": np.__version__,
            "python": platform.python_version(),
            "load_average_start": _load(),
        },
    }
    result.update(bench_sampler(cfg, quiet))
    result.update(bench_memory(cfg))

    problem = _problem(cfg)
    steps: dict[str, dict[str, float]] = {}
    table = table_methods()
    jax_rates: dict[str, float] = {}
    for method in cfg.methods:
        _say(f"engine: {method} (JAX)", quiet)
        row = bench_jax_engine(method, cfg, problem)
        jax_rates[method] = row["jax"]
        if method in table:
            _say(f"engine: {method} (NumPy reference)", quiet)
            row["numpy"] = bench_reference(method, cfg, problem)
            row["ratio"] = row["jax"] / row["numpy"]
            if cfg.numpy_all_cores and (os.cpu_count() or 1) > 1:
                row["numpy_all_cores"] = bench_reference_all_cores(
                    method, cfg, problem, row["numpy"]
                )
                row["ratio_all_cores"] = row["jax"] / row["numpy_all_cores"]
        steps[method] = row
    result["steps_per_s"] = steps
    result["engine_setup"] = {
        "poses": cfg.poses,
        "grasps": cfg.grasps,
        "trials": cfg.trials,
        "horizon": cfg.horizon,
        "reference_horizon": cfg.reference_horizon,
        "check_every": CHECK_EVERY,
        "checked_methods": [m for m in cfg.methods if _checked(m)],
    }
    plans, why = (None, "a quick run") if cfg.quick else sweep_plans()
    if plans is None:
        result.update(projection(jax_rates))
        result["projection_note"] = f"no sweep plans ({why})"
    else:
        by_poses = {cfg.poses: jax_rates}
        for poses in pose_buckets(plans):
            if poses in by_poses:
                continue
            at = _problem(cfg, poses)
            by_poses[poses] = {}
            for method in cfg.methods:
                _say(f"engine: {method} (JAX) at {poses} poses", quiet)
                by_poses[poses][method] = bench_jax_engine(method, cfg, at)["jax"]
        result["steps_per_s_by_poses"] = {str(p): r for p, r in by_poses.items()}
        result.update(projection_by_chunk(by_poses, plans, len(jax.local_devices())))
    result["machine"]["load_average_end"] = _load()
    return result


def _fmt_rate(x: float) -> str:
    if x >= 1e6:
        return f"{x / 1e6:.1f} M"
    if x >= 1e3:
        return f"{x / 1e3:.1f} k"
    return f"{x:.0f}"


def format_table(r: dict[str, Any]) -> str:
    m = r["machine"]
    lines = [
        f"machine: {m['cpu']}, {m['cores']} cores, JAX {m['jax']} on "
        f"{m['platform']} ({len(m['devices'])} devices), load average "
        f"{m['load_average_start']} -> {m['load_average_end']}",
        "",
        f"Exact Beta samples per second (shape {r['shape'][0]} x {r['shape'][1]}, "
        "posterior-like shapes)",
        "  legs_jax.core.sampling.beta_rows  "
        f"{_fmt_rate(r['sampler_samples_per_s']):>9}/s"
        f"   (compile {r['sampler_compile_s']} s)",
    ]
    for key, label in (("one_device", "one device"), ("all_devices", "all devices")):
        if f"sampler_samples_per_s_{key}" in r:
            lines.append(
                f"    {label + ' (rows split)' * (key == 'all_devices'):<27}"
                f"{_fmt_rate(r[f'sampler_samples_per_s_{key}']):>9}/s"
            )
    lines += [
        f"  jax.random.beta              "
        f"{_fmt_rate(r['jax_random_beta_samples_per_s']):>9}/s"
        f"   (compile {r['jax_random_beta_compile_s']} s)",
        f"  numpy Generator.beta, 1 core "
        f"{_fmt_rate(r['numpy_beta_samples_per_s']):>9}/s",
    ]
    if "sampler_new_samples_per_cpu_s" in r:
        rows_, arms_ = r["sampler_versions_shape"]
        v = r["sampler_versions"]
        lines += [
            "",
            f"Beta samplers side by side (one device, timed in turns; Thompson-step "
            f"shapes {rows_} x {arms_}): per CPU second (per core) and per wall second",
        ]
        for key, label in (
            ("old", f"old  sampling.beta_rows ({v['old']})"),
            ("new", f"new  beta_sampler.beta_rows_v2 ({v['new']})"),
            ("numpy", "numpy Generator.beta"),
        ):
            lines.append(
                f"  {label:<52}"
                f"{_fmt_rate(r[f'sampler_{key}_samples_per_cpu_s']):>9}/cpu-s"
                f"{_fmt_rate(r[f'sampler_{key}_samples_per_s']):>9}/s"
            )
        lines.append(
            f"  per core: new/old {r['sampler_new_over_old_per_cpu_s']:.2f}x, "
            f"new/numpy {r['sampler_new_over_numpy_per_cpu_s']:.2f}x, "
            f"old/numpy {r['sampler_old_over_numpy_per_cpu_s']:.2f}x"
        )
        lines.append(
            f"  Thompson draw step [{rows_}, {arms_}] + argmax: old "
            f"{_fmt_rate(r['thompson_step_old_per_cpu_s'])}/cpu-s, new "
            f"{_fmt_rate(r['thompson_step_new_per_cpu_s'])}/cpu-s "
            f"({r['thompson_step_new_over_old_per_cpu_s']:.2f}x)"
        )
        lines.append("")
    lines += [
        f"  random words (Threefry-2x32, one device) "
        f"{_fmt_rate(r['random_words_per_s_one_device'])}/s; "
        f"{r['random_words_per_beta']:.2f} words per Beta draw "
        f"({100 * r['beta_retry_fraction']:.1f} % of draws retried)",
        f"  memory: NumPy copy {r['numpy_copy_gb_per_s']:.1f} GB/s (one core), "
        f"JAX stream {r['jax_stream_gb_per_s_one_device']:.1f} GB/s (one device)",
        "",
    ]
    e = r["engine_setup"]
    lines.append(
        f"Rollout steps per second (synthetic problem: P={e['poses']}, "
        f"K={e['grasps']}, H={e['horizon']} (reference H={e['reference_horizon']}); "
        f"Dirichlet check every {e['check_every']} steps for "
        f"{', '.join(e['checked_methods']) or 'none'}, as in the main sweep)"
    )
    header = (
        f"  {'method':<12} {'JAX':>9} {'NumPy':>9} {'ratio':>7}"
        f" {'NumPy all cores':>16} {'ratio':>7} {'compile':>8}"
    )
    lines.append(header)
    table = table_methods()
    rows = r["steps_per_s"]
    for method in sorted(rows, key=lambda m: (m not in table, m)):
        row = rows[method]
        np_ = _fmt_rate(row["numpy"]) if "numpy" in row else "-"
        ratio = f"{row['ratio']:.1f}x" if "ratio" in row else "-"
        npa = _fmt_rate(row["numpy_all_cores"]) if "numpy_all_cores" in row else "-"
        ra = f"{row['ratio_all_cores']:.1f}x" if "ratio_all_cores" in row else "-"
        lines.append(
            f"  {method:<12} {_fmt_rate(row['jax']):>9} {np_:>9} {ratio:>7}"
            f" {npa:>16} {ra:>7} {row['compile_s']:>7}s"
        )
    by_poses = r.get("steps_per_s_by_poses")
    if by_poses:
        cols = sorted(by_poses, key=int)
        lines += ["", "JAX rollout steps per second by pose count (for the projection)"]
        lines.append(
            "  " + f"{'method':<16}" + "".join(f"{'P=' + c:>10}" for c in cols)
        )
        for method in sorted(by_poses[cols[0]]):
            lines.append(
                f"  {method:<16}"
                + "".join(f"{_fmt_rate(by_poses[c][method]):>10}" for c in cols)
            )
    lines += [
        "",
        f"Projected wall time of `python -m legs_jax.sweep --all` "
        f"({r['projection']}): "
        f"{r['projected_all_minutes']:.1f} min "
        f"({r['all_rollout_steps']:.3g} rollout-steps; compilation and precompute "
        "not included)",
    ]
    if r.get("projection_note"):
        lines.append(f"  ({r['projection_note']})")
    for name, minutes in r["projected_minutes_per_experiment"].items():
        lines.append(f"  {name:<16} {minutes:8.1f} min")
    return "\n".join(lines)


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog=_PROG, description=_DESCRIPTION)
    p.add_argument(
        "--json", action="store_true", help="print one JSON object instead of a table"
    )
    p.add_argument(
        "--quick",
        action="store_true",
        help="smaller problem and fewer repeats, table methods only (about a minute)",
    )
    p.add_argument(
        "--methods",
        nargs="+",
        action="extend",
        choices=_all_methods(),
        metavar="METHOD",
        help="methods to time besides the table's three (default: none with "
        "--quick, all seven otherwise); a method not timed is projected at the rate "
        "of one with the same per-step work",
    )
    p.add_argument(
        "--quiet", action="store_true", help="no progress messages on stderr"
    )
    return p


def main(argv: Sequence[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    cfg = settings(args.quick, args.methods)
    _set_host_devices()
    quiet = args.quiet or args.json
    try:
        result = run(cfg, quiet=quiet)
    except KeyboardInterrupt:
        print("interrupted", file=sys.stderr)
        return 130
    if args.json:
        print(json.dumps(result, indent=1, sort_keys=True))
    else:
        print(format_table(result))
    return 0


if __name__ == "__main__":
    sys.exit(main())
