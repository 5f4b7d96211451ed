"""Errors said in one line (every command's messages go through here)."""

from __future__ import annotations


def error_text(error: BaseException, limit: int | None = 200) -> str:
    """An error's text on one line (at most `limit` characters; None: all of it), or its type's name when it
    has none."""
    return " ".join(str(error).split())[:limit] or type(error).__name__
