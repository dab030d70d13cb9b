"""The sweep command end to end with the real engine, in subprocesses.

- ``--smoke`` runs every experiment and writes the documented tables.
- A sweep killed with SIGKILL after its first chunk, then resumed, gives the same
  bytes as an uninterrupted one.
- Ctrl-C stops cleanly and says what was kept.
- The jax.distributed code path (one process; two processes on this host in a slow
  test) gives the same bytes as a plain run.
- Four forced CPU devices give the same bytes as one (slow: it compiles the
  sharded programs).
"""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pandas as pd
import pytest
from helpers import run_module

import experiments

pytest.importorskip("legs_jax.core.engine")

ROOT = Path(__file__).resolve().parent.parent


def _env(devices: int | None = None) -> dict[str, str]:
    env = dict(os.environ)
    flags = [
        f
        for f in env.get("XLA_FLAGS", "").split()
        if "xla_force_host_platform_device_count" not in f
    ]
    if devices:
        flags.append(f"--xla_force_host_platform_device_count={devices}")
    env["XLA_FLAGS"] = " ".join(flags)
    env["JAX_PLATFORMS"] = "cpu"
    return env


def _sweep(args, env, timeout=300) -> subprocess.CompletedProcess:
    return run_module("legs_jax.sweep", args, cwd=ROOT, env=env, timeout=timeout)


def _tables(folder: Path) -> dict[str, bytes]:
    """Every merged result file's bytes (chunk folders and manifests excluded;
    objects.parquet without its problem-file paths, which name the folder)."""
    out = {}
    for p in sorted(folder.rglob("*.parquet")):
        if "chunks" in p.parts:
            continue
        key = p.relative_to(folder).as_posix()
        if p.name == "objects.parquet":
            df = pd.read_parquet(p).drop(columns="problem_file")
            out[key] = df.to_json().encode()
        else:
            out[key] = p.read_bytes()
    return out


def _finished(chunks: Path) -> list[str]:
    """Names of the finished chunk folders (not the temporary ones)."""
    if not chunks.is_dir():
        return []
    return sorted(
        d.name
        for d in chunks.iterdir()
        if not d.name.startswith(".") and (d / "chunk.json").is_file()
    )


def _smoke_checks(folder: Path, methods: set[str] | None) -> None:
    """What every experiment of a smoke run wrote: complete manifests, runs at
    the smoke's sizes, curves whose last point is the runs' mean final gap, checks
    at the check steps; ``methods``: the methods that ran (None: all declared)."""
    names = list(experiments.EXPERIMENTS)
    assert "prior_synthetic" in names and "regimes" in names and len(names) == 7
    assert sorted(d.name for d in folder.iterdir() if d.name[0] != "_") == sorted(names)
    for name in names:
        d = folder / name
        man = json.loads((d / "manifest.json").read_text())
        assert man["status"] == "complete" and man["config"]["smoke"] is True
        runs = pd.read_parquet(d / "runs.parquet")
        curves = pd.read_parquet(d / "curves.parquet")
        checks = pd.read_parquet(d / "checks.parquet")
        if methods is not None:
            assert set(runs.method) == methods, name
        assert runs.final_gap.between(0, 1).all()
        assert (runs.horizon == 200).all() and set(runs.trial) == {0}
        assert set(runs.rollout) == {0, 1}
        assert set(curves.step) == set(range(0, 201, 10))
        assert (curves.n_runs == 2).all()
        # The curve's last point is the mean final gap of the same runs.
        key = ["object", "method", "variant", "s", "delta", "gamma", "k", "n"]
        last = curves[curves.step == 200].set_index(key)
        mean = runs.groupby(key).final_gap.mean()
        pd.testing.assert_series_equal(
            last.gap_mean.sort_index(), mean.sort_index(), check_names=False
        )
        assert set(checks.step) <= {100, 200}
    act = pd.read_parquet(folder / "case_study/active_set.parquet")
    assert len(act) > 0 and set(act.method) == {"legs"}
    assert act.grasp.ge(0).all() and act.robustness.between(0, 1).all()
    es = pd.read_parquet(folder / "early_stopping/checks.parquet")
    assert es.p_lower_attempted.notna().all() and es.p_lower.between(0, 1).all()
    conf = pd.read_parquet(folder / "confidence/runs.parquet")
    assert sorted(set(conf.delta)) == [0.01, 0.05, 0.1, 0.15, 0.2, 0.25]
    ps = pd.read_parquet(folder / "prior_strength/runs.parquet")
    assert sorted(set(ps.s)) == [0, 1, 2, 3, 4, 5] and set(ps.delta) == {0.07}


def test_smoke_of_legs_runs_every_experiment(tmp_path):
    """LEGS's arms of all seven experiments (the grids of the confidence and
    prior-strength studies, the regimes map's variants); a second run finds
    everything done and changes nothing."""
    args = ["--smoke", "--methods", "legs", "--out", str(tmp_path)]
    p = _sweep(args, _env())
    assert p.returncode == 0, p.stderr[-3000:]
    _smoke_checks(tmp_path, {"legs"})
    before = _tables(tmp_path)
    p = _sweep(args, _env())
    assert p.returncode == 0, p.stderr[-3000:]
    assert _tables(tmp_path) == before


@pytest.mark.slow
def test_smoke_runs_every_experiment(tmp_path):
    """Every declared arm of all seven experiments (a few minutes: every method's
    programs compile)."""
    p = _sweep(["--smoke", "--out", str(tmp_path)], _env())
    assert p.returncode == 0, p.stderr[-3000:]
    _smoke_checks(tmp_path, None)
    main = pd.read_parquet(tmp_path / "main/runs.parquet")
    # Every method the experiment declares (the paper's seven, the two Bayes-UCB
    # rows and our method) ran.
    declared = {m for m, _, _ in experiments.get("main").ARMS}
    assert len(declared) == 10 and set(main.method) == declared
    assert set(main[main.variant == "orig_prior"].method) == {"borges_2000"}
    # A second run finds everything done and changes nothing.
    before = _tables(tmp_path)
    p = _sweep(["--smoke", "--out", str(tmp_path)], _env())
    assert p.returncode == 0, p.stderr[-3000:]
    assert _tables(tmp_path) == before


def test_sigkill_then_resume_equals_uninterrupted(tmp_path):
    args = ["--smoke", "--experiment", "main", "--methods", "dexnet", "legs", "tql"]
    ref = _sweep([*args, "--out", str(tmp_path / "ref")], _env())
    assert ref.returncode == 0, ref.stderr[-3000:]

    out = tmp_path / "killed"
    chunks = out / "main" / "chunks"
    proc = subprocess.Popen(
        [sys.executable, "-m", "legs_jax.sweep", *args, "--out", str(out)],
        cwd=ROOT,
        env=_env(),
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
    )
    try:
        deadline = time.time() + 240
        while time.time() < deadline and proc.poll() is None:
            if _finished(chunks):
                break
            time.sleep(0.05)
        assert proc.poll() is None, "the sweep finished before it could be killed"
        os.kill(proc.pid, signal.SIGKILL)
        proc.wait(timeout=30)
    finally:
        if proc.poll() is None:
            proc.kill()
    done = _finished(chunks)
    assert 1 <= len(done) < 3
    assert not (out / "main" / "runs.parquet").exists()
    res = _sweep([*args, "--out", str(out)], _env())
    assert res.returncode == 0, res.stderr[-3000:]
    man = json.loads((out / "main/manifest.json").read_text())
    assert man["status"] == "complete"
    assert sum(s.get("chunks_computed", 0) for s in man["sessions"]) == 3 - len(done)
    assert not list(chunks.glob(".tmp-*"))
    assert _tables(out) == _tables(tmp_path / "ref")


@pytest.mark.slow
def test_four_cpu_devices_equal_one(tmp_path):
    args = ["--smoke", "--experiment", "main", "--methods", "borges_2000", "legs"]
    one = _sweep([*args, "--out", str(tmp_path / "one")], _env(1))
    assert one.returncode == 0, one.stderr[-3000:]
    four = _sweep([*args, "--out", str(tmp_path / "four")], _env(4))
    assert four.returncode == 0, four.stderr[-3000:]
    man = json.loads((tmp_path / "four/main/manifest.json").read_text())
    assert man["sessions"][-1]["devices"]["count"] == 4
    assert _tables(tmp_path / "four") == _tables(tmp_path / "one")


def test_ctrl_c_stops_cleanly_and_says_what_was_kept(tmp_path):
    # A long horizon keeps the sweep running well after its first chunk is done.
    args = [
        "--smoke",
        "--experiment",
        "main",
        "--horizon",
        "2000",
        "--out",
        str(tmp_path),
    ]
    proc = subprocess.Popen(
        [sys.executable, "-m", "legs_jax.sweep", *args],
        cwd=ROOT,
        env=_env(),
        stdout=subprocess.DEVNULL,
        stderr=subprocess.PIPE,
        text=True,
    )
    chunks = tmp_path / "main" / "chunks"
    try:
        deadline = time.time() + 240
        while time.time() < deadline and proc.poll() is None and not _finished(chunks):
            time.sleep(0.05)
        assert proc.poll() is None, "the sweep finished before it could be stopped"
        proc.send_signal(signal.SIGINT)
        _, err = proc.communicate(timeout=120)
    finally:
        if proc.poll() is None:
            proc.kill()
    assert proc.returncode == 130, err[-2000:]
    kept = _finished(chunks)
    n_chunks = len(experiments.get("main").ARMS)  # smoke: one chunk an arm
    assert f"interrupted: main kept {len(kept)} of {n_chunks} finished chunk(s)" in err
    assert "Traceback" not in err and "run the same command again" in err.lower()
    assert not [d for d in chunks.iterdir() if d.name.startswith(".tmp")]
    man = json.loads((tmp_path / "main/manifest.json").read_text())
    assert man["status"] == "interrupted" and man["chunks_done"] == len(kept)


def _free_port() -> int:
    import socket

    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def test_distributed_single_process_path(tmp_path):
    args = ["--smoke", "--experiment", "main", "--methods", "dexnet", "tql"]
    ref = _sweep([*args, "--out", str(tmp_path / "ref")], _env())
    assert ref.returncode == 0, ref.stderr[-3000:]
    dist = ["--coordinator", f"127.0.0.1:{_free_port()}", "--num-processes", "1"]
    p = _sweep(
        [*args, *dist, "--process-id", "0", "--out", str(tmp_path / "d")], _env()
    )
    assert p.returncode == 0, p.stderr[-3000:]
    assert _tables(tmp_path / "d") == _tables(tmp_path / "ref")


@pytest.mark.slow
def test_two_processes_split_the_chunks_and_merge(tmp_path):
    args = ["--smoke", "--experiment", "main", "--methods", "dexnet", "legs", "tql"]
    ref = _sweep([*args, "--out", str(tmp_path / "ref")], _env())
    assert ref.returncode == 0, ref.stderr[-3000:]
    dist = ["--coordinator", f"127.0.0.1:{_free_port()}", "--num-processes", "2"]
    procs = [
        subprocess.Popen(
            [
                sys.executable,
                "-m",
                "legs_jax.sweep",
                *args,
                *dist,
                "--process-id",
                str(i),
                "--out",
                str(tmp_path / "d"),
            ],  # fmt: skip
            cwd=ROOT,
            env=_env(),
            stdout=subprocess.DEVNULL,
            stderr=subprocess.PIPE,
            text=True,
        )
        for i in range(2)
    ]
    errs = [p.communicate(timeout=300)[1] for p in procs]
    assert [p.returncode for p in procs] == [0, 0], errs
    man = json.loads((tmp_path / "d/main/manifest.json").read_text())
    assert {c["process_id"] for c in man["chunks"].values()} == {0, 1}
    assert _tables(tmp_path / "d") == _tables(tmp_path / "ref")


def test_ctrl_c_inside_a_gc_callback_is_kept_for_the_loop():
    # An exception raised in a garbage-collection callback is printed and
    # swallowed by Python; the handler leaves it to the loop's next check.
    import sys as _sys

    from legs_jax.sweep import execute

    def _xla_gc_callback():
        execute._on_sigint(signal.SIGINT, _sys._getframe())

    execute._INTERRUPTED.clear()
    try:
        _xla_gc_callback()  # returns: nothing raised inside the callback
        assert execute._INTERRUPTED.is_set()
        with pytest.raises(KeyboardInterrupt):
            execute._check_interrupt()
        execute._INTERRUPTED.clear()
        with pytest.raises(KeyboardInterrupt):  # elsewhere it raises at once
            execute._on_sigint(signal.SIGINT, _sys._getframe())
    finally:
        execute._INTERRUPTED.clear()
