"""Errors of the simulated world and its datasets."""

from __future__ import annotations


class SimError(Exception):
    """Base of the simulated world's errors."""


class SimInputError(SimError, ValueError):
    """A caller passed a bad argument; the message names it and the reason."""
