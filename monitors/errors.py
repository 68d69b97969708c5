"""User-facing errors: always ``FILE:LINE[:COL]: message`` plus an optional hint.

Every stage raises UserError for bad input; the CLI prints ``str(err)`` and exits 1.
Nothing user-caused may surface as a Python traceback.
"""

from __future__ import annotations


class UserError(Exception):
    def __init__(
        self,
        message: str,
        *,
        file: str = "<input>",
        line: int | None = None,
        col: int | None = None,
        hint: str | None = None,
    ) -> None:
        super().__init__(message)
        self.message = message
        self.file = file
        self.line = line
        self.col = col
        self.hint = hint

    def location(self) -> str:
        loc = self.file
        if self.line is not None:
            loc += f":{self.line}"
            if self.col is not None:
                loc += f":{self.col}"
        return loc

    def __str__(self) -> str:
        text = f"{self.location()}: {self.message}"
        if self.hint:
            text += f" (hint: {self.hint})"
        return text

    def at(self, file: str, line: int | None, col: int | None = None) -> UserError:
        """Re-anchor an error raised on a fragment (e.g. one requirement's text)
        to its place in a file; a column inside the fragment is kept relative
        to the fragment's own start column ``col``."""
        if line is not None:
            if self.line is not None and self.line > 1:
                new_line, new_col = line + self.line - 1, self.col
            else:
                new_line = line
                new_col = (col or 1) + (self.col or 1) - 1 if self.col is not None else col
            self.line, self.col = new_line, new_col
        self.file = file
        return self
