"""Hypothesis strategies that break a valid file's bytes the ways files do break: cut short, a slice lost or
repeated, NUL bytes, bytes that are not UTF-8, stray bytes spliced in."""

from __future__ import annotations

from hypothesis import strategies as st

NOT_UTF8 = (b"\xff", b"\xc3", b"\xe2\x82", b"\xed\xa0\x80", b"\xf8\x88\x80\x80\x80")  # lone lead, cut, surrogate, 5-byte


@st.composite
def broken_bytes(draw: st.DrawFn, valid: bytes, junk: tuple[bytes, ...] = ()) -> bytes:
    """`valid` broken at a drawn place in one drawn way (or two, applied in turn); `junk` adds tokens a format's
    reader may stumble on (a huge number, a separator), inserted as one more way."""
    data = valid
    ways = ("truncate", "drop", "repeat", "nul", "not_utf8", "splice") + (("junk",) if junk else ())
    for _ in range(draw(st.integers(1, 2))):
        at = draw(st.integers(0, len(data)))
        end = draw(st.integers(at, len(data)))
        how = draw(st.sampled_from(ways))
        if how == "truncate":
            data = data[:at]
        elif how == "drop":
            data = data[:at] + data[end:]
        elif how == "repeat":
            data = data[:end] + data[at:end] * draw(st.integers(1, 3)) + data[end:]
        elif how == "nul":
            data = data[:at] + b"\x00" + data[at:]
        elif how == "not_utf8":
            data = data[:at] + draw(st.sampled_from(NOT_UTF8)) + data[at:]
        elif how == "junk":
            data = data[:at] + draw(st.sampled_from(junk)) + data[at:]
        else:
            data = data[:at] + draw(st.binary(min_size=1, max_size=8)) + data[end:]
    return data
