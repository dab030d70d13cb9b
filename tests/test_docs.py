"""The documentation's shell commands are accepted by the programs they name.

The Python examples of docs/*.md run as tests themselves (Sybil, see the
repository's conftest.py). The shell commands there are mostly long (a sweep of
an hour, a build of every mesh), so here each ``python -m`` line of a ```bash
block is parsed by its program's own parser, nothing run: an option renamed or
removed in the code fails this test until the docs follow. The README's commands
run for real in tests/test_readme.py.
"""

from __future__ import annotations

import pytest
from doc_commands import ROOT, Refused, check_arguments, module_argv, shell_blocks

PAGES = sorted((ROOT / "docs").glob("*.md"))
# lines of a bash block that are not python -m commands
OTHER = ("pip install", "mkdocs ")


def test_the_docs_have_pages_and_commands():
    assert len(PAGES) >= 9
    assert sum(len(b) for p in PAGES for b in shell_blocks(p)) >= 30


@pytest.mark.parametrize("page", PAGES, ids=lambda p: p.name)
def test_every_command_of_the_page_is_accepted(page):
    refused = []
    for block in shell_blocks(page):
        for line in block:
            cmd = module_argv(line)
            if cmd is None:
                assert line.startswith(OTHER), f"{page.name}: not a command: {line}"
                continue
            try:
                check_arguments(*cmd)
            except Refused as e:
                refused.append(f"{line}\n  {e}")
    assert not refused, f"{page.name}:\n" + "\n".join(refused)


def test_a_refused_option_is_caught():
    with pytest.raises(Refused, match="--no-such-option"):
        check_arguments("legs_jax.sweep", ["--all", "--no-such-option"])
    with pytest.raises(Refused):
        check_arguments("legs_jax.online", ["no-such-command"])
