"""Exact Beta samplers side by side: this project's, ``jax.random.beta`` and
NumPy's ``Generator.beta``; random words and memory bandwidth.

JAX and the modules that load it (the methods, the engine, the reference) are
imported inside the functions: JAX must start after the benchmark has set one
host device per core (:func:`legs_jax.bench.common._set_host_devices`).
"""

from __future__ import annotations

import time
from collections.abc import Callable
from typing import Any

import numpy as np

from legs_jax.bench.common import (
    Settings,
    _interleaved_rates,
    _say,
    _timed_rate,
)


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


def _thompson_shapes(
    rows: int, arms: int, strength: float = 1.0, offset: float = 1.0
) -> tuple[np.ndarray, np.ndarray]:
    """Shapes of a K = ``arms`` Thompson step: 70 % of grasps at the prior
    α = 1 + q, β = 1 + (1 − q), 25 % tried a few to tens of times, 5 % with
    hundreds of counts (successes at the grasp's quality q).

    ``strength`` s and ``offset`` o give the prior α = o + s q, β = o + s (1 − q)
    instead: s = 5, o = 0 is BORGES's original prior, whose shapes fall below 1
    where q < 0.2 or q > 0.8 (Cheng's test rejects such draws more often)."""
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
    a = (offset + strength * q + wins).astype(np.float32)
    b = (offset + strength * (1.0 - q) + tries - wins).astype(np.float32)
    return a, b


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
    per-core figure: XLA may run one device's program on several threads, and
    what those threads spend waiting on each other counts).

    Then the same in a child process held to one core (``one_core_*`` keys, where
    the operating system lets a process choose its cores): all three on the same
    single core, so "per core" means exactly one core, not CPU seconds of a
    program spread over several."""
    out = _sampler_versions(cfg.sampler_rows, cfg.sampler_arms, cfg, quiet)
    _say("sampler versions: again, held to one core (child process)", quiet)
    one = _sampler_versions_one_core(cfg)
    out.update({f"one_core_{k}": v for k, v in one.items() if k.startswith(_RATES)})
    return out


# The keys of _sampler_versions that are rates or ratios (what the one-core run
# adds), and those of the harder shapes (measured on one core only).
_RATES = ("sampler_old", "sampler_new", "sampler_numpy", "thompson_step", "harder_")


def _sampler_versions(
    rows: int, arms: int, cfg: Settings, quiet: bool
) -> dict[str, Any]:
    import jax
    import jax.numpy as jnp

    from legs_jax.core import beta_sampler, sampling
    from legs_jax.runtime.programs import cpu_vector_options

    a, b = _thompson_shapes(rows, arms)
    dev = jax.local_devices()[0]
    keys = jax.device_put(jax.random.split(jax.random.key(2), rows), dev)
    aj, bj = jax.device_put((jnp.asarray(a), jnp.asarray(b)), dev)
    n = rows * arms
    # Compiled as the engine compiles its simulations (512-bit vectors on a CPU
    # with AVX-512); where that is not XLA's default, the engine's sampler is
    # also timed as XLA compiles it by default ("new_default").
    xla = cpu_vector_options([dev])
    samplers = {
        "old": (sampling.beta_rows, xla),
        "new": (beta_sampler.beta_rows_v2, xla),
    }
    if xla:
        samplers["new_default"] = (beta_sampler.beta_rows_v2, {})
    out: dict[str, Any] = {
        "sampler_versions": {
            "old": beta_sampler.PREVIOUS_SAMPLER_VERSION,
            "new": beta_sampler.SAMPLER_VERSION,
        },
        "sampler_versions_shape": [rows, arms],
        "sampler_compiler_options": xla,
    }

    def step(sampler):
        def draw(k, a_, b_):
            return sampling.argmax_first(sampler(k, a_, b_))

        return draw

    fns: dict[str, Callable[[], Any]] = {}
    steps: dict[str, Callable[[], Any]] = {}
    for name, (sampler, options) in samplers.items():
        _say(f"sampler versions: {name} (compiling)", quiet)
        draw = jax.jit(sampler, compiler_options=options or None)
        start = time.perf_counter()
        jax.block_until_ready(draw(keys, aj, bj))
        out[f"sampler_{name}_compile_s"] = round(time.perf_counter() - start, 2)
        fns[name] = lambda draw=draw: jax.block_until_ready(draw(keys, aj, bj))
        if name in ("old", "new"):
            pick = jax.jit(step(sampler), compiler_options=options or None)
            jax.block_until_ready(pick(keys, aj, bj))
            steps[name] = lambda pick=pick: jax.block_until_ready(pick(keys, aj, bj))
    a64, b64 = a.astype(np.float64), b.astype(np.float64)
    gen = np.random.default_rng(0)
    fns["numpy"] = lambda: gen.beta(a64, b64)
    _say(f"sampler versions: timing {', '.join(fns)} in turns", quiet)
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
    if "new_default" in cpu:
        out["sampler_new_default_over_numpy_per_cpu_s"] = (
            cpu["new_default"] / cpu["numpy"]
        )
    out["thompson_step_new_over_old_per_cpu_s"] = (
        step_rates["new"]["per_cpu_s"] / step_rates["old"]["per_cpu_s"]
    )
    return out


def _harder_shapes_vs_numpy(rows: int, arms: int, cfg: Settings) -> dict[str, Any]:
    """The engine's sampler against NumPy's ``Generator.beta`` on the shapes of a
    Thompson step under BORGES's original prior (:func:`_thompson_shapes` with
    s = 5, o = 0): the hardest mix the engine's rows draw (in a run on
    bar_clamp 14-16 % of that row's draws were rejected at try 0, against 5-8 %
    for the other rows; with q uniform, as here, about 22 %). Timed in turns on
    one device, per CPU second."""
    import jax
    import jax.numpy as jnp

    from legs_jax.core import beta_sampler
    from legs_jax.runtime.programs import cpu_vector_options

    a, b = _thompson_shapes(rows, arms, strength=5.0, offset=0.0)
    dev = jax.local_devices()[0]
    keys = jax.device_put(jax.random.split(jax.random.key(3), rows), dev)
    aj, bj = jax.device_put((jnp.asarray(a), jnp.asarray(b)), dev)
    # compiled (by the warm-up call) as the engine compiles it
    xla = cpu_vector_options([dev]) or None
    draw = jax.jit(beta_sampler.beta_rows_v2, compiler_options=xla)
    a64, b64 = a.astype(np.float64), b.astype(np.float64)
    gen = np.random.default_rng(0)
    fns = {
        "new": lambda: jax.block_until_ready(draw(keys, aj, bj)),
        "numpy": lambda: gen.beta(a64, b64),
    }
    rates = _interleaved_rates(fns, rows * arms, cfg.repeats, cfg.min_seconds)
    # The share of draws rejected at try 0 (retried), as the sampler computes it.
    first = beta_sampler._first_tries(*beta_sampler._beta_inputs(keys, aj, bj))
    return {
        "harder_sampler_new_samples_per_cpu_s": rates["new"]["per_cpu_s"],
        "harder_sampler_numpy_samples_per_cpu_s": rates["numpy"]["per_cpu_s"],
        "harder_sampler_new_over_numpy_per_cpu_s": rates["new"]["per_cpu_s"]
        / rates["numpy"]["per_cpu_s"],
        "harder_retry_fraction": float(jnp.mean(first < 0.0)),
    }


# The child of _sampler_versions_one_core: holds itself to one core before JAX
# (and with it XLA's thread pool) starts, then prints its rates as JSON.
_ONE_CORE_CHILD = """
import json, os, sys
os.sched_setaffinity(0, {min(os.sched_getaffinity(0))})
from legs_jax.bench.common import Settings
from legs_jax.bench.sampler import _harder_shapes_vs_numpy, _sampler_versions
args = json.loads(sys.argv[1])
cfg = Settings(**args["cfg"])
out = _sampler_versions(args["rows"], args["arms"], cfg, True)
out.update(_harder_shapes_vs_numpy(args["rows"], args["arms"], cfg))
print(json.dumps(out))
"""


def _one_device_env(environ) -> dict[str, str]:
    """``environ`` for the one-core child, with one XLA device: the parent's
    ``--xla_force_host_platform_device_count`` would give the child as many,
    whose thread pools then share its one core (on a 2-core Xeon the samplers ran
    15-20 % slower so, the harder shapes 40 %)."""
    env = dict(environ)
    flags = env.get("XLA_FLAGS", "").split()
    env["XLA_FLAGS"] = " ".join(
        f for f in flags if not f.startswith("--xla_force_host_platform_device_count")
    )
    return env


def _sampler_versions_one_core(cfg: Settings) -> dict[str, Any]:
    """:func:`_sampler_versions` in a child process held to one core; empty where
    the operating system has no way to choose a process's cores."""
    import dataclasses
    import json
    import os
    import subprocess
    import sys

    if not hasattr(os, "sched_setaffinity"):
        return {}
    args = {
        "cfg": dataclasses.asdict(cfg),
        "rows": cfg.sampler_rows,
        "arms": cfg.sampler_arms,
    }
    done = subprocess.run(
        [sys.executable, "-c", _ONE_CORE_CHILD, json.dumps(args)],
        capture_output=True,
        text=True,
        check=True,
        env=_one_device_env(os.environ),
    )
    return json.loads(done.stdout.strip().splitlines()[-1])


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
