"""kill -9 a simulated session mid-run, resume it, and find every outcome.

The run goes through the command line (``python -m legs_jax.online simulate``)
in a child process that is killed with SIGKILL once it has logged some outcomes;
``--resume`` finishes it. Every record logged before the kill is still in the
log, in place, and the resumed run ends with exactly the log of a run that was
never killed (the robot's draws are keyed by step, the method's by the engine's
key streams).
"""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parents[1]
_CACHE = Path()  # a compilation cache shared by the runs of this module


@pytest.fixture(scope="module", autouse=True)
def _compile_cache(tmp_path_factory):
    global _CACHE
    _CACHE = tmp_path_factory.mktemp("jax_cache")


def _cmd(out: Path, steps: int, extra=()) -> list[str]:
    return [
        sys.executable, "-m", "legs_jax.online", "simulate", "--object", "bar_clamp",
        "--steps", str(steps), "--out", str(out), "--quiet", "--eval-every", "50",
        *extra,
    ]  # fmt: skip


def _env() -> dict:
    env = dict(os.environ)
    env["JAX_COMPILATION_CACHE_DIR"] = str(_CACHE)
    env["PYTHONPATH"] = os.pathsep.join([str(ROOT), env.get("PYTHONPATH", "")])
    env["MPLBACKEND"] = "Agg"
    return env


def _complete_lines(path: Path) -> list[bytes]:
    raw = path.read_bytes() if path.is_file() else b""
    return raw.split(b"\n")[:-1]  # a torn tail is not a record


def _tells(lines) -> int:
    return sum(b'"type":"tell"' in line for line in lines)


def _outcomes(lines) -> list[tuple]:
    recs = [json.loads(x) for x in lines if b'"type":"tell"' in x]
    return [(r["step"], r["pose"], r["grasp"], r["success"]) for r in recs]


def _kill_resume(tmp_path, extra, steps, kill_after):
    out = tmp_path / "run"
    proc = subprocess.Popen(
        _cmd(out, steps, extra), cwd=ROOT, env=_env(), stderr=subprocess.PIPE
    )
    log = out / "log.jsonl"
    deadline = time.time() + 300
    while _tells(_complete_lines(log)) < kill_after:
        assert proc.poll() is None, proc.stderr.read().decode()
        assert time.time() < deadline, "the run logged too little in 300 s"
        time.sleep(0.05)
    proc.send_signal(signal.SIGKILL)
    proc.wait()
    proc.stderr.close()
    before = _complete_lines(log)
    n_before = _tells(before)
    assert kill_after <= n_before < steps  # killed mid-run
    res = subprocess.run(
        _cmd(out, steps, (*extra, "--resume")),
        cwd=ROOT,
        env=_env(),
        capture_output=True,
        text=True,
        timeout=600,
    )
    assert res.returncode == 0, res.stderr
    after = _complete_lines(log)
    # every record logged before the kill is still there, in place
    assert after[: len(before)] == before
    tells = [json.loads(x) for x in after if b'"type":"tell"' in x]
    assert [t["step"] for t in tells] == list(range(1, steps + 1))
    assert (out / "learning_curve.png").stat().st_size > 1000
    curve = [json.loads(x) for x in (out / "curve.jsonl").read_text().splitlines()]
    assert curve[-1]["step"] == steps
    return out, after


# three command-line runs, about a minute; the in-process resume: test_online.py
@pytest.mark.slow
def test_sigkill_mid_run_then_resume_loses_nothing(tmp_path, clamp_problem):
    extra = ("--problem", str(clamp_problem), "--given-poses", "--seed", "2")
    steps = 200
    out, after = _kill_resume(tmp_path, extra, steps, kill_after=50)
    # the same run never killed: the same log, record for record
    clean = tmp_path / "clean"
    res = subprocess.run(
        _cmd(clean, steps, extra), cwd=ROOT, env=_env(), capture_output=True,
        text=True, timeout=600,
    )  # fmt: skip
    assert res.returncode == 0, res.stderr
    # the same outcomes (the resumed run observes again the object it was looking
    # at when killed, so the observation records may differ in number)
    assert _outcomes(_complete_lines(clean / "log.jsonl")) == _outcomes(after)
    gaps = [
        json.loads(x)["gap"] for x in (out / "curve.jsonl").read_text().splitlines()
    ]
    assert np.all(np.isfinite(gaps))


@pytest.mark.slow
def test_sigkill_with_recognition_then_resume(tmp_path):
    """The same with depth images, recognition and observed reservoirs."""
    _kill_resume(tmp_path, ("--seed", "1", "--reservoir", "500"), 40, kill_after=12)
