"""What the command lines share: the parser every ``python -m precompute NAME``
subcommand starts from, and the options of a mesh file's size."""

from __future__ import annotations

import argparse
from pathlib import Path

from .errors import PrecomputeError
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


# ----------------------------------------------------- files of the repository

#: Folders of the repository whose files are shipped (committed): a command writes
#: there only when told ``--overwrite``. Used when git cannot say what is tracked.
SHIPPED_DIRS = ("precompute/prior_weights", "results", "data/problemset", "data/meshes")


def repo_root() -> Path:
    """The folder that holds the ``precompute`` package (the repository's root in a
    checkout)."""
    return Path(__file__).resolve().parent.parent


def tracked_under(folder: Path) -> list[Path]:
    """The committed files of the repository at or under ``folder`` (git's list when
    the repository is a git checkout, else the existing files under one of
    :data:`SHIPPED_DIRS`); empty when ``folder`` lies outside the repository."""
    import subprocess

    root = repo_root()
    try:
        rel = Path(folder).resolve().relative_to(root)
    except ValueError:
        return []
    if (root / ".git").exists():
        try:
            r = subprocess.run(
                ["git", "-C", str(root), "ls-files", "-z", "--", str(rel) or "."],
                capture_output=True,
                timeout=30,
                check=True,
            )
            return [root / p for p in r.stdout.decode().split("\0") if p]
        except (OSError, subprocess.SubprocessError):
            pass
    shipped = [root / d for d in SHIPPED_DIRS]
    out = []
    for d in shipped:
        here = root / rel
        if here == d or d in here.parents:
            base = here
        elif here in d.parents:
            base = d
        else:
            continue
        if base.is_file():
            out.append(base)
        elif base.is_dir():
            out += [p for p in base.rglob("*") if p.is_file()]
    return out


def guard_out(folder: Path, overwrite: bool, what: str = "--out") -> None:
    """Refuse (one line) to write into ``folder`` when it holds committed files of
    the repository, unless ``overwrite``."""
    if overwrite:
        return
    hits = tracked_under(folder)
    if hits:
        shown = hits[0].relative_to(repo_root())
        raise PrecomputeError(
            f"{folder} holds files committed to the repository (e.g. {shown}) that "
            f"this would replace: pass --overwrite to replace them, or choose "
            f"another {what}"
        )


def add_overwrite_arg(p: argparse.ArgumentParser, where: str) -> None:
    p.add_argument(
        "--overwrite",
        action="store_true",
        help=f"allow writing into {where} when it holds files committed to the "
        "repository (they are replaced); refused without it",
    )
