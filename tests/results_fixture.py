"""A small, plausible results directory for the figure and analysis tests.

``make_results(root)`` writes every experiment folder a full sweep writes
(``main``, ``case_study``, ``early_stopping``, ``prior_strength``, ``confidence``)
in the exact format of ``legs_jax.results``: fake engine results of the engine's
shapes go through ``chunk_tables``, ``write_chunk`` and ``merge_chunks``, as in a
real sweep, so the tables carry the real columns and dtypes. Values are random but
shaped like real ones: gaps that fall with the steps towards a per-method level,
lower bounds mostly below the true performance, LEGS active sets whose members
improve over time. Nothing here runs the engine; everything is seeded.

``make_data(root)`` writes meshes and problem files for the case-study objects
under ``root/meshes/<set>/`` and ``root/problems/<set>/`` (one object is left
without a problem file and one without a mesh, to exercise the fallbacks).
"""

from __future__ import annotations

import dataclasses
import json
import tempfile
import zlib
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pandas as pd

import experiments
from legs_jax import results as res
from legs_jax import synthetic
from legs_jax.core import problem as problem_mod
from legs_jax.sweep.store import _grasps_table

DEXNET = ("bar_clamp", "climbing_hold", "pawn", "turbine_housing")
EGAD = ("A0", "C3", "F6")
CASE = ("climbing_hold", "C3", "F6", "turbine_housing")
SET_OF = {**{o: "dexnet_adv" for o in DEXNET}, **{o: "egad_eval" for o in EGAD}}
OBJECT_ID = {o: i for i, o in enumerate(DEXNET + EGAD)}
ARMS = experiments.get("main").ARMS
# Typical final gap of each arm (roughly the paper's Table I).
LEVEL = {
    ("dexnet", ""): 0.55,
    ("k100_ub", ""): 0.09,
    ("borges_100", ""): 0.15,
    ("borges_2000", ""): 0.08,
    ("borges_2000", "orig_prior"): 0.11,
    ("legs_no_as", ""): 0.22,
    ("legs", ""): 0.06,
    ("tql", ""): 0.26,
    ("bayes_ucb_100", ""): 0.14,
    ("bayes_ucb_2000", ""): 0.07,
    ("pooled_ucb", ""): 0.13,
}
DEFAULTS = dict(
    s=1.0, prior_offset=1.0, delta=0.05, gamma=0.2, k=100, n=100, epsilon=0.1, eta=0.1
)
RHO_MIN = experiments.get("early_stopping").RHO_MIN

T, R, H = 2, 3, 600
RECORD_EVERY, CHECK_EVERY = 10, 100
P, K, K_ACTIVE = 3, 60, 8


def _rng(*key: int) -> np.random.Generator:
    return np.random.default_rng(np.random.SeedSequence([int(k) for k in key]))


def fixture_problem(name: str) -> problem_mod.Problem:
    """The problem of one fixture object: synthetic, with rotated poses."""
    pb = synthetic.make_problem(
        seed=OBJECT_ID[name], num_poses=P, num_grasps=K, num_trials=T, name=name
    )
    rng = _rng(OBJECT_ID[name], 7)
    tf = np.tile(np.eye(4), (P, 1, 1))
    for s in range(P):
        a, b = rng.uniform(0, np.pi, 2)
        rx = np.array(
            [[1, 0, 0], [0, np.cos(a), -np.sin(a)], [0, np.sin(a), np.cos(a)]]
        )
        rz = np.array(
            [[np.cos(b), -np.sin(b), 0], [np.sin(b), np.cos(b), 0], [0, 0, 1]]
        )
        tf[s, :3, :3] = rz @ rx
        tf[s, 2, 3] = 0.02
    meta = {**pb.meta, "set": SET_OF[name]}
    return dataclasses.replace(pb, pose_transform=tf.astype(np.float32), meta=meta)


def _fake_result(arm, objects, grid, seed):
    """Engine-shaped arrays [G, O, T, R, ...] for one arm."""
    method, variant, _ = arm
    G, O = len(grid), len(objects)  # noqa: E741
    curve_steps = np.arange(0, H + 1, RECORD_EVERY)
    check_steps = np.arange(CHECK_EVERY, H + 1, CHECK_EVERY)
    gap = np.zeros((G, O, T, R, len(curve_steps)))
    true_perf = np.zeros((G, O, T, R, len(check_steps)))
    p_lower = np.zeros_like(true_perf)
    p_att = np.zeros_like(true_perf)
    p_eb = np.full_like(true_perf, np.nan)  # our bound: Beta-posterior methods
    for o, name in enumerate(objects):
        orng = _rng(seed, OBJECT_ID[name])
        scale = orng.uniform(0.5, 1.5)
        p_total = orng.uniform(0.6, 0.95)
        for g, hp in enumerate(grid):
            rng = _rng(
                seed, OBJECT_ID[name], zlib.crc32(f"{method}.{variant}".encode()), g
            )
            # Hyperparameters move the level a little (appendix sweeps).
            shift = 0.04 * abs(hp["s"] - 1.0) / 5 + 0.3 * abs(hp["delta"] - 0.05)
            for t in range(T):
                start = min(0.95, LEVEL[("dexnet", "")] * scale + rng.normal(0, 0.03))
                level = LEVEL[(method, variant)] * scale + shift
                if method in ("dexnet", "k100_ub"):
                    const = min(0.95, max(0.0, level + rng.normal(0, 0.02)))
                    gap[g, o, t] = const
                    continue
                for r in range(R):
                    final = min(0.9, max(0.0, level + rng.normal(0, 0.04)))
                    tau = rng.uniform(100, 300)
                    curve = final + (start - final) * np.exp(-curve_steps / tau)
                    curve += rng.normal(0, 0.01, curve.shape)
                    gap[g, o, t, r] = np.clip(curve, 0.0, 1.0)
            # Dirichlet checks at multiples of CHECK_EVERY.
            at = gap[g, o][..., check_steps // RECORD_EVERY]  # [T, R, C2]
            tp = np.clip(p_total - at, 0.0, 1.0)
            true_perf[g, o] = tp
            p_lower[g, o] = tp - 0.03 + rng.normal(0, 0.02, tp.shape)
            p_att[g, o] = p_lower[g, o] - np.abs(rng.normal(0.02, 0.02, tp.shape))
            if method != "tql":
                erng = _rng(seed, OBJECT_ID[name], 23, g)  # apart from the others
                p_eb[g, o] = tp - 0.04 + erng.normal(0, 0.02, tp.shape)
    final_gap = gap[..., -1]
    rng = _rng(seed, 99)
    counts = rng.integers(100, H, size=final_gap.shape)
    return SimpleNamespace(
        final_gap=final_gap,
        final_performance=np.clip(0.8 - final_gap, 0, 1),
        successes=counts,
        distinct_grasps=rng.integers(10, 300, size=final_gap.shape),
        replacements=rng.integers(0, 200, size=final_gap.shape),
        curve_steps=curve_steps,
        gap_curve=gap.astype(np.float32),
        check_steps=check_steps,
        check_p_lower=p_lower,
        check_p_lower_attempted=p_att,
        check_true_performance=true_perf,
        active_set=None,
        check_p_lower_eb=p_eb,
    )


def _active_sets(objects, robustness, prior, seed):
    """LEGS active sets [1, O, T, R, C2, P, k]: top-k by prior, low members replaced
    by the next grasps by prior at every check; pose 2 unvisited until step 300."""
    c2 = H // CHECK_EVERY
    out = np.full((1, len(objects), T, R, c2, P, K_ACTIVE), -1, np.int64)
    for o in range(len(objects)):
        for t in range(T):
            for s in range(P):
                order = list(np.argsort(-prior[o, t, s], kind="stable"))
                active, queue = order[:K_ACTIVE], order[K_ACTIVE:]
                rng = _rng(seed, o, t, s)
                for c in range(c2):
                    if s == 2 and c < 2:
                        continue
                    out[0, o, t, :, c, s] = active
                    for i, a in enumerate(active):
                        weak = robustness[o, t, s, a] < 0.3
                        if weak and queue and rng.random() < 0.7:
                            active[i] = queue.pop(0)
    return out


def _write_experiment(root: Path, name: str, arms, objects, *, checks, active, seed):
    d = root / name
    chunks = d / "chunks"
    problems = [fixture_problem(o) for o in objects]
    robustness = np.stack([p.robustness for p in problems])  # [O, T, P, K]
    prior = np.stack([p.prior for p in problems])
    ids = []
    for arm in arms:
        method, variant, hp = arm
        keys = list(hp)
        g = max([len(v) for v in hp.values() if isinstance(v, tuple)] or [1])
        grid = []
        for i in range(g):
            point = dict(DEFAULTS)
            for k in keys:
                point[k] = hp[k][i] if isinstance(hp[k], tuple) else hp[k]
            grid.append(point)
        result = _fake_result(arm, objects, grid, seed)
        record_act = active and method == "legs"
        if record_act:
            result.active_set = _active_sets(objects, robustness, prior, seed)
        ctx = res.ChunkContext(
            experiment=name,
            method=method,
            variant=variant,
            grid=grid,
            objects=[(o, SET_OF[o]) for o in objects],
            trials=range(T),
            rollouts=range(R),
            seed=seed,
            horizon=H,
            record_checks=checks and method == "legs",
            record_active_set=record_act,
            robustness=robustness,
        )
        cid = f"{method}.{variant or 'default'}"
        meta = {"curve_steps": [int(s) for s in result.curve_steps], "rollouts": 1}
        res.write_chunk(chunks, cid, res.chunk_tables(result, ctx), meta)
        ids.append(cid)
    tables = res.merge_chunks(chunks, ids, [(a[0], a[1]) for a in arms], list(objects))
    for t, df in tables.items():
        res.atomic_write_parquet(df, d / f"{t}.parquet")
    res.atomic_write_parquet(
        pd.DataFrame(
            {
                "object": list(objects),
                "set": [SET_OF[o] for o in objects],
                "object_id": np.array([OBJECT_ID[o] for o in objects], np.int64),
                "num_poses": np.full(len(objects), P, np.int64),
                "num_grasps": np.full(len(objects), K, np.int64),
                # Where the sweep that made them found its problem files: a folder
                # that does not exist here (the figures then use <data>/problems).
                "problem_file": [
                    str(root / "elsewhere" / SET_OF[o] / f"{o}.npz") for o in objects
                ],
                "sha256": ["0" * 64] * len(objects),
            }
        ),
        d / "objects.parquet",
    )
    if active:
        # The reservoirs' table as the sweep writes it, from the problem files.
        with tempfile.TemporaryDirectory() as tmp:
            entries = []
            for o, pb in zip(objects, problems, strict=True):
                path = problem_mod.save(pb, Path(tmp) / f"{o}.npz")
                entries.append(SimpleNamespace(name=o, path=path))
            grasps = _grasps_table(SimpleNamespace(objects=entries))
        res.atomic_write_parquet(grasps, d / "grasps.parquet")
    manifest = {
        "experiment": name,
        "status": "complete",
        "config": {
            "experiment": name,
            "horizon": H,
            "trials": T,
            "rollouts": R,
            "record_every": RECORD_EVERY,
            "check_every": CHECK_EVERY,
            "seed": seed,
        },
        "config_hash": "f" * 64,
        "git": {"commit": "0" * 40, "dirty": False},
        "extra": {"rho_min": list(RHO_MIN) if name == "early_stopping" else []},
        # the fixture's problems carry a prior made from p, as the synthetic one
        "priors": ["synthetic"],
    }
    res.atomic_write_json(manifest, d / "manifest.json")


def write_experiment(
    root: str | Path,
    name: str,
    arms,
    objects,
    *,
    checks: bool = True,
    active: bool = False,
    seed: int = 0,
) -> Path:
    """One experiment folder ``root/name`` of the given arms (a grid: tuples of
    values, zipped) on the given objects; returns ``root``."""
    _write_experiment(
        Path(root), name, arms, objects, checks=checks, active=active, seed=seed
    )
    return Path(root)


def make_results(root: str | Path, seed: int = 0) -> Path:
    """Write the experiment folders under ``root``; returns ``root``."""
    root = Path(root)
    legs = [a for a in ARMS if a[0] == "legs"]
    _write_experiment(
        root, "main", ARMS, DEXNET + EGAD, checks=True, active=False, seed=seed
    )
    _write_experiment(
        root,
        "case_study",
        [a for a in ARMS if a[1] == ""],
        CASE,
        checks=True,
        active=True,
        seed=seed + 1,
    )
    _write_experiment(
        root, "early_stopping", legs, DEXNET, checks=True, active=False, seed=seed
    )
    # The appendix grids as their experiments declare them (LEGS on the bar clamp).
    for i, name in enumerate(("prior_strength", "confidence")):
        decl = experiments.get(name)
        _write_experiment(
            root,
            name,
            decl.ARMS,
            decl.OBJECTS,
            checks=False,
            active=False,
            seed=seed + 2 + i,
        )
    # The Dex-Net rows with the other prior: main's arms of the paper's methods.
    _write_experiment(
        root,
        "prior_synthetic",
        experiments.get("prior_synthetic").ARMS,
        DEXNET,
        checks=True,
        active=False,
        seed=seed + 4,
    )
    return root


def make_data(root: str | Path) -> Path:
    """Meshes and problem files of the case-study objects under ``root``.

    turbine_housing has a mesh but no problem file; F6 has a problem file but no
    mesh.
    """
    import trimesh

    root = Path(root)
    shapes = {
        "climbing_hold": trimesh.creation.icosphere(subdivisions=2, radius=0.03),
        "C3": trimesh.creation.box(extents=(60.0, 40.0, 25.0)),  # millimetres
        "turbine_housing": trimesh.creation.cylinder(radius=0.025, height=0.06),
    }
    for name, mesh in shapes.items():
        path = root / "meshes" / SET_OF[name] / f"{name}.obj"
        path.parent.mkdir(parents=True, exist_ok=True)
        mesh.export(path)
    for name in ("climbing_hold", "C3", "F6"):
        path = root / "problems" / SET_OF[name] / f"{name}.npz"
        path.parent.mkdir(parents=True, exist_ok=True)
        problem_mod.save(fixture_problem(name), path)
    return root


if __name__ == "__main__":  # pragma: no cover - manual use
    import sys

    out = Path(sys.argv[1] if len(sys.argv) > 1 else "fixture_results")
    make_results(out / "results")
    make_data(out / "data")
    print(json.dumps({"results": str(out / "results"), "data": str(out / "data")}))
