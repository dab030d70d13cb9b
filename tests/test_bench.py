"""The speed benchmark: its timing helpers measure what they say, its table shows
the figures it is given, its projection adds up the sweep, and (slow) a quick run
reports every figure. No timing thresholds on this machine's speed."""

from __future__ import annotations

import dataclasses
import json
import math
import os
import subprocess
import sys
import time

import pytest

import experiments
from legs_jax import bench
from legs_jax.bench import common

REQUIRED = (
    "sampler_samples_per_s",
    "jax_random_beta_samples_per_s",
    "numpy_beta_samples_per_s",
    "steps_per_s",
    "projected_all_minutes",
)


def _positive(x) -> bool:
    return isinstance(x, (int, float)) and math.isfinite(x) and x > 0


@pytest.fixture(scope="module")
def quick_result():
    env = dict(os.environ)
    env.pop("XLA_FLAGS", None)  # the benchmark chooses its own device count
    out = subprocess.run(
        [sys.executable, "-m", "legs_jax.bench", "--quick", "--json"],
        capture_output=True,
        text=True,
        env=env,
        timeout=600,
    )
    assert out.returncode == 0, out.stderr[-2000:]
    return json.loads(out.stdout)


@pytest.mark.slow
def test_quick_json_has_every_figure(quick_result):
    r = quick_result
    for key in REQUIRED:
        assert key in r, key
    for key in REQUIRED[:3] + ("projected_all_minutes",):
        assert _positive(r[key]), (key, r[key])
    assert set(bench.table_methods()) <= set(r["steps_per_s"])
    for method in bench.table_methods():
        row = r["steps_per_s"][method]
        for key in ("jax", "numpy", "ratio"):
            assert _positive(row[key]), (method, key, row[key])
        assert row["ratio"] == pytest.approx(row["jax"] / row["numpy"])
    for key in ("random_words_per_s_one_device", "numpy_copy_gb_per_s"):
        assert _positive(r[key]), key
    assert 4.0 <= r["random_words_per_beta"] < 6.0
    # The old and new exact Beta samplers and NumPy, timed in turns.
    for name in ("old", "new", "numpy"):
        for unit in ("per_s", "per_cpu_s"):
            assert _positive(r[f"sampler_{name}_samples_{unit}"]), (name, unit)
    for name in ("old", "new"):
        assert _positive(r[f"thompson_step_{name}_per_cpu_s"]), name
    assert r["sampler_new_over_old_per_cpu_s"] == pytest.approx(
        r["sampler_new_samples_per_cpu_s"] / r["sampler_old_samples_per_cpu_s"]
    )
    assert r["sampler_versions"]["new"] != r["sampler_versions"]["old"]
    # Compiled as the engine compiles its simulations; where that is not XLA's
    # default (512-bit vectors on AVX-512), the default is timed beside it.
    from legs_jax.runtime.programs import cpu_vector_options

    assert r["sampler_compiler_options"] == cpu_vector_options()
    if r["sampler_compiler_options"]:
        assert _positive(r["sampler_new_default_samples_per_cpu_s"])
        assert "new, compiled with XLA's defaults" in bench.format_table(r)
    # The human-readable table renders from the same figures.
    table = bench.format_table(r)
    assert "jax.random.beta" in table and "borges_2000" in table
    assert "beta_sampler.beta_rows_v2" in table and "Thompson draw step" in table
    # The stopping checks: each bound alone, LEGS with and without them.
    for key in ("paper", "ours", "ours_fit", "ours_boot"):
        assert _positive(r["check_cost_us_per_cpu"][key]), key
    for key in ("none", "paper", "both", "both_boot"):
        assert _positive(r["legs_checks_steps_per_cpu_s"][key]), key
    assert "Stopping checks" in table


def test_projection_adds_up_the_sweep():
    """Minutes = sum over experiments and arms of rollout-steps / rate."""
    rates = {
        "borges_2000": 1e4,
        "legs": 1e5,
        "tql": 2e5,
        "bayes_ucb_2000": 5e3,
        "pooled_ucb": 4e3,
    }
    assert set(rates) == set(bench.table_methods())
    p = bench.projection(rates)
    expected_s = 0.0
    for name in experiments.EXPERIMENTS:
        mod = experiments.get(name)
        n_obj = bench.count_objects(mod.OBJECTS)
        for method, _, hp in mod.ARMS:
            grid = max([len(v) for v in hp.values() if isinstance(v, tuple)] or [1])
            rate = rates.get(method) or rates[bench.proxy()[method]]
            expected_s += n_obj * mod.TRIALS * mod.ROLLOUTS * mod.HORIZON * grid / rate
    assert p["projected_all_minutes"] == pytest.approx(expected_s / 60, rel=1e-3)
    assert sum(p["projected_minutes_per_experiment"].values()) == pytest.approx(
        p["projected_all_minutes"], abs=0.1
    )
    # Twice the speed, half the time.
    faster = bench.projection({k: 2 * v for k, v in rates.items()})
    assert faster["projected_all_minutes"] == pytest.approx(
        p["projected_all_minutes"] / 2, rel=1e-2
    )


def test_main_object_count():
    # 13 Dex-Net adversarial + 49 EGAD evaluation objects.
    assert bench.count_objects(("dexnet_adv", "egad_eval")) == 62
    assert bench.count_objects(("bar_clamp",)) == 1


def test_help_and_bad_arguments():
    ok = subprocess.run(
        [sys.executable, "-m", "legs_jax.bench", "--help"],
        capture_output=True,
        text=True,
    )
    assert ok.returncode == 0 and "--quick" in ok.stdout and "--json" in ok.stdout
    bad = subprocess.run(
        [sys.executable, "-m", "legs_jax.bench", "--methods", "nope"],
        capture_output=True,
        text=True,
    )
    assert bad.returncode == 2 and "invalid choice" in bad.stderr
    assert "Traceback" not in bad.stderr


def test_timed_calls_measure_wall_and_cpu_seconds():
    """A call that sleeps 20 ms does 50 calls' work a wall second, and uses almost
    no CPU: its rate per CPU second is far above its rate per wall second."""
    per_s, per_cpu_s = common._timed_calls(lambda: time.sleep(0.02), 3.0, 0.2)
    assert 3.0 * 50 * 0.2 < per_s <= 3.0 * 50 * 1.01  # sleeps last at least 20 ms
    assert per_cpu_s > 5 * per_s

    # The median of repeats, each at least min_seconds long.
    calls = []
    rate = common._timed_rate(lambda: calls.append(time.sleep(0.01)), 1.0, 3, 0.05)
    assert len(calls) >= 3 * 5 and 0 < rate <= 100 * 1.01


def test_interleaved_rates_time_in_turns():
    """Repeat r of every function before repeat r + 1 of any (after one warm-up
    call each), so that a change of load hits them alike, the order rotated by one
    from each repeat to the next (none always first)."""
    order = []

    def fn(name):
        def call():
            order.append(name)
            time.sleep(0.002)

        return call

    fns = {"a": fn("a"), "b": fn("b"), "c": fn("c")}
    rates = common._interleaved_rates(fns, 2.0, 4, 0.0)
    # warm-up, then four repeats of one call each, each starting one later
    assert order == list("abc" + "abc" + "bca" + "cab" + "abc")
    for r in rates.values():
        assert set(r) == {"per_s", "per_cpu_s"}
        assert r["per_s"] <= 2.0 / 0.002 * 1.01


def _result(**over):
    """A benchmark result with made-up figures (every key the table reads)."""
    r = {
        "machine": {"cpu": "Test CPU", "cores": 2, "jax": "0.0", "platform": "cpu",
                    "devices": ["d0", "d1"], "load_average_start": [0.1, 0.1, 0.1],
                    "load_average_end": [0.2, 0.2, 0.2]},
        "shape": [16, 2000],
        "sampler_samples_per_s": 69.5e6, "sampler_compile_s": 1.5,
        "sampler_samples_per_s_one_device": 40e6,
        "sampler_samples_per_s_all_devices": 69.5e6,
        "jax_random_beta_samples_per_s": 8.2e6, "jax_random_beta_compile_s": 2.0,
        "numpy_beta_samples_per_s": 26.6e6,
        "random_words_per_s_one_device": 2.1e9, "random_words_per_beta": 4.7,
        "beta_retry_fraction": 0.044, "numpy_copy_gb_per_s": 9.0,
        "jax_stream_gb_per_s_one_device": 12.0,
        "engine_setup": {"poses": 4, "grasps": 2000, "horizon": 100,
                         "reference_horizon": 100, "check_every": 100,
                         "checked_methods": ["legs"]},
        "steps_per_s": {
            "legs": {"jax": 3.0e5, "numpy": 1.0e5, "ratio": 3.0, "compile_s": 4.0},
            "tql": {"jax": 2.5e3, "compile_s": 1.0},
        },
        "projection": "by experiment", "projected_all_minutes": 71.0,
        "all_rollout_steps": 1.0e9,
        "projected_minutes_per_experiment": {"main": 62.0, "regimes": 9.0},
    }  # fmt: skip
    r.update(over)
    return r


def test_table_shows_the_figures_it_is_given():
    lines = bench.format_table(_result()).splitlines()
    text = "\n".join(lines)
    assert "Test CPU, 2 cores" in text
    assert "69.5 M/s" in text and "26.6 M/s" in text and "8.2 M/s" in text
    assert "4.70 words per Beta draw (4.4 % of draws retried)" in text
    (legs,) = [x for x in lines if x.split()[:1] == ["legs"]]
    assert legs.split()[1:7] == ["300.0", "k", "100.0", "k", "3.0x", "-"]
    (tql,) = [x for x in lines if x.split()[:1] == ["tql"]]
    assert tql.split()[1:5] == ["2.5", "k", "-", "-"]  # not timed against NumPy
    assert "71.0 min" in text and "main" in text and "62.0 min" in text
    assert "Beta samplers side by side" not in text  # no sampler versions given
    assert "Stopping checks" not in text  # no check costs given


def test_table_shows_the_check_costs_it_is_given():
    r = _result(
        check_cost_setup={
            "rows": 32,
            "poses": 8,
            "slots": 100,
            "M": 3000,
            "M_ours": 1000,
            "boot_replicates": 8,
        },
        check_cost_us_per_cpu={
            "paper": 300.0,
            "ours": 450.0,
            "ours_fit": 47.0,
            "ours_boot": 900.0,
        },
        check_cost_ours_over_paper=1.5,
        legs_checks_steps_per_cpu_s={
            "none": 2.0e5,
            "paper": 1.2e5,
            "both": 1.0e5,
            "both_boot": 0.8e5,
        },
        legs_checks_rollouts=64,
        legs_checks_added_us_per_check={
            "paper": 350.0,
            "ours": 170.0,
            "ours_boot": 420.0,
        },
        legs_checks_both_over_none=2.0,
    )
    text = bench.format_table(r)
    assert "P=8, 100 slots a pose, M=3000, ours M'=1000" in text
    assert "the paper's bound alone      300 us" in text
    assert "ours alone                   450 us (1.50x the paper's; its fit 47 us)" in (
        text
    )
    assert "ours, fit bootstrapped (8 replicates)      900 us (3.00x the paper's)" in (
        text
    )
    assert "200.0 k steps/cpu-s without checks, 120.0 k with the paper's" in text
    assert (
        "the paper's bound 350 us, ours beside it (the same Dirichlet draws) 170 us"
        in text
    )
    assert "with ours bootstrapped: 80.0 k steps/cpu-s; ours adds 420 us a check" in (
        text
    )


def test_table_shows_the_sampler_versions_and_the_one_core_runs_it_is_given():
    versions = {
        "sampler_versions": {"old": "mt-1", "new": "cheng-1"},
        "sampler_versions_shape": [64, 2000],
        "sampler_old_samples_per_s": 30e6, "sampler_old_samples_per_cpu_s": 31e6,
        "sampler_new_samples_per_s": 36e6, "sampler_new_samples_per_cpu_s": 37e6,
        "sampler_numpy_samples_per_s": 12e6, "sampler_numpy_samples_per_cpu_s": 12.5e6,
        "sampler_new_over_old_per_cpu_s": 37 / 31,
        "sampler_new_over_numpy_per_cpu_s": 37 / 12.5,
        "sampler_old_over_numpy_per_cpu_s": 31 / 12.5,
        "thompson_step_old_per_cpu_s": 250.0, "thompson_step_new_per_cpu_s": 300.0,
        "thompson_step_new_over_old_per_cpu_s": 1.2,
    }  # fmt: skip
    one = {f"one_core_{k}": v for k, v in versions.items() if "sampler_v" not in k}
    one.update(
        one_core_sampler_new_over_numpy_per_cpu_s=3.05,
        one_core_harder_sampler_new_samples_per_cpu_s=25e6,
        one_core_harder_sampler_numpy_samples_per_cpu_s=10e6,
        one_core_harder_sampler_new_over_numpy_per_cpu_s=2.5,
        one_core_harder_retry_fraction=0.219,
    )
    text = bench.format_table(_result(**versions))
    assert "Thompson-step shapes 64 x 2000" in text
    assert "per core: new/old 1.19x, new/numpy 2.96x, old/numpy 2.48x" in text
    assert "held to one core" not in text  # no one-core run given
    text = bench.format_table(_result(**versions, **one))
    assert "new/numpy 3.05x, old/numpy 2.48x; Thompson step new/old 1.20x" in text
    (harder,) = [x for x in text.splitlines() if "original prior" in x]
    assert "21.9 % retried" in harder and harder.endswith("new/numpy 2.50x")
    assert "25.0 M/s" in harder and "10.0 M/s" in harder
    assert "XLA's defaults" not in text and "compiled as the engine" not in text
    # Compiled with 512-bit vectors, the sampler as XLA compiles it by default
    # beside it, in both runs.
    default = {
        "sampler_new_default_samples_per_s": 28e6,
        "sampler_new_default_samples_per_cpu_s": 29e6,
    }
    wide = {
        **versions, **default, **one,
        **{f"one_core_{k}": v for k, v in default.items()},
        "one_core_sampler_new_default_over_numpy_per_cpu_s": 2.32,
        "sampler_compiler_options": {"xla_cpu_prefer_vector_width": 512},
    }  # fmt: skip
    text = bench.format_table(_result(**wide))
    assert "compiled as the engine compiles its simulations: " in text
    assert "xla_cpu_prefer_vector_width=512" in text
    (line,) = [x for x in text.splitlines() if x.lstrip().startswith("new, compiled")]
    assert "29.0 M/cpu-s" in line and "28.0 M/s" in line
    (line,) = [x for x in text.splitlines() if "one core, new compiled" in x]
    assert "29.0 M/s" in line and line.endswith("new/numpy 2.32x")


@pytest.mark.slow  # the quick benchmark above times them too
def test_check_cost_bench_times_both_bounds_on_the_same_shapes():
    """A tiny run of the function-level comparison: both bounds timed, ours at
    least its own fit (it includes it)."""
    cfg = dataclasses.replace(bench.settings(True, None), repeats=1, min_seconds=0.0)
    r = bench.bench_check_cost(cfg, 3, quiet=True)
    assert r["check_cost_setup"]["poses"] == 3
    us = r["check_cost_us_per_cpu"]
    assert all(_positive(us[k]) for k in ("paper", "ours", "ours_fit", "ours_boot"))
    assert r["check_cost_setup"]["boot_replicates"] >= 1
    assert r["check_cost_ours_over_paper"] == pytest.approx(us["ours"] / us["paper"])


def test_bench_of_one_method_runs_the_steps_it_reports():
    """A tiny run of TQL through the engine: the steps it reports are the steps
    it ran (rollouts x horizon), at a finite positive rate."""
    cfg = dataclasses.replace(
        bench.settings(True, None), repeats=1, trials=2, horizon=20,
        rollouts_sparse=6, rollouts_dense=6, grasps=50, poses=2,
    )  # fmt: skip
    from legs_jax.bench import engine

    row = bench.bench_jax_engine("tql", cfg, engine._problem(cfg))
    assert row["rollouts"] == 6 and row["horizon"] == 20
    assert math.isfinite(row["jax"]) and row["jax"] > 0 and row["compile_s"] >= 0


def test_the_one_core_child_gets_one_xla_device():
    """The benchmark sets one XLA device per core in its own process; its one-core
    child must not inherit that (two devices' thread pools on one core slowed
    the samplers there)."""
    from legs_jax.bench import sampler

    flags = "--xla_force_host_platform_device_count=2 --xla_cpu_use_thunk_runtime=true"
    env = sampler._one_device_env({"XLA_FLAGS": flags, "HOME": "/h"})
    assert env == {"XLA_FLAGS": "--xla_cpu_use_thunk_runtime=true", "HOME": "/h"}
    child_env = sampler._one_device_env({**os.environ, "XLA_FLAGS": flags.split()[0]})
    done = subprocess.run(
        [sys.executable, "-c", "import jax; print(jax.device_count())"],
        env=child_env,
        capture_output=True,
        text=True,
        check=True,
    )
    assert done.stdout.split() == ["1"]
