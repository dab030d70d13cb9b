"""``python -m precompute train-prior``: data and weights of the learned prior.

Stages (each with a progress bar unless ``--quiet``):

1. generate ``--objects`` objects (:mod:`precompute.shapes`, seed ``--seed``);
2. label them in ``--jobs`` processes (:mod:`precompute.trainset`: up to
   ``--poses`` poses each, a reservoir of up to ``--grasps`` antipodal grasps per
   pose, p from ``--samples`` perturbed executions, one noisy depth image per pose);
3. split by object (a seeded permutation: 80 % train, 10 % validation, 10 % test)
   and cut the network's crops (:mod:`precompute.gqcnn`);
4. train (:func:`train`): Adam (learning rate ``--lr``, cosine decay to 5 % of it
   over the run), batches of ``--batch``,
   ``--epochs`` passes; loss: binary cross-entropy of the logit against p as a soft
   label (so the network estimates p itself, not a thresholded p); each example
   turned by 180° with probability 1/2 (the same grasp); the weights of the epoch
   with the lowest validation loss are kept;
5. evaluate on the test objects and write ``weights.npz``, ``metrics.json`` and
   ``MODEL_CARD.md`` into ``--out`` (default: ``runs/prior`` under the current
   folder). The shipped weights (``precompute/prior_weights``) are replaced only
   when told so: ``--out precompute/prior_weights --overwrite``. New weights are
   used by a build only when named: ``python -m precompute ... --prior-weights
   runs/prior/weights.npz``.

Everything is determined by the seed: the objects, the labels, the noise, the
split, the initial weights, the batch order and the turns (JAX on CPU is
deterministic for a fixed program and machine).

Why one file: labelling, training, the model card and the command line describe one
run fixed by one :class:`TrainConfig` and one seed, and the card records the
settings that every other section uses.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import os
import platform
import sys
import time
from pathlib import Path

import numpy as np

from legs_jax._files import git_state

from ._cli import guard_out
from .errors import PrecomputeError
from .gqcnn import Arch, Cropper, init_params, make_model, save_weights
from .shapes import generate
from .trainset import label_shape

__all__ = ["TrainConfig", "QUICK", "default_out", "metrics", "train", "main"]

STREAM_SPLIT = 13
STREAM_INIT = 14


@dataclasses.dataclass(frozen=True)
class TrainConfig:
    """What a training run depends on (the full-scale defaults; see BENCHMARKS.md
    "learned prior" for the sizing)."""

    objects: int = 3000
    grasps: int = 100
    poses: int = 4
    samples: int = 50
    seed: int = 0
    epochs: int = 6
    batch: int = 128
    lr: float = 1e-3

    def check(self) -> TrainConfig:
        for name in ("objects", "grasps", "poses", "samples", "epochs", "batch"):
            if getattr(self, name) < 1:
                raise PrecomputeError(f"--{name} must be at least 1")
        if self.objects < 10:
            raise PrecomputeError("--objects must be at least 10 (train/val/test)")
        if self.seed < 0:
            raise PrecomputeError(f"--seed must be non-negative, got {self.seed}")
        if not self.lr > 0:
            raise PrecomputeError(f"--lr must be positive, got {self.lr}")
        return self


#: ``--quick``: a run of about a minute (the tests use it).
QUICK = TrainConfig(objects=30, grasps=40, poses=2, samples=20, epochs=4, batch=64)


def default_out() -> Path:
    """Where a run writes unless told ``--out``: ``runs/prior`` under the current
    folder (a user's own work, never the shipped weights)."""
    return Path.cwd() / "runs" / "prior"


def shipped_out() -> Path:
    """The folder of the shipped weights (``--out`` there needs ``--overwrite``)."""
    return Path(__file__).resolve().parent / "prior_weights"


# ------------------------------------------------------------------ labelling


def _label_one(args):
    index, cfg = args
    shape = generate(index, cfg.seed)
    ex = label_shape(
        shape,
        seed=cfg.seed,
        grasps=cfg.grasps,
        samples=cfg.samples,
        max_poses=cfg.poses,
    )
    return index, shape.kind, ex


def _worker_init():
    for var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
        os.environ[var] = "1"


def label_all(cfg: TrainConfig, jobs: int, progress: bool):
    """{index: (kind, [PoseExamples])} of every object (no JAX in this stage, so
    that the worker processes can be forked)."""
    from tqdm import tqdm

    work = [(i, cfg) for i in range(cfg.objects)]
    out = {}
    bar = tqdm(total=len(work), desc="label objects", unit="obj", disable=not progress)
    try:
        if jobs <= 1:
            for w in work:
                i, kind, ex = _label_one(w)
                out[i] = (kind, ex)
                bar.update(1)
        else:
            import multiprocessing as mp

            method = "fork" if "fork" in mp.get_all_start_methods() else "spawn"
            if "jax" in sys.modules:  # a started JAX runtime does not survive fork
                method = "spawn"
            with mp.get_context(method).Pool(jobs, initializer=_worker_init) as pool:
                for i, kind, ex in pool.imap_unordered(_label_one, work):
                    out[i] = (kind, ex)
                    bar.update(1)
    finally:
        bar.close()
    return out


def split_objects(n: int, seed: int) -> dict[str, np.ndarray]:
    """Object indices of the train / val / test split (80 / 10 / 10 %)."""
    rng = np.random.Generator(
        np.random.PCG64(np.random.SeedSequence([seed, STREAM_SPLIT]))
    )
    perm = rng.permutation(n)
    k = max(1, n // 10)
    return {
        "test": np.sort(perm[:k]),
        "val": np.sort(perm[k : 2 * k]),
        "train": np.sort(perm[2 * k :]),
    }


def make_arrays(labelled, objects: np.ndarray, progress: bool, desc: str):
    """(x [N, S, S] float16, z [N] float32, p [N] float32, obj [N]) of the objects."""
    from tqdm import tqdm

    cropper = Cropper()
    xs, zs, ps, os_ = [], [], [], []
    for i in tqdm(objects, desc=desc, unit="obj", disable=not progress):
        for ex in labelled[int(i)][1]:
            x, z = cropper(ex.depth_image(), ex.center, ex.axis)
            xs.append(x.astype(np.float16))
            zs.append(z.astype(np.float32))
            ps.append(ex.p)
            os_.append(np.full(len(ex.p), int(i)))
    if not xs:
        raise PrecomputeError(f"no labelled grasps in the {desc.split()[-1]} objects")
    return (
        np.concatenate(xs),
        np.concatenate(zs),
        np.concatenate(ps).astype(np.float32),
        np.concatenate(os_),
    )


# ------------------------------------------------------------------- training


def metrics(q: np.ndarray, p: np.ndarray) -> dict:
    """Loss (binary cross-entropy against p), accuracy and ROC AUC of q for the
    classes p ≥ 0.5 / p < 0.5, Pearson correlation of q and p."""
    from scipy.stats import rankdata

    q = np.asarray(q, np.float64)
    p = np.asarray(p, np.float64)
    qc = np.clip(q, 1e-7, 1 - 1e-7)
    loss = float(-(p * np.log(qc) + (1 - p) * np.log(1 - qc)).mean())
    pos = p >= 0.5
    acc = float(((q >= 0.5) == pos).mean())
    n1, n0 = int(pos.sum()), int((~pos).sum())
    if n1 and n0:
        r = rankdata(q)
        auc = float((r[pos].sum() - n1 * (n1 + 1) / 2) / (n1 * n0))
    else:
        auc = float("nan")
    corr = float(np.corrcoef(q, p)[0, 1]) if q.std() > 0 and p.std() > 0 else 0.0
    return {
        "examples": int(len(p)),
        "positive_share": float(pos.mean()) if len(p) else float("nan"),
        "loss": loss,
        "accuracy": acc,
        "roc_auc": auc,
        "corr_q_p": corr,
    }


def reliability(q: np.ndarray, p: np.ndarray, bins: int = 10) -> dict:
    """Per bin of q (equal widths on [0, 1]): grasps, mean q, mean p and the share
    with p ≥ 0.5 (a reliability diagram's numbers)."""
    q = np.asarray(q, np.float64)
    p = np.asarray(p, np.float64)
    k = np.minimum((q * bins).astype(np.int64), bins - 1)
    rows = []
    for b in range(bins):
        sel = k == b
        n = int(sel.sum())
        rows.append(
            {
                "q_lo": b / bins,
                "q_hi": (b + 1) / bins,
                "grasps": n,
                "mean_q": float(q[sel].mean()) if n else float("nan"),
                "mean_p": float(p[sel].mean()) if n else float("nan"),
                "share_p_ge_0.5": float((p[sel] >= 0.5).mean()) if n else float("nan"),
            }
        )
    return {"bins": rows}


def _reliability_figure(rel: dict, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    rows = [r for r in rel["bins"] if r["grasps"]]
    fig, ax = plt.subplots(figsize=(4.2, 4.0), dpi=100)
    ax.plot([0, 1], [0, 1], color="0.7", lw=1, label="calibrated")
    ax.plot(
        [r["mean_q"] for r in rows], [r["mean_p"] for r in rows], "o-", label="mean p"
    )
    ax.plot(
        [r["mean_q"] for r in rows],
        [r["share_p_ge_0.5"] for r in rows],
        "s--",
        label="share p ≥ 0.5",
    )
    ax.set_xlabel("predicted q (bin mean)")
    ax.set_ylabel("ground truth")
    ax.set_xlim(0, 1)
    ax.set_ylim(0, 1)
    ax.set_title("Learned prior, held-out generated objects", fontsize=9)
    ax.legend(fontsize=8, loc="upper left")
    fig.tight_layout()
    fig.savefig(path, metadata={"Software": None})
    plt.close(fig)


def _predict(apply, params, x, z, batch: int = 1024) -> np.ndarray:
    n = len(x)
    out = np.zeros(n, np.float32)
    for s in range(0, n, batch):
        e = min(n, s + batch)
        xb = np.zeros((batch, *x.shape[1:], 1), np.float32)
        zb = np.zeros((batch, 1), np.float32)
        xb[: e - s, ..., 0] = x[s:e]
        zb[: e - s, 0] = z[s:e]
        out[s:e] = np.asarray(apply(params, xb, zb))[: e - s]
    return 1.0 / (1.0 + np.exp(-out.astype(np.float64)))


def train(cfg: TrainConfig, data: dict, arch=None, progress: bool = True):
    """Train on ``data["train"]``, select on ``data["val"]`` (each (x, z, p, obj)).

    Returns (params, arch, history): history has the validation loss before
    training ("val_loss_init") and after each epoch.
    """
    import jax
    import jax.numpy as jnp
    import optax
    from tqdm import tqdm

    arch = arch or Arch()
    model = make_model(arch)
    ss = np.random.SeedSequence([cfg.seed, STREAM_INIT])
    init_key, turn_key = jax.random.split(jax.random.key(int(ss.generate_state(1)[0])))
    params = init_params(arch, init_key)
    xt, zt, pt, _ = data["train"]
    xv, zv, pv, _ = data["val"]
    n = len(pt)
    B = min(cfg.batch, n)
    steps = n // B
    schedule = optax.cosine_decay_schedule(cfg.lr, cfg.epochs * steps, alpha=0.05)
    tx = optax.adam(schedule)
    opt = tx.init(params)
    apply = jax.jit(model.apply)

    def loss_fn(params, x, z, y):
        return optax.sigmoid_binary_cross_entropy(model.apply(params, x, z), y).mean()

    @jax.jit
    def step(params, opt, x, z, y, key):
        turn = jax.random.bernoulli(key, 0.5, (x.shape[0],))
        x = jnp.where(turn[:, None, None, None], x[:, ::-1, ::-1, :], x)
        value, grads = jax.value_and_grad(loss_fn)(params, x, z, y)
        updates, opt = tx.update(grads, opt, params)
        return optax.apply_updates(params, updates), opt, value

    rng = np.random.Generator(
        np.random.PCG64(np.random.SeedSequence([cfg.seed, STREAM_INIT, 1]))
    )
    history = {"val_loss_init": metrics(_predict(apply, params, xv, zv), pv)["loss"]}
    history["epochs"] = []
    best = (history["val_loss_init"], params, 0)
    bar = tqdm(
        total=cfg.epochs * steps, desc="train", unit="batch", disable=not progress
    )
    start = time.perf_counter()
    try:
        for epoch in range(cfg.epochs):
            order = rng.permutation(n)
            total = 0.0
            for b in range(steps):
                idx = np.sort(order[b * B : (b + 1) * B])
                key = jax.random.fold_in(turn_key, epoch * steps + b)
                params, opt, value = step(
                    params,
                    opt,
                    xt[idx, ..., None].astype(np.float32),
                    zt[idx, None],
                    pt[idx],
                    key,
                )
                total += float(value)
                bar.update(1)
            val = metrics(_predict(apply, params, xv, zv), pv)
            history["epochs"].append(
                {
                    "epoch": epoch + 1,
                    "train_loss": total / max(steps, 1),
                    **{f"val_{k}": v for k, v in val.items() if k != "examples"},
                }
            )
            bar.set_postfix_str(f"val loss {val['loss']:.4f} auc {val['roc_auc']:.3f}")
            if val["loss"] < best[0]:
                best = (val["loss"], params, epoch + 1)
    finally:
        bar.close()
    history["train_seconds"] = time.perf_counter() - start
    history["train_examples_per_s"] = (
        cfg.epochs * steps * B / max(history["train_seconds"], 1e-9)
    )
    history["best_epoch"] = best[2]
    history["val_loss_best"] = best[0]
    return best[1], arch, history


# ----------------------------------------------------------------- model card


def _commit() -> str:
    state = git_state()
    if state["commit"] is None:
        return "unknown (not a git checkout)"
    return state["commit"] + (" (with uncommitted changes)" if state["dirty"] else "")


def _machine() -> str:
    import jax

    cpu = platform.processor() or platform.machine()
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                cpu = line.split(":", 1)[1].strip()
                break
    except OSError:
        pass
    dev = jax.devices()[0]
    return f"{os.cpu_count()} cores, {cpu}; JAX {jax.__version__} on {dev.platform}"


def _card(cfg, arch, nparams, sha, info, m, h, timings, counts) -> str:
    def row(name, d):
        return (
            f"| {name} | {d['examples']} | {d['positive_share']:.3f} | {d['loss']:.4f} "
            f"| {d['accuracy']:.3f} | {d['roc_auc']:.3f} | {d['corr_q_p']:.3f} |"
        )

    t = timings
    return f"""# Learned prior: model card

A small GQ-CNN-style network (`precompute/gqcnn.py`) that estimates the robustness p
of a top-down parallel-jaw grasp from an overhead depth image of the object alone.
Trained only on generated objects (`precompute/shapes.py`), never on the 62
evaluation meshes. Written by `python -m precompute train-prior`; do not edit by hand.

## Data

- Objects: {cfg.objects} generated (seed {cfg.seed}; CSG, convex hulls, blobs in
  turn; EGAD!'s size rule for the 80 mm opening), split by object: {counts["train"]}
  train, {counts["val"]} validation, {counts["test"]} test.
- Labels: up to {cfg.poses} stable poses per object, a reservoir of up to
  {cfg.grasps} antipodal grasps per pose, p from {cfg.samples} perturbed executions
  (the evaluation problems' sampler and perturbation model, `precompute/grasps.py`).
- Examples: {counts["examples"]} labelled grasps ({counts["examples_train"]} train).
- Observation: `precompute/depth.py` (camera 0.7 m above the table, fx = fy = 525 px,
  32 × 32 crops of 4 mm pixels, Dex-Net 2.0's gamma and correlated Gaussian noise).

## Network and training

- Architecture: {arch.to_json()}; {nparams} parameters.
- Loss: binary cross-entropy of the logit against p as a soft label. Adam, learning
  rate {cfg.lr} with cosine decay to 5 %, batch {cfg.batch}, {cfg.epochs} epochs,
  180° turns as augmentation; kept: epoch {h["best_epoch"]} (lowest validation loss
  {h["val_loss_best"]:.4f}; before training {h["val_loss_init"]:.4f}).
- Weights: `weights.npz` (no pickle), SHA-256 `{sha}`.
- Code: commit {info["commit"]}.
- Machine: {info["machine"]}.
- Wall time: {t["total"]:.0f} s in all (shapes and labels {t["label"]:.0f} s,
  {counts["examples"] / max(t["label"], 1e-9):.0f} labelled grasps/s with
  {info["jobs"]} process(es); crops {t["crops"]:.0f} s; training {t["train"]:.0f} s,
  {h["train_examples_per_s"]:.0f} examples/s; evaluation {t["eval"]:.0f} s).

## Held-out metrics (classes: p ≥ 0.5 against the rest; q ≥ 0.5 predicts success)

Reliability diagram of the test objects: `reliability_test.png` (numbers in
`metrics.json`).

| objects | grasps | share p ≥ 0.5 | loss | accuracy | ROC AUC | corr(q, p) |
|---|---|---|---|---|---|---|
{row("train", m["train"])}
{row("validation", m["val"])}
{row("test", m["test"])}

For comparison, Dex-Net 2.0's GQ-CNN: 85.7 % accuracy on held-out synthetic data
(6.7 M examples, 1,500 objects; RSS 2017). The table above is for generated objects;
how the prior does on the evaluation sets is in the problem report.
"""


# ------------------------------------------------------------------------ CLI


def _parser() -> argparse.ArgumentParser:
    d = TrainConfig()
    p = argparse.ArgumentParser(
        prog="python -m precompute train-prior",
        description="Data and weights of the learned prior: generate the training "
        "objects, label them with the evaluation problems' physics, train the "
        "network and write weights.npz, metrics.json, MODEL_CARD.md and "
        "reliability_test.png into --out (default: runs/prior under the current "
        "folder). The shipped weights are used by the builds until others are "
        "named with --prior-weights PATH; replacing them needs "
        "--out precompute/prior_weights --overwrite.",
    )
    p.add_argument("--quick", action="store_true", help="a run of about a minute")
    for name, kind, help_ in [
        ("objects", int, "generated objects"),
        ("grasps", int, "grasps per pose"),
        ("poses", int, "most likely poses per object"),
        ("samples", int, "perturbed executions per grasp"),
        ("seed", int, "seed of everything"),
        ("epochs", int, "training epochs"),
        ("batch", int, "batch size"),
        ("lr", float, "Adam learning rate"),
    ]:
        p.add_argument(
            f"--{name}",
            type=kind,
            default=None,
            help=f"{help_} (default {getattr(d, name)}; --quick: "
            f"{getattr(QUICK, name)})",
        )
    p.add_argument(
        "--out",
        type=Path,
        default=None,
        help="output folder (default: runs/prior under the current folder)",
    )
    p.add_argument(
        "--overwrite",
        action="store_true",
        help="allow --out to be a folder of the repository's committed files (e.g. "
        "precompute/prior_weights, the shipped weights), replacing them",
    )
    p.add_argument("--jobs", type=int, default=None, help="labelling processes")
    p.add_argument("--quiet", action="store_true", help="no progress bars")
    return p


def run(cfg: TrainConfig, out: Path, jobs: int, progress: bool = True) -> dict:
    """The whole pipeline (module docstring); returns metrics.json's content."""
    cfg = cfg.check()
    t0 = time.perf_counter()
    labelled = label_all(cfg, jobs, progress)
    t1 = time.perf_counter()
    split = split_objects(cfg.objects, cfg.seed)
    data = {
        k: make_arrays(labelled, v, progress, f"crops {k}") for k, v in split.items()
    }
    t2 = time.perf_counter()
    params, arch, hist = train(cfg, data, progress=progress)
    t3 = time.perf_counter()
    import jax

    apply = jax.jit(make_model(arch).apply)
    m = {
        k: metrics(_predict(apply, params, x, z), p) for k, (x, z, p, _) in data.items()
    }
    t4 = time.perf_counter()
    nparams = int(sum(np.size(a) for a in jax.tree_util.tree_leaves(params)))
    info = {"commit": _commit(), "machine": _machine(), "jobs": jobs}
    counts = {k: len(v) for k, v in split.items()}
    counts["examples"] = int(sum(len(d[2]) for d in data.values()))
    counts["examples_train"] = int(len(data["train"][2]))
    timings = {
        "label": t1 - t0,
        "crops": t2 - t1,
        "train": t3 - t2,
        "eval": t4 - t3,
        "total": t4 - t0,
    }
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    sha = save_weights(
        out / "weights.npz",
        params,
        arch,
        {"config": dataclasses.asdict(cfg), "best_epoch": hist["best_epoch"]},
    )
    result = {
        "config": dataclasses.asdict(cfg),
        "arch": json.loads(arch.to_json()),
        "parameters": nparams,
        "weights_sha256": sha,
        "split_objects": counts,
        "kinds": {
            k: sum(1 for v in labelled.values() if v[0] == k)
            for k in ("csg", "hull", "blob")
        },
        "metrics": m,
        "history": hist,
        "timings_s": timings,
        **info,
    }
    q_test = _predict(apply, params, data["test"][0], data["test"][1])
    result["reliability_test"] = reliability(q_test, data["test"][2])
    _reliability_figure(result["reliability_test"], out / "reliability_test.png")
    (out / "metrics.json").write_text(
        json.dumps(result, indent=1, sort_keys=True) + "\n"
    )
    (out / "MODEL_CARD.md").write_text(
        _card(cfg, arch, nparams, sha, info, m, hist, timings, counts)
    )
    return result


def main(argv=None) -> int:
    a = _parser().parse_args(argv)
    base = QUICK if a.quick else TrainConfig()
    over = {
        k: getattr(a, k)
        for k in (
            "objects",
            "grasps",
            "poses",
            "samples",
            "seed",
            "epochs",
            "batch",
            "lr",
        )
        if getattr(a, k) is not None
    }
    cfg = dataclasses.replace(base, **over).check()
    if a.jobs is not None and a.jobs < 1:
        raise PrecomputeError(f"--jobs must be at least 1, got {a.jobs}")
    jobs = a.jobs if a.jobs is not None else (os.cpu_count() or 1)
    out = a.out if a.out is not None else default_out()
    _guard(out, a.overwrite)
    r = run(cfg, out, jobs, progress=not a.quiet)
    m = r["metrics"]["test"]
    print(
        f"test objects: accuracy {m['accuracy']:.3f}, ROC AUC {m['roc_auc']:.3f}, "
        f"loss {m['loss']:.4f} (validation loss {r['history']['val_loss_init']:.4f} "
        f"-> {r['history']['val_loss_best']:.4f}); {r['timings_s']['total']:.0f} s "
        f"-> {out}"
    )
    print(f"wrote {out / 'weights.npz'}, metrics.json, MODEL_CARD.md")
    if Path(out).resolve() != shipped_out().resolve():
        print(
            "builds use these weights only when named: python -m precompute ... "
            f"--prior-weights {out / 'weights.npz'}"
        )
    return 0


def _guard(out: Path, overwrite: bool) -> None:
    """Refuse to replace the shipped weights (or any committed file) unless
    ``overwrite``."""
    shipped = shipped_out()
    if not overwrite and Path(out).resolve() == shipped.resolve():
        if (shipped / "weights.npz").exists():
            raise PrecomputeError(
                f"{out} holds the shipped weights of the learned prior: pass "
                "--overwrite to replace them, or leave --out out (default runs/prior)"
            )
    guard_out(out, overwrite)
