"""The documentation's Python examples run as tests (Sybil): every ```python
block of docs/*.md, in order, one namespace a page (so a page's examples go to
one test worker, as one xdist group). A block after a
``<!-- skip: next -->`` comment is shown, not run (it needs a camera or a robot).
Examples that write files run in a temporary folder; the others in the
repository, so that they can read the committed results."""

from __future__ import annotations

import os

import pytest
from sybil import Sybil
from sybil.parsers.markdown import PythonCodeBlockParser, SkipParser

_WRITES_FILES = ["problems.md"]


@pytest.fixture
def in_tmp_folder(tmp_path):
    here = os.getcwd()
    os.chdir(tmp_path)
    try:
        yield tmp_path
    finally:
        os.chdir(here)


_PARSERS = [PythonCodeBlockParser(), SkipParser()]

pytest_collect_file = (
    Sybil(
        parsers=_PARSERS,
        path="docs",
        patterns=_WRITES_FILES,
        fixtures=["in_tmp_folder"],
        name="docs-in-tmp",
    )
    + Sybil(
        parsers=_PARSERS,
        path="docs",
        patterns=["*.md"],
        excludes=_WRITES_FILES,
        name="docs",
    )
).pytest()


@pytest.hookimpl(tryfirst=True)  # before pytest-xdist reads the groups
def pytest_collection_modifyitems(config, items):
    """A page's examples share its namespace and its skip directives, which are
    examples too: they run on one worker, in the page's order."""
    for item in items:
        if type(item).__name__ == "SybilItem" and not item.get_closest_marker(
            "xdist_group"
        ):
            item.add_marker(pytest.mark.xdist_group(f"docs-{item.path.name}"))
