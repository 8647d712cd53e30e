"""candump -L lines of a block parsed in one compiled pass (numba): the bulk reader's front.

``vdp.io.bulk`` parses a block with numpy, a few dozen whole-array passes over its bytes
(splitting, fields, digits, hex), which cost ~0.4 us a line: over half of what reading,
decoding and aligning a log costs.  :func:`lines` does the same in one loop over the bytes,
with the same rules: any line they do not accept makes the whole log the per-frame reader's
(``Irregular``), so this parser may only be as strict as numpy's or stricter, never laxer.
``tests/test_scan.py`` holds the two to the same arrays, line for line (a simulated log and
the real RAV4's), and to the same verdicts on irregular lines.

Without numba the numpy parse runs (:func:`available`).
"""

from __future__ import annotations

import logging
import threading

import numpy as np

log = logging.getLogger(__name__)

# what the numpy parse says for each rule a line breaks (bulk.BulkSource._block)
MESSAGES = (
    "",
    "a line with only a carriage return",
    "tabs or other whitespace between fields",
    "a line without 3 or 4 fields",
    "a 4th field that is not a direction",
    "a line not '(time) channel id#data'",
    "a timestamp without a decimal point",
    "a timestamp that is not plain digits",
    "a timestamp with too many digits",
    "a frame that is not a plain data frame (remote, FD, raw DLC or bad hex)",
    "an error frame or an id out of range",
    "a channel name longer than 8 characters",
)
(OK, ONLY_CR, WHITESPACE, FIELDS, DIRECTION, SHAPE, NO_DOT, DIGITS, TOO_LONG, NOT_DATA, ID_RANGE, CHANNEL) = range(
    len(MESSAGES)
)

# logs.EXT_KEY, an extended id's key, as a copy: numba freezes a global into the cached code and
# invalidates that cache only when this file changes (tests/test_scan.py holds the two equal)
_EXT_KEY = 1 << 31
_POW10 = np.array([10.0**k for k in range(19)])  # exact: 10**k is a double up to k = 22
_MAX_EXACT = float(1 << 53)  # N / 10**k is the correctly rounded decimal only below this
# hex digit values by byte (255: not a hex digit); numpy's parse (vdp.io.bulk) reads the same table
_HEX = np.full(256, 255, np.uint8)
for _i, _c in enumerate(b"0123456789"):
    _HEX[_c] = _i
for _i, _c in enumerate(b"abcdef"):
    _HEX[_c] = 10 + _i
    _HEX[_c - 32] = 10 + _i


def _line(a, s, e, hexv, pow10, n, line_no, ts, key, data, dlc, ch_code, ch_lo, ch_hi):
    """Parse the line a[s:e] (no newline, no carriage return) into row ``n``; its rule code."""
    n_bytes = a.shape[0]
    # fields: "(ts) channel id#data [R|T]", single spaces
    sp1 = sp2 = sp3 = -1
    count = 0
    for i in range(s, e):
        if a[i] == 32:
            count += 1
            if count == 1:
                sp1 = i
            elif count == 2:
                sp2 = i
            elif count == 3:
                sp3 = i
    if count != 2 and count != 3:  # noqa: PLR1714 (numba: no set literals)
        return FIELDS
    if count == 3:
        d = a[sp3 + 1] if sp3 + 1 < e else 0
        if e - sp3 != 2 or not (d == 82 or d == 114 or d == 84 or d == 116):  # noqa: PLR1714 (R r T t; numba: no set literals)
            return DIRECTION
    else:
        sp3 = e
    if not (a[s] == 40 and a[sp1 - 1] == 41 and sp2 > sp1 + 1 and sp3 > sp2 + 1):
        return SHAPE
    # time stamp: digits '.' digits, at most 18 of them, the value exact in a double
    dot = -1
    for i in range(s, n_bytes):  # the first dot at or after the line's start (numpy's searchsorted)
        if a[i] == 46:
            dot = i
            break
    if dot < 0 or not dot < sp1 - 1:
        return NO_DOT
    li, lf = dot - s - 1, sp1 - 2 - dot
    if not (li >= 1 and li + lf <= 18 and lf >= 0):
        return DIGITS
    num = 0
    for i in range(s + 1, sp1 - 1):
        if i != dot:
            dg = np.int64(a[i]) - 48
            if dg < 0 or dg > 9:
                return DIGITS
            num = num * 10 + dg
    if num >= _MAX_EXACT:
        return TOO_LONG
    # id#data
    h = -1
    for i in range(sp2, n_bytes):  # the first '#' at or after the second space
        if a[i] == 35:
            h = i
            break
    id_len, dlen = h - sp2 - 1, sp3 - h - 1
    if not (h >= 0 and h < sp3 and (id_len == 3 or id_len == 8) and dlen % 2 == 0 and dlen <= 16):  # noqa: PLR1714 (numba: no set literals)
        return NOT_DATA
    aid = 0
    for i in range(sp2 + 1, h):
        v = hexv[a[i]]
        if v > 15:
            return NOT_DATA
        aid = aid * 16 + np.int64(v)
    ext = id_len == 8
    if (not ext and aid > 0x7FF) or (ext and aid > 0x1FFFFFFF):
        return ID_RANGE
    for j in range(8):
        data[n, j] = 0
    for j in range(dlen // 2):
        hi, lo = hexv[a[h + 1 + 2 * j]], hexv[a[h + 2 + 2 * j]]
        if hi > 15 or lo > 15:
            return NOT_DATA
        data[n, j] = (hi << 4) | lo
    # channel: up to 8 bytes, packed little-endian into one code
    if sp2 - sp1 - 1 > 8:
        return CHANNEL
    code = np.uint64(0)
    for j in range(sp2 - sp1 - 1):
        code |= np.uint64(a[sp1 + 1 + j]) << np.uint64(8 * j)
    ts[n] = np.float64(num) / pow10[lf]
    key[n] = aid | _EXT_KEY if ext else aid
    dlc[n] = dlen // 2
    ch_code[n] = code
    ch_lo[n], ch_hi[n] = sp1 + 1, sp2
    return OK


def _scan(a, hexv, pow10):
    """Every non-empty line of ``a`` (bytes ending in a newline), parsed.

    Returns (code, line of the first rule broken (1-based within the block; 0: none), lines
    in the block, then per non-empty line: its line number, time stamp, key, 8 data bytes,
    dlc, channel code and the channel name's byte span).  On a broken rule the arrays are
    empty.  The rules, in the numpy parse's words (MESSAGES), are checked line by line.
    """
    n_bytes = a.shape[0]
    cap = 0
    white = False
    for i in range(n_bytes):
        c = a[i]
        if c == 10:
            cap += 1
        elif c == 9 or c == 11 or c == 12:  # noqa: PLR1714 (numba: no set literals)
            white = True
    line_no = np.empty(cap, np.int64)
    ts = np.empty(cap, np.float64)
    key = np.empty(cap, np.int64)
    data = np.empty((cap, 8), np.uint8)
    dlc = np.empty(cap, np.int64)
    ch_code = np.empty(cap, np.uint64)
    ch_lo = np.empty(cap, np.int64)
    ch_hi = np.empty(cap, np.int64)
    err, err_line, n, line, start = OK, 0, 0, 0, 0
    if white:
        err = WHITESPACE
    for end in range(n_bytes):
        if err != OK:
            break
        if a[end] != 10:
            continue
        line += 1
        s, e = start, end
        start = end + 1
        if e > s and a[e - 1] == 13:
            e -= 1
            if e == s:
                err, err_line = ONLY_CR, line
                break
        if e == s:
            continue  # an empty line: counted, not a frame
        code = _line(a, s, e, hexv, pow10, n, line_no, ts, key, data, dlc, ch_code, ch_lo, ch_hi)
        if code != OK:
            err, err_line = code, line
            break
        line_no[n] = line
        n += 1
    if err != OK:
        n = 0
    return err, err_line, cap, line_no[:n], ts[:n], key[:n], data[:n], dlc[:n], ch_code[:n], ch_lo[:n], ch_hi[:n]


_compiled: list = []  # [the compiled _scan], or [None] without numba
_making = threading.Lock()  # replays starting at once in one process (a Dask worker's threads) compile once


def _kernel():
    """The compiled scan, made at first use (or loaded from numba's cache beside this file):
    ``import vdp.io.bulk`` does not import numba."""
    global _line  # noqa: PLW0603 (rebound once to its compiled self, which the compiled scan calls)
    if _compiled:
        return _compiled[0]
    with _making:  # numba refuses to compile an already compiled _line a second time
        if not _compiled:
            try:
                from numba import njit
            except ImportError:  # numba is a dependency; without it bulk parses with numpy
                _compiled.append(None)
            else:
                # the compiled scan calls the compiled line parser, inlined (a call per line cost ~40 %)
                _line = njit(cache=True, nogil=True, inline="always")(_line)
                _compiled.append(njit(cache=True, nogil=True)(_scan))
    return _compiled[0]


def available() -> bool:
    """Whether the compiled parse runs here (numba imports)."""
    return _kernel() is not None


def lines(buf: bytes):
    """(code, line, lines in the block, arrays...) of :func:`_scan` over ``buf``, compiled."""
    return _kernel()(np.frombuffer(buf, np.uint8), _HEX, _POW10)


def warm() -> None:
    """Compile (or load from the cache) the parse once, before any log needs it."""
    if available():
        lines(b"(1.000000) can0 123#00\n")
