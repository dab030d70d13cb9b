"""Where the online commands write: a run at another configuration than a shipped
table's goes to runs/online/, and no command replaces a file tracked by git
unless told to (--overwrite)."""

from __future__ import annotations

import json
import re
import shlex
import subprocess
from pathlib import Path
from types import SimpleNamespace

import pytest

from legs_jax.online import agreement as agreement_mod
from legs_jax.online import cli
from legs_jax.online import recognition_table as table_mod

ROOT = Path(__file__).resolve().parents[1]
SHIPPED = ROOT / "results" / "online"


def _snapshot(folder: Path) -> dict[str, bytes]:
    return {
        str(p.relative_to(folder)): p.read_bytes()
        for p in sorted(folder.rglob("*"))
        if p.is_file()
    }


def _command(markdown: Path, command: str) -> list[str]:
    """The arguments of ``python -m legs_jax.online COMMAND`` in the Regenerate
    line of a shipped table."""
    line = next(x for x in markdown.read_text().splitlines() if "Regenerate" in x)
    m = re.search(rf"`python -m legs_jax\.online {command} ([^`]*)`", line)
    return shlex.split(m.group(1))


def test_the_defaults_are_the_shipped_recognition_table():
    """The bare command regenerates results/online/recognition.md: the parser's
    defaults are the configuration of the table's own Regenerate line."""
    parser = cli.build_parser()
    shipped = parser.parse_args(
        [
            "recognition-table",
            *_command(SHIPPED / "recognition.md", "recognition-table"),
        ]
    )
    bare = parser.parse_args(["recognition-table"])
    for a in (shipped, bare):
        names = a.objects or list(table_mod.DEXNET_OBJECTS)
        assert table_mod.is_shipped(names, a.views, a.seed)
    assert not table_mod.is_shipped(["bar_clamp"], bare.views, bare.seed)
    assert not table_mod.is_shipped(names, bare.views + 1, bare.seed)


def test_the_shipped_agreement_configuration_is_its_regenerate_line():
    text = (SHIPPED / "agreement.md").read_text()
    build = re.search(r"--object (\S+) --trials (\d+) --grasps (\d+)", text)
    pb = SimpleNamespace(
        name=build.group(1),
        num_trials=int(build.group(2)),
        num_grasps=int(build.group(3)),
    )
    parser = cli.build_parser()
    args = parser.parse_args(
        ["agreement", *_command(SHIPPED / "agreement.md", "agreement")]
    )
    assert agreement_mod.is_shipped(pb, args)
    args.rollouts += 1
    assert not agreement_mod.is_shipped(pb, args)
    pb.num_trials += 1
    args.rollouts -= 1
    assert not agreement_mod.is_shipped(pb, args)


def _one_line_refusal(err: str) -> None:
    assert "--overwrite" in err and "Traceback" not in err
    assert err.strip().count("\n") == 0, err


def test_no_command_replaces_the_shipped_results(monkeypatch, capsys):
    """In the repository: each command pointed at results/online (or a folder of
    it) at another configuration is refused in one line naming --overwrite, before
    any work, and every file there stays byte-identical."""
    before = _snapshot(SHIPPED)
    monkeypatch.chdir(ROOT)
    table = ["recognition-table", "--objects", "bar_clamp", "--views", "10", "--quiet"]
    for out in ("results/online", "results/online/recognition.md"):
        assert cli.main([*table, "--out", out]) == 2
        _one_line_refusal(capsys.readouterr().err)
    problem = cli._find_problem("bar_clamp")
    assert problem is not None
    agree = ["agreement", "--problem", str(problem), "--rollouts", "2", "--quiet"]
    for out in ("results/online", "results/online/agreement.md"):
        assert cli.main([*agree, "--out", out, "--compile-cache", "off"]) == 2
        _one_line_refusal(capsys.readouterr().err)
    for folder in ("results/online/stop_at", "results/online"):
        sim = ["simulate", "--object", "bar_clamp", "--steps", "5", "--out", folder]
        assert cli.main([*sim, "--quiet", "--compile-cache", "off"]) == 2
        _one_line_refusal(capsys.readouterr().err)
        # serve answers in JSON lines, the refusal too
        assert cli.main(["serve", folder, "--compile-cache", "off"]) == 2
        out = capsys.readouterr().out.splitlines()
        assert len(out) == 1
        resp = json.loads(out[0])
        assert not resp["ok"] and "--overwrite" in resp["error"]["message"]
    # --overwrite lets the folder through (the next error is the object's)
    sim = ["simulate", "--object", "no_such_thing", "--out", "results/online/stop_at"]
    assert cli.main([*sim, "--overwrite", "--compile-cache", "off"]) == 2
    err = capsys.readouterr().err
    assert "no_such_thing" in err and "--overwrite" not in err
    assert _snapshot(SHIPPED) == before


@pytest.fixture
def repo(tmp_path, monkeypatch) -> Path:
    """A git repository holding a tracked results/online/recognition.md."""
    subprocess.run(["git", "init", "-q", str(tmp_path)], check=True)
    shipped = tmp_path / "results" / "online" / "recognition.md"
    shipped.parent.mkdir(parents=True)
    shipped.write_text("the shipped table\n")
    subprocess.run(["git", "-C", str(tmp_path), "add", "results"], check=True)
    monkeypatch.chdir(tmp_path)
    return tmp_path


def test_another_configuration_goes_to_runs_and_overwrite_replaces(repo, capsys):
    """recognition-table --objects bar_clamp: runs/online/recognition.md, said on
    stdout; --out results/online is refused, and done with --overwrite."""
    shipped = repo / "results" / "online" / "recognition.md"
    args = ["recognition-table", "--objects", "bar_clamp", "--views", "2", "--quiet"]
    assert cli.main(args) == 0
    out = capsys.readouterr().out
    mine = repo / "runs" / "online" / "recognition.md"
    assert "| bar_clamp |" in mine.read_text()
    assert f"wrote {Path('runs/online/recognition.md')}" in out
    assert shipped.read_text() == "the shipped table\n"
    assert cli.main([*args, "--out", "results/online"]) == 2
    _one_line_refusal(capsys.readouterr().err)
    assert shipped.read_text() == "the shipped table\n"
    assert cli.main([*args, "--out", "results/online", "--overwrite"]) == 0
    assert "| bar_clamp |" in shipped.read_text()
    # a folder of the user's own, and a file name of their own
    assert cli.main([*args, "--out", str(repo / "mine")]) == 0
    assert (repo / "mine" / "recognition.md").is_file()
    assert cli.main([*args, "--out", str(repo / "t.md")]) == 0
    assert (repo / "t.md").is_file()


def test_regenerating_the_table_keeps_the_notes_below_it(tmp_path):
    """The shipped table carries notes below its "Targets:" line; a regenerated
    table keeps them, so the same numbers give the same file."""
    shipped = Path(__file__).resolve().parents[1] / "results/online/recognition.md"
    text = shipped.read_text()
    notes = table_mod.kept_notes(shipped)
    assert notes.strip().startswith("Wrong merges:")
    # the generated part is everything up to and including the Targets line
    generated = text[: len(text) - len(notes)]
    assert generated.rstrip().endswith("Targets: ≥ 95 % right, ≤ 2 % duplicates.")
    out = tmp_path / "recognition.md"
    out.write_text(text)
    assert generated + table_mod.kept_notes(out) == text
    out.write_text(generated)  # a table without notes keeps none
    assert table_mod.kept_notes(out) == ""
    assert table_mod.kept_notes(tmp_path / "missing.md") == ""
