"""The one property every fuzz test asserts: a result, or the project's own one-line error naming the file."""

from __future__ import annotations

from collections.abc import Callable
from typing import TypeVar

T = TypeVar("T")


def result_or_one_line_error(read: Callable[[], T], errors: type[BaseException] | tuple[type[BaseException], ...],
                             names: str | tuple[str, ...]) -> T | None:
    """Call `read`; return its result, or None when it raised one of `errors` whose message is a single line
    naming one of `names` (a file name or path). Any other exception type, or a message without the file,
    fails the test (it propagates, or the assertion says why)."""
    names = (names,) if isinstance(names, str) else names
    try:
        return read()
    except errors as error:
        message = str(error)
        assert "\n" not in message.strip(), f"a multi-line error: {message!r}"
        assert any(name in message for name in names), f"the error names none of {names}: {message!r}"
        return None
