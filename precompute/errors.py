"""The one error precompute raises on bad input."""

from __future__ import annotations

__all__ = ["PrecomputeError"]


class PrecomputeError(ValueError):
    """Bad input to precompute: a mesh that cannot be used, an unknown object, bad
    options. The message is one line and names the file or option at fault; the CLI
    prints it without a traceback and exits with status 2."""
