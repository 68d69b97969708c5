"""How ``inject`` fails: one line, no traceback."""

from __future__ import annotations


class InjectError(Exception):
    """A one-line failure of ``inject`` (printed without a traceback, exit 1)."""


class Unviolable(InjectError):
    """No publishable trace violates the requirement (``--all`` skips it, says why)."""
