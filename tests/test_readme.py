"""Every command of the README's ```bash blocks works in the repository and
changes no tracked file.

How a command line is run (the first rule that matches it decides):

- ``NOT_RUN``: the set-up commands themselves (``pip install``, ``python -m
  pytest``): this test runs inside them.
- ``DRY_RUN``: commands that take an hour; run with ``--dry-run`` appended.
- ``TINY``: long commands whose output a later command of the same block reads;
  run with the arguments listed appended (small sizes; a later option wins in
  argparse), so that the rest of the block runs on real output.
- any other command: verbatim.

Each block runs as one test, its commands in order, in the repository root, with
``git status --porcelain`` compared before and after; what a block creates under
the ignored ``runs/`` and ``problems/`` folders is removed afterwards. A block
with a ``TINY`` command or a command in ``SLOW`` is marked slow. Commands that
name ``my_pkg.my_method`` get the example method of docs/methods.md as
``my_pkg/my_method.py`` on ``PYTHONPATH``, as the README tells the reader to save
it. The default suite also checks every README command line against its
program's parser (nothing runs), which is fast.
"""

from __future__ import annotations

import os
import re
import shlex
import shutil
import subprocess
import sys

import pytest
from doc_commands import ROOT, Refused, check_arguments, module_argv, shell_blocks

README = ROOT / "README.md"

NOT_RUN = ("pip install", "python -m pytest")
DRY_RUN = ("python -m legs_jax.sweep --all --out",)
_SWEEP_TINY = ["--trials", "1", "--rollouts", "2", "--horizon", "100", "--quiet"]
TINY = {
    "python -m legs_jax.sweep --experiment": _SWEEP_TINY,
    "python -m legs_jax.sweep --problems": _SWEEP_TINY,
    "python -m precompute --mesh": [
        "--trials",
        "1",
        "--grasps",
        "100",
        "--samples",
        "5",
    ],
    "python -m legs_jax.online simulate": ["--steps", "40", "--quiet"],
}
SLOW = ("python -m legs_jax.figures", "python -m legs_jax.online serve")
USER_FOLDERS = ("runs", "problems")


def _mode(line: str) -> tuple[str, list[str]]:
    if line.startswith(NOT_RUN):
        return "not run", []
    if line.startswith(DRY_RUN):
        return "dry run", ["--dry-run"]
    for prefix, extra in TINY.items():
        if line.startswith(prefix):
            return "tiny", extra
    return "verbatim", []


def _blocks() -> list[list[str]]:
    return [b for b in shell_blocks(README) if b]


def _params():
    out = []
    for i, block in enumerate(_blocks()):
        slow = any(_mode(c)[0] == "tiny" or c.startswith(SLOW) for c in block)
        marks = [pytest.mark.slow] if slow else []
        out.append(pytest.param(block, id=f"block{i}", marks=marks))
    return out


def _git_status() -> str:
    return subprocess.run(
        ["git", "status", "--porcelain"],
        cwd=ROOT,
        capture_output=True,
        text=True,
        check=True,
    ).stdout


def _user_paths() -> set:
    out = set()
    for name in USER_FOLDERS:
        folder = ROOT / name
        if folder.is_dir():
            out |= {p for p in folder.iterdir()}
            out |= {p for p in folder.glob("*/*")}
    return out


def _example_method_package(tmp_path):
    text = (ROOT / "docs" / "methods.md").read_text()
    blocks = re.findall(r"```python\n(.*?)```", text, flags=re.S)
    (code,) = [b for b in blocks if "METHOD = Method(" in b]
    pkg = tmp_path / "user_src" / "my_pkg"
    pkg.mkdir(parents=True)
    (pkg / "__init__.py").write_text("")
    (pkg / "my_method.py").write_text(code)
    return pkg.parent


def test_the_readme_starts_with_the_three_set_up_commands():
    text = README.read_text()
    assert len(text.splitlines()) <= 300
    head = "\n".join(text.splitlines()[:40])
    first = _blocks()[0]
    assert first == [
        'pip install -e ".[dev]"',
        "python -m pytest",
        "python -m legs_jax.sweep --all",
    ]
    assert "Python >= 3.11" in head
    hashes = re.findall(r"\b(?=[0-9a-f]*[a-f])(?=[0-9a-f]*\d)[0-9a-f]{7,40}\b", text)
    assert not hashes, f"commit hashes in the README: {hashes}"


def test_every_readme_command_is_accepted_by_its_program():
    refused = []
    for block in _blocks():
        for line in block:
            mode, extra = _mode(line)
            if mode == "not run":
                continue
            cmd = module_argv(line)
            assert cmd is not None, f"not a python -m command: {line}"
            try:
                check_arguments(cmd[0], cmd[1] + extra)
            except Refused as e:
                refused.append(f"{line}\n  {e}")
    assert not refused, "\n".join(refused)


@pytest.mark.parametrize("block", _params())
def test_readme_block_runs_and_changes_no_tracked_file(block, tmp_path):
    env = dict(os.environ, MPLBACKEND="Agg")
    if any("my_pkg.my_method" in line for line in block):
        src = _example_method_package(tmp_path)
        env["PYTHONPATH"] = os.pathsep.join(
            [str(src), *filter(None, [env.get("PYTHONPATH")])]
        )
    before, existing = _git_status(), _user_paths()
    try:
        for line in block:
            mode, extra = _mode(line)
            if mode == "not run":
                continue
            cmd = line.replace("python ", shlex.quote(sys.executable) + " ", 1)
            cmd = " ".join([cmd.split(" <")[0], *map(shlex.quote, extra)])
            if " <" in line:
                cmd += " <" + line.split(" <", 1)[1]
            r = subprocess.run(
                ["bash", "-c", cmd],
                cwd=ROOT,
                env=env,
                capture_output=True,
                text=True,
                timeout=1800,
            )
            assert r.returncode == 0, (
                f"{line} ({mode}) exited {r.returncode}\n{r.stdout[-3000:]}\n"
                f"{r.stderr[-3000:]}"
            )
            assert _git_status() == before, f"{line} changed tracked files"
    finally:
        for p in sorted(_user_paths() - existing, reverse=True):
            if p.is_dir():
                shutil.rmtree(p, ignore_errors=True)
            else:
                p.unlink(missing_ok=True)


def _md_rows(text: str) -> dict[str, list[str]]:
    """Rows of the markdown tables in ``text``: label -> the other cells, bold
    marks removed, ``K_s=`` written ``K=``, a trailing ", extra" dropped."""
    rows = {}
    for line in text.splitlines():
        if not line.startswith("| ") or set(line) <= set("|:- "):
            continue
        cells = [c.strip().replace("**", "") for c in line.strip("|").split("|")]
        label = cells[0].replace("K_s=", "K=").removesuffix(", extra")
        rows[label] = cells[1:]
    return rows


def test_readme_results_are_table_one():
    """The README's results table repeats Table I (results/tables/table1.md)
    cell for cell, so that a rerun that changes Table I cannot leave it stale."""
    text = README.read_text()
    section = text.split("## Results", 1)[1].split("\n## ", 1)[0]
    readme = _md_rows(section)
    table = _md_rows((ROOT / "results" / "tables" / "table1.md").read_text())
    shown = [label for label in readme if label in table]
    assert len(shown) >= 7, readme.keys()
    for label in shown:
        assert readme[label] == table[label], label
    assert set(readme) - set(shown) <= {"method", "LEGS wins"}
