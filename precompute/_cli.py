"""The parser every ``python -m precompute NAME`` subcommand starts from."""

from __future__ import annotations

import argparse
from pathlib import Path


def subcommand_parser(name: str, doc: str | None) -> argparse.ArgumentParser:
    """The parser of ``python -m precompute NAME``: its module's ``doc`` as the
    description, and ``--problems``."""
    ap = argparse.ArgumentParser(
        prog=f"python -m precompute {name}",
        description=doc,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    ap.add_argument(
        "--problems", type=Path, help="problem folder (default: data/problems)"
    )
    return ap
