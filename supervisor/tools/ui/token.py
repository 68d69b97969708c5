"""The UI's bearer token: where ``install-service`` puts it, how it is made and read.

The token authorises state changes from the page (resets); the page asks the
operator for it once.  docs/reference/commands.md, ``ui``.
"""

from __future__ import annotations

import secrets
from pathlib import Path

from monitors.errors import UserError

TOKEN_FILE = Path("/etc/safety-supervisor/ui.token")
TOKEN_MODE = 0o640  # root:<service group>: the UI's user reads it, operators get it from root
MIN_TOKEN_CHARS = 16  # a guessable token would make the page's resets open to anyone


def new_token() -> bytes:
    """A fresh token file's content: 256 random bits, URL-safe, one line."""
    return secrets.token_urlsafe(32).encode() + b"\n"


def read_token(path: Path) -> bytes:
    """The token in ``path`` (surrounding whitespace dropped); a UserError naming
    the file when it cannot be read or is too short."""
    try:
        mode = path.stat().st_mode
        token = path.read_bytes().strip()
    except OSError as e:
        raise UserError(f"cannot read the token: {e.strerror or e}", file=str(path)) from None
    if mode & 0o006:
        # a token every local user can read gives every local user the resets
        raise UserError(
            "the token is readable or writable by every user",
            file=str(path),
            hint=f"chmod {TOKEN_MODE:04o} {path}",
        )
    if len(token) < MIN_TOKEN_CHARS:
        raise UserError(
            f"the token is shorter than {MIN_TOKEN_CHARS} characters",
            file=str(path),
            hint="python3 -c 'import secrets; print(secrets.token_urlsafe(32))' > FILE",
        )
    return token
