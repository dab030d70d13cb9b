"""Where the online commands write, and the files they must not replace unasked.

The tables under ``results/online/`` are shipped with the repository. A command
writes there by default only when run at the configuration that produced the
shipped file (it then regenerates it); any other configuration writes under
:data:`RUNS_DIR` (``runs/online/``, ignored by git) unless ``--out`` says
otherwise. Whatever the folder, a file tracked by git is replaced only at the
shipped configuration or with ``--overwrite`` (:func:`refuse_tracked`).
"""

from __future__ import annotations

import subprocess
from pathlib import Path

from legs_jax.online.errors import InputError

__all__ = [
    "RESULTS_DIR",
    "RUNS_DIR",
    "is_results",
    "out_file",
    "refuse_tracked",
    "tracked",
]

RESULTS_DIR = Path("results/online")
RUNS_DIR = Path("runs/online")


def out_file(out: Path | None, name: str, shipped: bool) -> Path:
    """The file a table command writes: ``--out`` as a file (``.md``) or a folder
    (``name`` inside it); without ``--out``, ``results/online/NAME`` at the
    shipped configuration and ``runs/online/NAME`` at any other."""
    if out is None:
        return (RESULTS_DIR if shipped else RUNS_DIR) / name
    out = Path(out)
    return out if out.suffix.lower() == ".md" else out / name


def is_results(path: Path) -> bool:
    """Whether ``path`` is the shipped file of its name, ``results/online/NAME``
    (from the current folder): the one a run at the shipped configuration
    regenerates."""
    return Path(path).resolve() == (RESULTS_DIR / Path(path).name).resolve()


def tracked(path: Path) -> list[Path]:
    """The files git tracks at ``path`` (a file) or under it (a folder); empty
    when it does not exist, is in no repository, or git is not installed."""
    path = Path(path)
    if not path.exists():
        return []
    where = path if path.is_dir() else path.parent
    arg = "." if path.is_dir() else path.name
    try:
        r = subprocess.run(
            ["git", "-C", str(where), "ls-files", "-z", "--", arg],
            capture_output=True,
            text=True,
            timeout=30,
        )
    except (OSError, subprocess.SubprocessError):
        return []
    if r.returncode != 0:
        return []
    return [where / name for name in r.stdout.split("\0") if name]


def refuse_tracked(paths, overwrite: bool) -> None:
    """Refuse, in one line naming ``--overwrite``, to replace files git tracks at
    or under ``paths`` (files or folders), unless ``overwrite``."""
    if overwrite:
        return
    for p in paths:
        found = tracked(p)
        if not found:
            continue
        if Path(p).is_dir():
            names = ", ".join(sorted(str(f.relative_to(p)) for f in found)[:3])
            more = f" and {len(found) - 3} more" if len(found) > 3 else ""
            raise InputError(
                f"{p} holds files tracked by git (shipped results: {names}{more}); "
                "add --overwrite to write there anyway, or choose another --out"
            )
        raise InputError(
            f"{p} is a file tracked by git (a shipped result) and this is not the "
            "configuration that produced it; add --overwrite to replace it, or "
            "choose another --out"
        )
