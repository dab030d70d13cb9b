"""Command-line arguments that several of the package's command lines share."""

from __future__ import annotations

import argparse
from pathlib import Path


def compile_cache_arg(p: argparse.ArgumentParser, so_that: str) -> None:
    """``--compile-cache DIR``: JAX's persistent compilation cache (see
    :func:`legs_jax._jax_cache.compile_cache`), ``so_that`` saying what it saves."""
    p.add_argument(
        "--compile-cache",
        metavar="DIR",
        help=f"JAX persistent compilation cache, so that {so_that} (default "
        "$JAX_COMPILATION_CACHE_DIR, else $XDG_CACHE_HOME/legs_jax/jax or "
        "~/.cache/legs_jax/jax; 'off' disables)",
    )


def quiet_arg(p: argparse.ArgumentParser) -> None:
    """``--quiet``: no progress bar."""
    p.add_argument("--quiet", action="store_true", help="no progress bar")


def out_arg(p: argparse.ArgumentParser, default: str, help: str) -> None:
    """``--out FILE`` (a path, ``default`` when not given)."""
    p.add_argument("--out", type=Path, default=Path(default), help=help)
