"""Design study of our stopping bound (issue 23): how often it is a valid lower
bound, and how far below the truth, with the empirical-Bayes prior fitted with
and without the recommended grasp's own outcomes.

    python -m experiments.early_stopping.bound_design --set dexnet_adv
    python -m experiments.early_stopping.bound_design --set egad_eval --rollouts 2

LEGS runs on every object of the set (the shipped problem files), T trials × R
rollouts of H steps, checked every 100 steps; each check records our bound with
the empirical-Bayes prior G_s fitted to every attempted grasp of the pose
(``with-rec``, the design of the previous round) and, on the same rollouts and
the same draws, with G_s fitted without the recommended grasp's own outcomes
(``leave-out``, the shipped design since this study:
:func:`legs_jax.core.stopping.eb_posterior`). A check is valid when the bound is
at most the true performance Σ_s λ_s p[s, π_t(s)]; ground truth enters only this
scoring. The Dex-Net set is the design set, the EGAD set the held-out test. The
results of sweeps (``results/``) use the shipped (leave-out) bound; this study
writes none.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

from experiments.early_stopping.sweep import RHO_MIN  # Fig. 4's thresholds

ROOT = Path(__file__).resolve().parents[2]
VARIANTS = {"with-rec": False, "leave-out": True}


def score(bound: np.ndarray, truth: np.ndarray) -> dict[str, float]:
    """Share of checks with bound ≤ truth, and the mean of (truth − bound)."""
    bound, truth = np.asarray(bound).ravel(), np.asarray(truth).ravel()
    return {
        "valid": float(np.mean(bound <= truth)),
        "below": float(np.mean(truth - bound)),
        "checks": int(bound.size),
    }


def stopping(bound: np.ndarray, truth: np.ndarray, rho: float, horizon: int):
    """Stopping at the first check whose bound reaches ``rho``: (runs stopped,
    share of them whose true performance there is at least ``rho``, mean
    stopping step with H for a run that never stops). Arrays [..., C2], checks
    every 100 steps."""
    b = np.asarray(bound).reshape(-1, np.shape(bound)[-1])
    t = np.asarray(truth).reshape(b.shape)
    hit = b >= rho
    stopped = hit.any(axis=1)
    first = np.argmax(hit, axis=1)
    right = t[np.arange(len(b)), first] >= rho
    steps = np.where(stopped, 100 * (first + 1), horizon)
    share = float(right[stopped].mean()) if stopped.any() else float("nan")
    return int(stopped.sum()), share, float(steps.mean())


def study(set_name: str, trials: int, rollouts: int, horizon: int, progress: bool):
    """Per object and variant: (bound, truth) arrays of every check."""
    from tqdm.auto import tqdm

    from legs_jax.core import engine, problem

    files = sorted((ROOT / "data" / "problemset" / set_name).glob("*.npz"))
    if not files:
        raise SystemExit(f"error: no problem files of set '{set_name}'")
    out = {}
    for i, path in enumerate(tqdm(files, desc=set_name, disable=not progress)):
        pb = problem.load(path)
        batch = problem.stack([pb], num_trials=min(trials, pb.num_trials))
        for name, leave_out in VARIANTS.items():
            r = engine.run(
                batch, "legs", object_ids=[i], num_rollouts=rollouts,
                horizon=horizon, check_every=100, eb_leave_out_rec=leave_out,
                progress=False,
            )  # fmt: skip
            out[(pb.name, name)] = (r.check_p_lower_eb, r.check_true_performance)
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
    ap.add_argument("--json", action="store_true", help="one JSON object")
    ap.add_argument("--quiet", action="store_true", help="no progress bar")
    a = ap.parse_args(argv)
    for n in ("trials", "rollouts", "horizon"):
        if getattr(a, n) < 1:
            ap.error(f"--{n} must be at least 1")
    got = study(a.set, a.trials, a.rollouts, a.horizon, not a.quiet)
    objects = sorted({o for o, _ in got})
    rows = {}
    for name in VARIANTS:
        # [runs, C2] of every object, joined once (score() flattens them)
        bound, truth = (
            np.concatenate(
                [
                    got[(o, name)][k].reshape(-1, got[(o, name)][k].shape[-1])
                    for o in objects
                ]
            )
            for k in (0, 1)
        )
        stops = {rho: stopping(bound, truth, rho, a.horizon) for rho in RHO_MIN}
        rows[name] = {
            **score(bound, truth),
            "stopped_right_min": min(
                (v[1] for v in stops.values() if v[0]), default=float("nan")
            ),
            "stops": {str(r): v for r, v in stops.items()},
            "per_object": {o: score(*got[(o, name)])["valid"] for o in objects},
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
        "of them truly >= rho_min, mean stopping step"
    )
    for rho in RHO_MIN:
        print(f"  rho_min {rho:.2f}: " + "; ".join(
            f"{name} {n} {share:.1%} {step:.0f}"
            for name in VARIANTS
            for n, share, step in [rows[name]["stops"][str(rho)]]
        ))  # fmt: skip
    print("valid per object: " + ", ".join(
        f"{o} {rows['with-rec']['per_object'][o]:.0%} -> "
        f"{rows['leave-out']['per_object'][o]:.0%}" for o in objects
    ))  # fmt: skip
    return 0


if __name__ == "__main__":
    sys.exit(main())
