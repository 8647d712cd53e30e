"""Names (a vehicle's, a file's) put into the text of other formats, escaped for each.

A name comes from the user (a profile, a hand-edited result, a command line): it may hold a
quote, a newline, a ``$`` or a lone surrogate (JSON's "\\ud800").  Written in as it is, it
broke the TOML or YAML around it or added a line to it: a TOML string escapes it, a comment or
a title takes it on one line.
"""

from __future__ import annotations

import unicodedata

_SHORT = {"\b": "\\b", "\t": "\\t", "\n": "\\n", "\f": "\\f", "\r": "\\r", '"': '\\"', "\\": "\\\\"}


def clean(s: object) -> str:
    """``s`` as text that can be written as UTF-8: a lone surrogate becomes U+FFFD."""
    text = str(s)
    return "".join("\ufffd" if 0xD800 <= ord(c) <= 0xDFFF else c for c in text)


def _odd(c: str) -> bool:
    """A character no format here takes raw: controls (C0, DEL, C1), line and paragraph
    separators, and U+FFFE/FFFF (a YAML reader refuses the stream for them)."""
    return unicodedata.category(c) in ("Cc", "Zl", "Zp") or c in "\ufffe\uffff"


def toml_str(s: object) -> str:
    """A TOML basic string (TOML 1.0: quote, backslash and controls escaped)."""
    return '"' + "".join(_SHORT.get(c) or (f"\\u{ord(c):04X}" if _odd(c) else c) for c in clean(s)) + '"'


def one_line(s: object) -> str:
    """``s`` on one line, for a comment or a title: each control or line break a space."""
    return "".join(" " if _odd(c) else c for c in clean(s))
