"""The speed benchmark runs and reports every figure (no timing thresholds)."""

from __future__ import annotations

import json
import math
import os
import subprocess
import sys

import pytest

import experiments
from legs_jax import bench

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
    # The human-readable table renders from the same figures.
    table = bench.format_table(r)
    assert "jax.random.beta" in table and "borges_2000" in table
    assert "beta_sampler.beta_rows_v2" in table and "Thompson draw step" in table


def test_projection_adds_up_the_sweep():
    """Minutes = sum over experiments and arms of rollout-steps / rate."""
    rates = {"borges_2000": 1e4, "legs": 1e5, "tql": 2e5, "bayes_ucb_2000": 5e3}
    assert set(rates) == set(bench.table_methods())
    p = bench.projection(rates)
    expected_s = 0.0
    for name in experiments.EXPERIMENTS:
        mod = experiments.get(name)
        n_obj = bench._count_objects(mod.OBJECTS)
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
    assert bench._count_objects(("dexnet_adv", "egad_eval")) == 62
    assert bench._count_objects(("bar_clamp",)) == 1


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
