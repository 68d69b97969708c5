"""The demo's one error: a one-line reason it cannot go on."""

from __future__ import annotations


class DemoError(Exception):
    """A one-line reason the demo cannot go on."""
