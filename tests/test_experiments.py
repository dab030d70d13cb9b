"""The experiments are their folders: each ``experiments/<name>/sweep.py`` is found
without being listed, in the order its ``ORDER`` gives; every uppercase constant of
a declaration reaches the namespace ``get`` returns; ``analysis.py`` declares the
outputs of its experiment."""

from __future__ import annotations

import importlib
import shutil
import sys
from pathlib import Path

import pytest

import experiments

ROOT = Path(__file__).resolve().parents[1]


def test_every_folder_with_a_declaration_is_an_experiment():
    folders = {p.parent.name for p in (ROOT / "experiments").glob("*/sweep.py")}
    assert set(experiments.EXPERIMENTS) == folders
    assert experiments.EXPERIMENTS[0] == "main"
    orders = [experiments.get(n).ORDER for n in experiments.EXPERIMENTS]
    assert orders == sorted(orders)
    for name in experiments.EXPERIMENTS:
        decl = experiments.get(name)
        assert decl.NAME == name and decl.OBJECTS and decl.ARMS
        out = experiments.analysis(name)  # None: no outputs of its own
        assert out is None or out.STEPS or out.SECTIONS
    with pytest.raises(KeyError):
        experiments.get("no_such_experiment")


def test_a_new_folder_is_found_and_keeps_its_own_constants(tmp_path, monkeypatch):
    """A copy of the loader with one more folder: the new experiment is listed
    (after those with an ORDER), with the defaults and its own constants."""
    pkg = tmp_path / "my_experiments"
    pkg.mkdir()
    shutil.copy(ROOT / "experiments" / "__init__.py", pkg / "__init__.py")
    for name, order in (("first", "ORDER = 1\n"), ("extra", "")):
        (pkg / name).mkdir()
        (pkg / name / "__init__.py").write_text("")
        (pkg / name / "sweep.py").write_text(
            f'NAME = "{name}"\n{order}OBJECTS = ("dexnet_adv",)\n'
            'ARMS = (("legs", "", {}),)\nPRIOR = "synthetic"\nlower = 1\n'
        )
    monkeypatch.syspath_prepend(str(tmp_path))
    mod = importlib.import_module("my_experiments")
    try:
        assert mod.EXPERIMENTS == ("first", "extra")
        decl = mod.get("extra")
        assert decl.PRIOR == "synthetic" and decl.TRIALS == 10
        assert not hasattr(decl, "lower")
        assert mod.analysis("extra") is None
    finally:
        for key in [k for k in sys.modules if k.startswith("my_experiments")]:
            del sys.modules[key]
