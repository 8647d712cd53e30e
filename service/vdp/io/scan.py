"""candump -L lines parsed in one compiled pass over a block's bytes: the one candump parser.

Both readers of candump logs parse with :func:`_scan`: the bulk reader (``vdp.io.bulk``)
asks for a block's lines and gives the log to the per-frame reader at the first line the
scan refuses (``stop``); the per-frame reader (``vdp.io.formats.candump``) asks for every
line's verdict and reads only the refused ones (remote, FD and error frames, damage) by its
own tolerant rules.  A line the scan accepts is read exactly as those rules would read it
(``tests/test_scan.py`` holds the two to that, line by line, and the compiled scan to the
same source run as Python).

Compiled with numba where it imports (:func:`available`); without it the per-frame reader
reads every line by its own rules and the bulk reader steps aside.
"""

from __future__ import annotations

import logging
import sys
import threading
import types

import numpy as np

log = logging.getLogger(__name__)

# what the bulk reader says for each rule a line breaks (bulk.BulkSource._block)
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
    "a channel name longer than 8 characters or with a NUL byte",
    "an empty line",
)
(
    OK,
    ONLY_CR,
    WHITESPACE,
    FIELDS,
    DIRECTION,
    SHAPE,
    NO_DOT,
    DIGITS,
    TOO_LONG,
    NOT_DATA,
    ID_RANGE,
    CHANNEL,
    EMPTY,
) = range(len(MESSAGES))

# logs.EXT_KEY, an extended id's key, as a copy: numba freezes a global into the cached code and
# invalidates that cache only when this file changes (tests/test_scan.py holds the two equal)
_EXT_KEY = 1 << 31
_POW10 = np.array([10.0**k for k in range(19)])  # exact: 10**k is a double up to k = 22
_MAX_EXACT = float(1 << 53)  # N / 10**k is the correctly rounded decimal only below this
# hex digit values by byte (255: not a hex digit)
_HEX = np.full(256, 255, np.uint8)
for _i, _c in enumerate(b"0123456789"):
    _HEX[_c] = _i
for _i, _c in enumerate(b"abcdef"):
    _HEX[_c] = 10 + _i
    _HEX[_c - 32] = 10 + _i


def pack(b: bytes) -> int:
    """Up to 8 bytes as one number, little-endian: the scan's channel and id codes."""
    return int.from_bytes(b, "little")


def _line(a, s, e, hexv, pow10, n, ts, key, idc, data, dlc, ch_code, ch_lo, ch_hi, rx):
    """Parse the line a[s:e] (no newline, no final carriage return) into row ``n``; its rule code.

    Accepts only what ``bytes.split()`` cuts into the same fields, ``float()`` reads to the
    same time and ``unhexlify`` to the same bytes: the per-frame reader's reading of the line.
    """
    n_bytes = a.shape[0]
    # fields: "(ts) channel id#data [R|T]", single spaces; any other whitespace (split() cuts
    # at a tab or a carriage return too) is the per-frame reader's to judge
    sp1 = sp2 = sp3 = -1
    count = 0
    white = False
    for i in range(s, e):
        c = a[i]
        if c == 32:
            count += 1
            if count == 1:
                sp1 = i
            elif count == 2:
                sp2 = i
            elif count == 3:
                sp3 = i
        elif c == 9 or c == 11 or c == 12 or c == 13:  # noqa: PLR1714 (numba: no set literals)
            white = True
    if white:
        return WHITESPACE
    if count != 2 and count != 3:  # noqa: PLR1714 (numba: no set literals)
        return FIELDS
    r = 1
    if count == 3:
        d = a[sp3 + 1] if sp3 + 1 < e else 0
        if e - sp3 != 2 or not (d == 82 or d == 114 or d == 84 or d == 116):  # noqa: PLR1714 (R r T t; numba: no set literals)
            return DIRECTION
        r = 1 if d == 82 or d == 114 else 0  # noqa: PLR1714 (numba: no set literals)
    else:
        sp3 = e
    if not (a[s] == 40 and a[sp1 - 1] == 41 and sp2 > sp1 + 1 and sp3 > sp2 + 1):
        return SHAPE
    # time stamp: digits '.' digits, at most 18 of them, the value exact in a double
    dot = -1
    for i in range(s, n_bytes):  # the first dot at or after the line's start
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
    spelled = np.uint64(0)
    for j in range(id_len):
        c = a[sp2 + 1 + j]
        v = hexv[c]
        if v > 15:
            return NOT_DATA
        aid = aid * 16 + np.int64(v)
        spelled |= np.uint64(c) << np.uint64(8 * j)
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
    # channel: up to 8 bytes, packed little-endian into one code (a NUL byte would make two
    # names one code)
    if sp2 - sp1 - 1 > 8:
        return CHANNEL
    code = np.uint64(0)
    for j in range(sp2 - sp1 - 1):
        c = a[sp1 + 1 + j]
        if c == 0:
            return CHANNEL
        code |= np.uint64(c) << np.uint64(8 * j)
    ts[n] = np.float64(num) / pow10[lf]
    key[n] = aid | _EXT_KEY if ext else aid
    idc[n] = spelled
    dlc[n] = dlen // 2
    ch_code[n] = code
    ch_lo[n], ch_hi[n] = sp1 + 1, sp2
    rx[n] = r
    return OK


def _scan(a, hexv, pow10, stop):
    """The lines of ``a`` (bytes ending in a newline), parsed.

    ``stop``: stop at the first line that breaks a rule; the rows are then the non-empty
    lines up to it.  Otherwise one row per line, each with its rule code (EMPTY for an empty
    line; a row's fields are set only where its code is OK).

    Returns (code, line of the first rule broken (1-based within the block; 0: none), lines
    in the block, then per row: its rule code, the line's byte span (without its newline),
    its line number, time stamp, key, id spelling, 8 data bytes, dlc, channel code, the
    channel name's byte span and 1 for a received frame).  With ``stop``, on a broken rule the
    arrays are empty.
    """
    n_bytes = a.shape[0]
    cap = 0
    for i in range(n_bytes):
        if a[i] == 10:
            cap += 1
    codes = np.zeros(cap, np.uint8)
    lo = np.zeros(cap, np.int64)
    hi = np.zeros(cap, np.int64)
    line_no = np.zeros(cap, np.int64)
    ts = np.zeros(cap, np.float64)
    key = np.zeros(cap, np.int64)
    idc = np.zeros(cap, np.uint64)
    data = np.zeros((cap, 8), np.uint8)
    dlc = np.zeros(cap, np.int64)
    ch_code = np.zeros(cap, np.uint64)
    ch_lo = np.zeros(cap, np.int64)
    ch_hi = np.zeros(cap, np.int64)
    rx = np.zeros(cap, np.uint8)
    err, err_line, n, line, start = OK, 0, 0, 0, 0
    for end in range(n_bytes):
        if a[end] != 10:
            continue
        line += 1
        s, e = start, end
        start = end + 1
        cr = e > s and a[e - 1] == 13
        if cr:
            e -= 1
        if e > s:
            code = _line(a, s, e, hexv, pow10, n, ts, key, idc, data, dlc, ch_code, ch_lo, ch_hi, rx)
        else:
            code = ONLY_CR if cr else EMPTY
        if stop:
            if code == EMPTY:
                continue  # counted, not a frame
            if code != OK:
                err, err_line = code, line
                break
        codes[n] = code
        lo[n], hi[n] = s, end
        line_no[n] = line
        n += 1
    if err != OK:
        n = 0
    return (
        err,
        err_line,
        cap,
        codes[:n],
        lo[:n],
        hi[:n],
        line_no[:n],
        ts[:n],
        key[:n],
        idc[:n],
        data[:n],
        dlc[:n],
        ch_code[:n],
        ch_lo[:n],
        ch_hi[:n],
        rx[:n],
    )


_compiled: list = []  # [the compiled _scan], or [None] without numba
_making = threading.Lock()  # replays starting at once in one process (a Dask worker's threads) compile once


def _kernel():
    """The compiled scan, made at first use (or loaded from numba's cache beside this file):
    ``import vdp.io.bulk`` does not import numba.  :func:`_scan` itself stays Python, the
    reference the tests run."""
    if _compiled:
        return _compiled[0]
    with _making:
        if not _compiled:
            try:
                from numba import njit
            except ImportError:  # numba is a dependency; without it no compiled parse
                _compiled.append(None)
            else:
                # the compiled scan calls the compiled line parser, inlined (a call per line cost ~40 %);
                # it is _scan's own code with _line bound to that in its globals
                ns = dict(globals())
                ns["_line"] = njit(cache=True, nogil=True, inline="always")(_line)
                fn = types.FunctionType(_scan.__code__, ns, "_scan", _scan.__defaults__)
                fn.__qualname__ = _scan.__qualname__
                fn.__module__ = __name__
                _compiled.append(njit(cache=True, nogil=True)(fn))
    return _compiled[0]


def available() -> bool:
    """Whether the compiled parse runs here (numba imports)."""
    return _kernel() is not None


PAYS_FROM = 1 << 22  # bytes (~90,000 lines): a log this long pays for loading numba (~0.8 s of CPU) itself


def pays(size: int) -> bool:
    """Whether a log of ``size`` bytes is parsed by the compiled scan: where numba is loaded
    already (a replay's compiled estimator loads it for its own use), or the log is long
    enough to pay for loading it; and numba imports.  The frames are the same either way (the
    scan reads a line only as the per-frame reader's tolerant rules read it): a short log's
    replay then starts without numba's fixed cost, when nothing else needs it."""
    return ("numba" in sys.modules or size >= PAYS_FROM) and available()


def lines(buf: bytes, stop: bool = True):
    """:func:`_scan` over ``buf``, compiled."""
    return _kernel()(np.frombuffer(buf, np.uint8), _HEX, _POW10, stop)


def reference(buf: bytes, stop: bool = True):
    """:func:`_scan` over ``buf``, run as Python: the compiled parse's reference (slow)."""
    return _scan(np.frombuffer(buf, np.uint8), _HEX, _POW10, stop)


def warm() -> None:
    """Compile (or load from the cache) the parse once, before any log needs it."""
    if available():
        lines(b"(1.000000) can0 123#00\n", True)
        lines(b"(1.000000) can0 123#00\n", False)
