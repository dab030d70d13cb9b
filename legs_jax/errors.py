"""Errors raised by legs_jax for invalid user input."""

from __future__ import annotations

__all__ = ["ConfigError"]


class ConfigError(ValueError):
    """An invalid configuration: an unknown method, a hyperparameter outside its
    range, or a problem that does not fit the request.

    Raised before any computation, with a one-line message that names the
    offending value and what is allowed.
    """
