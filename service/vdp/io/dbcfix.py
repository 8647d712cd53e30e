"""Load a DBC, repairing the small syntax faults that make cantools refuse real-world files.

cantools parses strictly (its grammar, then a consistency check), while the DBCs
carmakers and openpilot ship are written for tools that are more forgiving.  The
faults seen in the opendbc package (0.3.x), each repaired in text before parsing:

- a message comment without its ``BO_`` keyword (``CM_ 145 "..."``) or a signal
  comment without its signal name (``CM_ SG_ 304 "..."``): becomes a message comment;
- a database comment (``CM_ "..."``) between the messages: dropped;
- a number written without its leading zero (``(.25,-500)``): ``0.25``;
- an id above 11 bits without the extended flag (bit 31): the flag is set, as the
  bus can only carry such an id as an extended frame;
- a message or signal name that starts with a digit (``2017_5``): prefixed with ``_``;
- a value table (``VAL_``) of a signal the file does not define: dropped.

Signals that overlap, or other consistency faults, are accepted by loading with
``strict=False``.  :func:`load` says once per file which repairs it made (a warning
naming the file and the reasons); a file that still does not parse is a
:class:`~vdp.errors.ProfileError` naming the file, cantools' reason and the fix.
"""

from __future__ import annotations

import logging
import re
from pathlib import Path

import cantools

from ..errors import ProfileError

log = logging.getLogger(__name__)

_BARE_MSG_COMMENT = re.compile(r'^CM_ (\d+) "', re.MULTILINE)
_NAMELESS_SIG_COMMENT = re.compile(r'^CM_ SG_ (\d+) "', re.MULTILINE)
_DB_COMMENT = re.compile(r'^CM_ "[^"]*";[ \t]*\r?\n', re.MULTILINE)
_NO_SEMI = re.compile(r'^((?:CM_|VAL_) [^\n]*")[ \t]*$', re.MULTILINE)
_LEADING_DOT = re.compile(r"(?<=[(,\[|])(-?)\.(\d)")
_BO = re.compile(r"^BO_ (\d+) (\w+)\s*:", re.MULTILINE)
_SG = re.compile(r"^[ \t]+SG_ (\w+)\b", re.MULTILINE)
_ID_REF = re.compile(r"\b(BO_|SG_|VAL_|SIG_VALTYPE_|BO_TX_BU_|SG_MUL_VAL_) (\d+)\b")
_VAL = re.compile(r"^VAL_ (\d+) (\w+) .*?;[ \t]*\r?\n", re.MULTILINE)
_EXT = 0x80000000

_warned: set[str] = set()


def repair(text: str) -> tuple[str, list[str]]:
    """``text`` with the faults above repaired, and one reason per kind of repair made."""
    reasons: list[str] = []

    def sub(pattern: re.Pattern, repl, s: str, why: str) -> str:
        out, n = pattern.subn(repl, s)
        if n:
            reasons.append(f"{why} ({n}x)")
        return out

    text = sub(_NO_SEMI, _semicolon, text, "comment or value table without its closing ';'")
    text = sub(_BARE_MSG_COMMENT, r'CM_ BO_ \1 "', text, "message comment without BO_")
    text = sub(_NAMELESS_SIG_COMMENT, r'CM_ BO_ \1 "', text, "signal comment without a signal name")
    last_bo = max((m.start() for m in _BO.finditer(text)), default=-1)
    db_comments = [m for m in _DB_COMMENT.finditer(text) if m.start() < last_bo]
    if db_comments:
        for m in reversed(db_comments):
            text = text[: m.start()] + text[m.end() :]
        reasons.append(f"database comment between the messages dropped ({len(db_comments)}x)")
    text = sub(_LEADING_DOT, r"\g<1>0.\2", text, "number without its leading zero")
    # ids above 11 bits must be extended
    ids = {int(m.group(1)) for m in _BO.finditer(text)}
    fix = {i: i | _EXT for i in ids if 0x7FF < i < _EXT}
    if fix:
        text = _ID_REF.sub(lambda m: f"{m.group(1)} {fix.get(int(m.group(2)), int(m.group(2)))}", text)
        reasons.append(f"id above 11 bits without the extended flag ({len(fix)}x)")
    # ids beyond 29 bits cannot be on a bus at all: drop those messages
    ids = {int(m.group(1)) for m in _BO.finditer(text)}
    drop = {i for i in ids if (i & ~_EXT) > 0x1FFFFFFF}
    if drop:
        text = _drop_messages(text, drop)
        reasons.append(f"message with an id beyond 29 bits dropped ({len(drop)}x)")
    # names that start with a digit
    names = {m.group(2) for m in _BO.finditer(text)} | {m.group(1) for m in _SG.finditer(text)}
    bad = sorted(n for n in names if n[0].isdigit())
    if bad:
        pat = re.compile(r"(?<![\w.])(" + "|".join(re.escape(n) for n in bad) + r")\b")
        text = pat.sub(r"_\1", text)
        reasons.append(f"name starting with a digit prefixed with '_' ({', '.join(bad[:5])})")
    # value tables of signals that do not exist
    sigs: set[tuple[int, str]] = set()
    msg_id = None
    for line in text.splitlines():
        m = _BO.match(line)
        if m:
            msg_id = int(m.group(1))
            continue
        s = _SG.match(line)
        if s and msg_id is not None:
            sigs.add((msg_id, s.group(1)))
        elif line.strip() and not line[0].isspace():
            msg_id = None
    orphans = [m for m in _VAL.finditer(text) if (int(m.group(1)), m.group(2)) not in sigs]
    if orphans:
        for m in reversed(orphans):
            text = text[: m.start()] + text[m.end() :]
        reasons.append(
            f"value table of an undefined signal dropped ({', '.join(m.group(2) for m in orphans[:5])}"
            f"{' ...' if len(orphans) > 5 else ''})"
        )
    return text, reasons


def _semicolon(m: re.Match) -> str:
    line = m.group(1)
    return f"{line} ;" if line.count('"') % 2 == 0 else m.group(0)


def _drop_messages(text: str, ids: set[int]) -> str:
    out, skip, in_comment = [], False, False
    for line in text.splitlines(keepends=True):
        if in_comment:  # the rest of a dropped multi-line comment
            in_comment = line.count('"') % 2 == 0
            continue
        m = _BO.match(line)
        if m:
            skip = int(m.group(1)) in ids
        elif skip and line[:1].isspace() and line.strip():
            continue  # a signal of a dropped message
        else:
            skip = False if line.strip() else skip
        if skip and m:
            continue
        ref = _ID_REF.search(line)
        if ref and not m and int(ref.group(2)) in ids and not line[:1].isspace():
            in_comment = line.count('"') % 2 == 1
            continue
        out.append(line)
    return "".join(out)


def first_line(exc: Exception) -> str:
    s = " ".join(str(exc).split())
    return (s[:200] + " ...") if len(s) > 200 else (s or type(exc).__name__)


def load(path: str | Path, where: str = "") -> cantools.database.can.Database:
    """The CAN database in ``path``, repaired if cantools cannot parse it as it is."""
    path = Path(path)
    pre = f"{where}: " if where else ""
    if path.suffix.lower() != ".dbc":  # .kcd, .arxml, .sym: cantools' own loaders, no repairs
        try:
            db = cantools.database.load_file(str(path), strict=False)
        except Exception as exc:
            raise ProfileError(f"{pre}cannot load {path}: {first_line(exc)}") from None
        if not isinstance(db, cantools.database.can.Database):
            raise ProfileError(f"{pre}{path} is not a CAN database")
        return db
    try:
        text = path.read_text(encoding="utf-8", errors="replace")
    except OSError as exc:
        raise ProfileError(f"{pre}cannot read DBC {path}: {exc.strerror or exc}") from None
    try:
        db = cantools.database.load_string(text, database_format="dbc", strict=False)
    except Exception as exc:  # cantools raises parser-specific errors of many types
        fixed, reasons = repair(text)
        if not reasons:
            raise ProfileError(
                f"{pre}cannot load DBC {path}: {first_line(exc)}; fix that line of the file "
                f"(cantools' DBC grammar), or give a DBC that cantools loads"
            ) from None
        try:
            db = cantools.database.load_string(fixed, database_format="dbc", strict=False)
        except Exception as exc2:
            raise ProfileError(
                f"{pre}cannot load DBC {path}, even after repairing {'; '.join(reasons)}: "
                f"{first_line(exc2)}; fix that line of the file (cantools' DBC grammar)"
            ) from None
        key = str(path.resolve())
        if key not in _warned:
            _warned.add(key)
            log.warning(
                "DBC %s does not parse as it is (%s); loaded with repairs: %s",
                path,
                first_line(exc),
                "; ".join(reasons),
            )
    if not isinstance(db, cantools.database.can.Database):
        raise ProfileError(f"{pre}{path} is not a CAN database")
    return db
