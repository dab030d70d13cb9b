"""Small file helpers shared by the writers of problems, results and reports."""

from __future__ import annotations

import hashlib
import os
import tempfile
from collections.abc import Callable
from pathlib import Path
from typing import IO, Any

__all__ = ["atomic_write", "git_state", "public_mode", "sha256_file"]


def atomic_write(
    path: str | os.PathLike, write: Callable[[IO[Any]], Any], *, text: bool = False
) -> Path:
    """Write ``path`` through a temporary file beside it, renamed into place once
    ``write(fh)`` has filled it (a reader never sees a partial file; on any error
    the temporary file is removed). ``text``: UTF-8 with LF line ends."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
    try:
        if text:
            fh = os.fdopen(fd, "w", encoding="utf-8", newline="\n")
        else:
            fh = os.fdopen(fd, "wb")
        with fh:
            write(fh)
        public_mode(tmp)
        os.replace(tmp, path)
    except BaseException:
        if os.path.exists(tmp):
            os.unlink(tmp)
        raise
    return path


def sha256_file(path: str | os.PathLike) -> str:
    """The SHA-256 of a file's bytes, hex, read a megabyte at a time."""
    h = hashlib.sha256()
    with open(path, "rb") as fh:
        for block in iter(lambda: fh.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()


def public_mode(path: str | os.PathLike) -> None:
    """Give a temporary file the mode a plain ``open`` would (``tempfile.mkstemp``
    makes 0600 files, which other users of a shared folder could not read)."""
    umask = os.umask(0)
    os.umask(umask)
    os.chmod(path, 0o666 & ~umask)


def git_state() -> dict[str, Any]:
    """The commit of this checkout (``commit``, None outside git) and whether
    tracked files other than ``results/`` (which runs rewrite) differ from it
    (``dirty``)."""
    import subprocess

    root = Path(__file__).resolve().parents[1]

    def git(*args: str) -> subprocess.CompletedProcess:
        return subprocess.run(
            ["git", *args], cwd=root, capture_output=True, text=True, timeout=10
        )

    try:
        head = git("rev-parse", "HEAD")
        if head.returncode != 0:
            return {"commit": None}
        status = git(
            "status", "--porcelain", "--untracked-files=no", "--", ".",
            ":(exclude)results",
        )  # fmt: skip
        return {"commit": head.stdout.strip(), "dirty": bool(status.stdout.strip())}
    except (OSError, subprocess.SubprocessError):
        return {"commit": None}
