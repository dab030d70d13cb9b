"""Small file helpers shared by the writers of problems, results and reports."""

from __future__ import annotations

import os

__all__ = ["public_mode"]


def public_mode(path: str | os.PathLike) -> None:
    """Give a temporary file the mode a plain ``open`` would (``tempfile.mkstemp``
    makes 0600 files, which other users of a shared folder could not read)."""
    umask = os.umask(0)
    os.umask(umask)
    os.chmod(path, 0o666 & ~umask)
