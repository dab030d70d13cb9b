"""Fixtures that several test files share; each is built once per test session."""

from __future__ import annotations

import os
import shutil
import tempfile
from pathlib import Path

import numpy as np
import pytest
import trimesh
from helpers import small_clamp_file

from legs_jax.online.robot import World


@pytest.fixture(scope="session")
def box() -> World:
    """A 40 x 60 x 30 mm box resting on its largest face (one pose)."""
    m = trimesh.creation.box((0.04, 0.06, 0.03))
    tf = np.eye(4)
    tf[2, 3] = 0.015
    return World(
        "box", np.asarray(m.vertices), np.asarray(m.faces), tf[None], np.ones(1),
        np.ones((1, 1)),
    )  # fmt: skip


@pytest.fixture(scope="session")
def clamp_problem(tmp_path_factory) -> Path:
    """A small bar_clamp problem file (1 trial, 100 grasps a pose, 20 samples)."""
    return small_clamp_file(tmp_path_factory.mktemp("problem"))


def pytest_configure(config):
    """The run's own JAX compilation cache, shared by its workers and their
    subprocesses and removed at the end: a command under test that turns the
    cache on (the sweep and the online CLI do by default) neither writes into the
    user's ``~/.cache`` nor reads programs an earlier run left there, so every
    run starts cold, as in a fresh checkout."""
    if os.environ.get("PYTEST_XDIST_WORKER") is None:  # the controller, or -n 0
        path = tempfile.mkdtemp(prefix="legs_jax-tests-jax-cache-")
        os.environ["LEGS_JAX_CACHE_DIR"] = path  # JAX itself leaves it off
        if os.environ.pop("JAX_COMPILATION_CACHE_DIR", None) is not None:
            import jax  # read the variable when imported (by this file's imports)

            jax.config.update("jax_compilation_cache_dir", None)
        config.stash[_CACHE_KEY] = path


def pytest_unconfigure(config):
    path = config.stash.get(_CACHE_KEY, None)
    if path is not None:
        shutil.rmtree(path, ignore_errors=True)


_CACHE_KEY = pytest.StashKey[str]()


def pytest_xdist_auto_num_workers(config) -> int:
    """``-n auto``: one worker per core, at most four (each worker holds a JAX
    runtime and its compiled programs, up to about 3 GB)."""
    return max(1, min(os.cpu_count() or 1, 4))


@pytest.hookimpl(tryfirst=True)  # before pytest-xdist reads the groups
def pytest_collection_modifyitems(config, items):
    """Tests that read one of their module's shared fixtures (``scope="module"``)
    go to one worker, which builds it once: they form one xdist group per module
    (``--dist loadgroup``), unless a test already names its group."""
    for item in items:
        info = getattr(item, "_fixtureinfo", None)
        module = getattr(item, "module", None)
        if info is None or module is None or item.get_closest_marker("xdist_group"):
            continue
        if any(
            d.scope == "module" for defs in info.name2fixturedefs.values() for d in defs
        ):
            item.add_marker(pytest.mark.xdist_group(f"fixtures-{module.__name__}"))
