"""The command lines of a Markdown file's shell blocks, and a check that the
package's command-line programs accept them, for the README's and the docs'
tests.

A command line is a line of a ```bash block: a trailing ``# comment`` is dropped,
a line ending in ``\\`` continues on the next. Blocks marked ```text (sketches
with placeholders, such as the multi-host commands) are not commands.
"""

from __future__ import annotations

import argparse
import contextlib
import io
import re
import shlex
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]

_BLOCK = re.compile(r"^```(\w*)\n(.*?)^```", flags=re.S | re.M)


def shell_blocks(path: Path) -> list[list[str]]:
    """The ```bash blocks of ``path``, each as its list of command lines."""
    out = []
    for lang, body in _BLOCK.findall(path.read_text()):
        if lang not in ("bash", "sh", "shell", "console"):
            continue
        lines, pending = [], ""
        for raw in body.splitlines():
            line = pending + raw.strip()
            if line.endswith("\\"):
                pending = line[:-1] + " "
                continue
            pending = ""
            line = re.sub(r"(^|\s)#.*$", "", line).strip()  # a trailing comment
            if line:
                lines.append(line)
        out.append(lines)
    return out


def module_argv(line: str) -> tuple[str, list[str]] | None:
    """``python -m MODULE ARGS...`` -> (MODULE, ARGS); None for any other
    command. Shell redirections (``< FILE``) are dropped."""
    words = shlex.split(line, comments=True)
    if len(words) < 3 or words[0] != "python" or words[1] != "-m":
        return None
    args, skip = [], False
    for w in words[3:]:
        if skip:
            skip = False
            continue
        if w in ("<", ">", "2>"):
            skip = True
            continue
        args.append(w)
    return words[2], args


class Refused(Exception):
    """The program's parser refused the command line."""


def _parse(parser: argparse.ArgumentParser, args: list[str]) -> None:
    err = io.StringIO()
    try:
        with contextlib.redirect_stderr(err), contextlib.redirect_stdout(io.StringIO()):
            parser.parse_args(args)
    except SystemExit as e:
        if e.code not in (0, None):
            raise Refused(err.getvalue().strip()) from None


def check_arguments(module: str, args: list[str]) -> None:
    """Parse ``args`` with the parser of ``python -m module`` (nothing runs);
    raise :class:`Refused` with the parser's message when it refuses them."""
    if module == "legs_jax.sweep":
        from legs_jax.sweep import cli

        _parse(cli.build_parser(), args)
    elif module == "legs_jax.figures":
        from legs_jax import figures

        _parse(figures.build_parser(), args)
    elif module == "legs_jax.online":
        from legs_jax.online import cli

        _parse(cli.build_parser(), args)
    elif module == "legs_jax.bench":
        from legs_jax import bench

        _parse(bench.build_parser(), args)
    elif module == "precompute":
        from precompute import cli

        sub = args[0] if args else None
        if sub == "report":
            from precompute import report

            _parse(report.build_parser(), args[1:])
        elif sub == "train-prior":
            from precompute import train_prior

            _parse(train_prior._parser(), args[1:])
        elif sub in ("compare", "ship", "calibrate"):
            pass  # their parsers are built inside their commands
        else:
            _parse(cli._build_parser(), args)
    elif module in ("legs_jax.sweep.shapes", "pytest"):
        pass
    elif module.startswith("experiments."):
        import importlib

        importlib.import_module(module)
    else:
        raise Refused(f"no known program {module!r}")
