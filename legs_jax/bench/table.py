"""The benchmark's result as a table for people."""

from __future__ import annotations

from typing import Any

from legs_jax.bench.common import table_methods


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
        xla = r.get("sampler_compiler_options") or {}
        if xla:
            lines.append(
                "  (old and new compiled as the engine compiles its simulations: "
                + ", ".join(f"{k}={val}" for k, val in sorted(xla.items()))
                + ")"
            )
        labels = [
            ("old", f"old  sampling.beta_rows ({v['old']})"),
            ("new", f"new  beta_sampler.beta_rows_v2 ({v['new']})"),
        ]
        if "sampler_new_default_samples_per_cpu_s" in r:
            labels.append(("new_default", "new, compiled with XLA's defaults"))
        for key, label in (*labels, ("numpy", "numpy Generator.beta")):
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
        if "one_core_sampler_new_samples_per_cpu_s" in r:
            one = {
                k[len("one_core_") :]: v
                for k, v in r.items()
                if k.startswith("one_core_")
            }
            lines.append(
                "  held to one core (all three on the same core): old "
                f"{_fmt_rate(one['sampler_old_samples_per_cpu_s'])}/s, new "
                f"{_fmt_rate(one['sampler_new_samples_per_cpu_s'])}/s, numpy "
                f"{_fmt_rate(one['sampler_numpy_samples_per_cpu_s'])}/s: new/numpy "
                f"{one['sampler_new_over_numpy_per_cpu_s']:.2f}x, old/numpy "
                f"{one['sampler_old_over_numpy_per_cpu_s']:.2f}x; Thompson step "
                f"new/old {one['thompson_step_new_over_old_per_cpu_s']:.2f}x"
            )
            if "sampler_new_default_over_numpy_per_cpu_s" in one:
                lines.append(
                    "  held to one core, new compiled with XLA's defaults: "
                    f"{_fmt_rate(one['sampler_new_default_samples_per_cpu_s'])}/s, "
                    "new/numpy "
                    f"{one['sampler_new_default_over_numpy_per_cpu_s']:.2f}x"
                )
        if "one_core_harder_sampler_new_over_numpy_per_cpu_s" in r:
            lines.append(
                "  held to one core, the shapes of BORGES's original prior "
                "(alpha = 5q + s, beta = 5(1 - q) + f; "
                f"{100 * r['one_core_harder_retry_fraction']:.1f} % retried): new "
                f"{_fmt_rate(r['one_core_harder_sampler_new_samples_per_cpu_s'])}/s, "
                "numpy "
                f"{_fmt_rate(r['one_core_harder_sampler_numpy_samples_per_cpu_s'])}/s: "
                "new/numpy "
                f"{r['one_core_harder_sampler_new_over_numpy_per_cpu_s']:.2f}x"
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
    if "check_cost_us_per_cpu" in r:
        lines += ["", *_check_lines(r)]
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


def _check_lines(r: dict[str, Any]) -> list[str]:
    """The stopping checks: each bound alone, and LEGS with and without them."""
    st = r["check_cost_setup"]
    us = r["check_cost_us_per_cpu"]
    added = r["legs_checks_added_us_per_check"]
    steps = r["legs_checks_steps_per_cpu_s"]
    return [
        f"Stopping checks (same shapes: {st['rows']} rollouts, P={st['poses']}, "
        f"{st['slots']} slots a pose, M={st['M']}, ours M'={st['M_ours']}; CPU "
        "microseconds per check of one rollout, timed in turns)",
        f"  the paper's bound alone {us['paper']:8.0f} us",
        f"  ours alone              {us['ours']:8.0f} us "
        f"({r['check_cost_ours_over_paper']:.2f}x the paper's; its fit "
        f"{us['ours_fit']:.0f} us)",
        *(
            [
                f"  ours, fit bootstrapped ({st['boot_replicates']} replicates) "
                f"{us['ours_boot']:8.0f} us ({us['ours_boot'] / us['paper']:.2f}x "
                "the paper's)"
            ]
            if "ours_boot" in us
            else []
        ),
        f"  LEGS ({r['legs_checks_rollouts']} rollouts): "
        f"{_fmt_rate(steps['none'])} steps/cpu-s without checks, "
        f"{_fmt_rate(steps['paper'])} with the paper's bound, "
        f"{_fmt_rate(steps['both'])} with both "
        f"({r['legs_checks_both_over_none']:.2f}x the time without)",
        f"  a check adds: the paper's bound {added['paper']:.0f} us, ours beside it "
        f"(the same Dirichlet draws) {added['ours']:.0f} us",
        *(
            [
                f"  with ours bootstrapped: {_fmt_rate(steps['both_boot'])} "
                f"steps/cpu-s; ours adds {added['ours_boot']:.0f} us a check"
            ]
            if "ours_boot" in added
            else []
        ),
    ]
