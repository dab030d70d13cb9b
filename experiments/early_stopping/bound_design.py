"""Design study of our stopping bound: how often it is a valid lower
bound, and how far below the truth, for three fits of the empirical-Bayes prior.

    python -m experiments.early_stopping.bound_design --set dexnet_adv
    python -m experiments.early_stopping.bound_design --set egad_eval --rollouts 2

LEGS runs on every object of the set (the shipped problem files), T trials × R
rollouts of H steps, checked every 100 steps; on the same rollouts and the same
draws each check records our bound with the prior G_s fitted

- ``with-rec``: to every attempted grasp of the pose, from the uniform histogram
  (the first design);
- ``leave-out``: without the recommended grasp's own outcomes, from the uniform
  histogram (the second);
- ``pooled``: without them, from the pose's pooled success rate (the shipped
  design: :func:`legs_jax.core.stopping.eb_posterior`);
- ``boot-R``: as ``pooled``, averaged over R Bayesian-bootstrap fits of G_s
  (:func:`legs_jax.core.stopping.bootstrap_posterior`; ``--variants`` picks R).

The oracle stops each run at its first check whose true performance is at least
ρ_min; the study prints each variant's mean stopping step over the oracle's.

A check is valid when the bound is at most the true performance
Σ_s λ_s p[s, π_t(s)]; ground truth enters only this scoring. Both sets have been
looked at while designing. The results of sweeps (``results/``) use the shipped
bound; this study writes none.
"""

from __future__ import annotations

import argparse
import json
import sys
from collections.abc import Sequence
from pathlib import Path

import numpy as np
import pandas as pd

from experiments.early_stopping.sweep import RHO_MIN  # Fig. 4's thresholds
from legs_jax.core import problem
from legs_jax.report import analysis as an

ROOT = Path(__file__).resolve().parents[2]
# name -> (G_s fitted without the recommended grasp, where the fit starts,
# Bayesian-bootstrap replicates of the fit: 0 for the plug-in fit)
VARIANTS = {
    "with-rec": (False, "uniform", 0),
    "leave-out": (True, "uniform", 0),
    "pooled": (True, "pooled", 0),
}


def variant(name: str) -> tuple[bool, str, int]:
    """A variant's settings: one of ``VARIANTS`` or ``boot-R`` (R >= 1)."""
    if name in VARIANTS:
        return VARIANTS[name]
    head, _, r = name.partition("-")
    if head == "boot" and r.isdigit() and int(r) >= 1:
        return (True, "pooled", int(r))
    raise ValueError(
        f"unknown variant '{name}' (one of {', '.join(VARIANTS)} or boot-R, R >= 1)"
    )


def checks_frame(
    obj: str, bound: np.ndarray, truth: np.ndarray, steps: np.ndarray
) -> pd.DataFrame:
    """The checks of one object as the report reads them (one row per check:
    object, trial, rollout, step, ``p_lower_eb``, true_performance), so that
    the study scores them with the report's own :func:`bound_summary` and
    :func:`stopping_sensitivity`. ``bound``, ``truth``: [..., R, C2] (runs of
    one object; the leading axes are its trials) at the check ``steps`` [C2]."""
    bound = np.asarray(bound, np.float64)
    bound = bound.reshape((-1,) + bound.shape[-2:])
    T, R, C = bound.shape
    t, r, c = np.meshgrid(np.arange(T), np.arange(R), np.arange(C), indexing="ij")
    return pd.DataFrame(
        dict(
            object=obj,
            trial=t.ravel(),
            rollout=r.ravel(),
            step=np.asarray(steps)[c.ravel()],
            p_lower_eb=bound.ravel(),
            true_performance=np.asarray(truth, np.float64).ravel(),
        )
    )


def study(
    set_name: str,
    trials: int,
    rollouts: int,
    horizon: int,
    progress: bool,
    variants: Sequence[str] = tuple(VARIANTS),
    save: Path | None = None,
):
    """Per object and variant: the checks (:func:`checks_frame`). With ``save``,
    each object's checks are written to ``save/<set>/<variant>/<object>.parquet``
    as soon as they are computed, and read back instead of recomputed when they
    are there (an interrupted study resumes; the files do not record the sizes:
    use one folder per study)."""
    import jax
    from tqdm.auto import tqdm

    from legs_jax import runtime  # jax: only when the study runs, not for --help

    files = sorted((ROOT / "data" / "problemset" / set_name).glob("*.npz"))
    if not files:
        raise SystemExit(f"error: no problem files of set '{set_name}'")
    out = {}
    for i, path in enumerate(tqdm(files, desc=set_name, disable=not progress)):
        pb = None
        for name in variants:
            kept = (
                None
                if save is None
                else save / set_name / name / f"{path.stem}.parquet"
            )
            if kept is not None and kept.exists():
                out[(path.stem, name)] = pd.read_parquet(kept)
                continue
            if pb is None:
                pb = problem.load(path)
                batch = problem.stack([pb], num_trials=min(trials, pb.num_trials))
            leave_out, start, replicates = variant(name)
            r = runtime.run(
                batch, "legs", object_ids=[i], num_rollouts=rollouts,
                horizon=horizon, check_every=100, eb_leave_out_rec=leave_out,
                eb_fit_start=start, eb_replicates=replicates, progress=False,
            )  # fmt: skip
            out[(path.stem, name)] = checks_frame(
                pb.name, r.check_p_lower_eb, r.check_true_performance, r.check_steps
            )
            if kept is not None:
                kept.parent.mkdir(parents=True, exist_ok=True)
                out[(path.stem, name)].to_parquet(kept, index=False)
        # each object's shapes compile anew: drop the programs of the last one.
        # (Even so, the compiler's code mappings grow: on EGAD a process has
        # aborted after about 26 objects of three variants. With ``save`` a
        # rerun of the same command resumes where it stopped.)
        jax.clear_caches()
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(
        prog="python -m experiments.early_stopping.bound_design",
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    ap.add_argument("--set", default="dexnet_adv", choices=["dexnet_adv", "egad_eval"])
    ap.add_argument("--trials", type=int, default=10, help="trials T (10)")
    ap.add_argument("--rollouts", type=int, default=2, help="rollouts R (2)")
    ap.add_argument("--horizon", type=int, default=3000, help="steps H (3000)")
    ap.add_argument(
        "--variants",
        default=",".join(VARIANTS),
        help="comma-separated variants: " + ", ".join(VARIANTS) + " or boot-R "
        f"(default {','.join(VARIANTS)})",
    )
    ap.add_argument(
        "--save",
        type=Path,
        default=None,
        metavar="DIR",
        help="keep each object's checks in DIR/<set>/<variant>/<object>.parquet "
        "(a rerun with the same DIR resumes from them)",
    )
    ap.add_argument("--json", action="store_true", help="one JSON object")
    ap.add_argument("--quiet", action="store_true", help="no progress bar")
    a = ap.parse_args(argv)
    for n in ("trials", "rollouts", "horizon"):
        if getattr(a, n) < 1:
            ap.error(f"--{n} must be at least 1")
    names = [v.strip() for v in a.variants.split(",") if v.strip()]
    try:
        for name in names:
            variant(name)
    except ValueError as e:
        ap.error(str(e))
    got = study(a.set, a.trials, a.rollouts, a.horizon, not a.quiet, names, a.save)
    objects = sorted({o for o, _ in got})
    truth = pd.concat([got[(o, names[0])] for o in objects], ignore_index=True)
    oracle = an.stopping_sensitivity(
        truth.assign(p_lower_eb=truth["true_performance"]), RHO_MIN, a.horizon
    )
    oracle_step = dict(zip(RHO_MIN, oracle["mean_stop_step"], strict=True))
    rows = {}
    for name in names:
        checks = pd.concat([got[(o, name)] for o in objects], ignore_index=True)
        pooled = an.bound_summary(checks).iloc[0]
        per_object = an.bound_summary(checks, by_object=True)
        sens = an.stopping_sensitivity(checks, RHO_MIN, a.horizon)
        stops = {
            rho: (
                int(x.n_stopped),
                float(x.accuracy),
                float(x.mean_stop_step),
                float(x.mean_stop_step) / oracle_step[rho],
            )
            for rho, x in zip(RHO_MIN, sens.itertuples(), strict=True)
        }
        rows[name] = {
            "valid": float(pooled["accuracy"]),
            "below": float(pooled["tightness"]),
            "checks": int(pooled["n_checks"]),
            "stopped_right_min": min(
                (v[1] for v in stops.values() if v[0]), default=float("nan")
            ),
            "stops": {str(r): v for r, v in stops.items()},
            "per_object": dict(
                zip(per_object["object"], per_object["accuracy"], strict=True)
            ),
        }
    if a.json:
        print(json.dumps({"set": a.set, **vars(a), "variants": rows}))
        return 0
    print(f"{a.set}: LEGS, {a.trials} trials x {a.rollouts} rollouts, H = {a.horizon}")
    print(f"{'variant':<10} {'checks':>7} {'valid':>7} {'truth - bound':>14}")
    for name, r in rows.items():
        print(f"{name:<10} {r['checks']:>7} {r['valid']:>7.1%} {r['below']:>14.4f}")
    print(
        "stopping at the first check with bound >= rho_min: runs stopped, share "
        "of them truly >= rho_min, mean stopping step (over the oracle's)"
    )
    for rho in RHO_MIN:
        print(f"  rho_min {rho:.2f}: " + "; ".join(
            f"{name} {n} {share:.1%} {step:.0f} ({ratio:.2f}x)"
            for name in names
            for n, share, step, ratio in [rows[name]["stops"][str(rho)]]
        ))  # fmt: skip
    print("valid per object (" + " -> ".join(names) + "): " + ", ".join(
        f"{o} " + " -> ".join(f"{rows[n]['per_object'][o]:.0%}" for n in names)
        for o in objects
    ))  # fmt: skip
    return 0


if __name__ == "__main__":
    sys.exit(main())
