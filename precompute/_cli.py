"""What the command lines share: the parser every ``python -m precompute NAME``
subcommand starts from, and the options of a mesh file's size."""

from __future__ import annotations

import argparse
from pathlib import Path

from .mesh import FITS, UNITS


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


FIT_HELP = (
    "none keeps the file's size (default); egad scales as EGAD! does for the "
    "gripper (largest side = the 80 mm opening, smallest side at most 64 mm)"
)


def add_mesh_size_args(
    p: argparse.ArgumentParser, mesh: str, units_note: str = ""
) -> None:
    """``--units`` and ``--fit`` of a mesh file (``mesh`` names the option that
    gives it, for the help; ``units_note`` ends the help of ``--units``)."""
    p.add_argument(
        "--units", choices=list(UNITS), help=f"length unit of {mesh}{units_note}"
    )
    p.add_argument(
        "--fit",
        choices=list(FITS),
        default="none",
        help=f"size rule of {mesh}: {FIT_HELP}",
    )
