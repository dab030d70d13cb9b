"""Errors of the online session: each has a one-line message for the user."""

from __future__ import annotations

__all__ = ["InputError", "OrderError", "StateError"]


class InputError(ValueError):
    """Bad input (an image of the wrong shape, NaN or empty depth, no object in
    view, bad intrinsics); the session is unchanged."""


class OrderError(RuntimeError):
    """A call out of order (``tell`` without ``ask``, ``ask`` before
    ``observe``); the session is unchanged."""


class StateError(RuntimeError):
    """A state folder that cannot be used: corrupt, foreign, or already a
    session when a new one was asked for."""
