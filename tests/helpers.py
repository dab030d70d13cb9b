"""Helpers that several test modules share: running a module of this repository
in a fresh interpreter, and building a small problem of a catalogue object."""

from __future__ import annotations

import subprocess
import sys
from collections.abc import Mapping, Sequence
from pathlib import Path


def run_module(
    module: str,
    args: Sequence[str],
    *,
    cwd: str | Path,
    env: Mapping[str, str] | None = None,
    timeout: float = 300,
) -> subprocess.CompletedProcess:
    """``python -m module args`` in a fresh interpreter, its output captured as
    text."""
    return subprocess.run(
        [sys.executable, "-m", module, *args],
        capture_output=True,
        text=True,
        cwd=cwd,
        env=env,
        timeout=timeout,
    )


def catalog_problem(name: str, **params):
    """A problem of the catalogue object ``name``, built with ``BuildParams(**params)``
    (small sizes keep a test fast)."""
    import precompute
    from precompute.build import BuildParams, build_problem

    info = precompute.catalog.lookup(name)
    return build_problem(
        info.mesh_path, units=info.units, name=info.name, params=BuildParams(**params)
    )


def small_clamp_file(folder: Path) -> Path:
    """``folder/bar_clamp.npz``: a small bar_clamp problem (1 trial, 100 grasps a
    pose, 20 samples), as the online sessions' tests read it."""
    from legs_jax.core import problem

    path = Path(folder) / "bar_clamp.npz"
    problem.save(catalog_problem("bar_clamp", trials=1, grasps=100, samples=20), path)
    return path
