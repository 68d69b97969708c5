"""The bench's one error: a one-line reason it cannot go on."""

from __future__ import annotations


class BenchError(Exception):
    """One line for the user."""
