"""Frames -> signal values: the bit-level half of decoding, apart from channel mapping.

A decoder (:class:`vdp.io.decoder.FrameDecoder`, :mod:`vdp.io.bulk`) asks for the signals
a message must yield and gets a function ``data -> (error kind or None, value1, ...)``:
generated Python for plain integer signals (:func:`compile_extractor`: shifts and masks on
one ``int.from_bytes``, about 3x faster than ``cantools.Message.decode``), cantools for
multiplexed messages and float signals (:func:`cantools_extractor`).  Each value is checked
against its DBC range (:func:`limits`) or the profile's override of it.  What the values
mean (units, signs, channels) is the decoder's business, not this module's.
"""

from __future__ import annotations

import logging
import math
from collections.abc import Callable, Sequence
from typing import Any

from cantools.database.errors import DecodeError as _CantoolsDecodeError

from ..errors import ProfileError
from ..units import UNIT_FACTORS

log = logging.getLogger(__name__)


def nothing(data: Any) -> tuple:
    """The extractor of a message not built yet: no error, no value."""
    return (None,)


def limits(msg: Any, sig: Any) -> tuple[float, float]:
    """The [minimum, maximum] a decoded value is checked against (±inf where the DBC has none).

    Decoded values are raw*scale+offset in floating point, so allow a sliver
    (1/1000 of a step) past the limits.  A DBC range that the bit field cannot
    even reach on one side (opendbc's Toyota KINEMATICS has [0|65535] on a
    10-bit signal of about ±18 m/s^2) is not a physical range: it is ignored.
    """
    lo = -math.inf if sig.minimum is None else float(sig.minimum)
    hi = math.inf if sig.maximum is None else float(sig.maximum)
    if sig.is_float:
        return lo, hi
    tol = abs(sig.conversion.scale) * 1e-3
    reach_lo, reach_hi = reach(sig)
    if lo < reach_lo - tol or hi > reach_hi + tol:
        log.info(
            "%s.%s: ignoring DBC range [%g|%g]: its %d bits carry only [%g, %g]",
            msg.name,
            sig.name,
            lo,
            hi,
            sig.length,
            reach_lo,
            reach_hi,
        )
        return -math.inf, math.inf
    return lo - tol, hi + tol


def reach(sig: Any) -> tuple[float, float]:
    """The physical values an integer signal's bits can carry."""
    scale, offset = sig.conversion.scale, sig.conversion.offset
    raw_lo, raw_hi = (
        (-(1 << (sig.length - 1)), (1 << (sig.length - 1)) - 1) if sig.is_signed else (0, (1 << sig.length) - 1)
    )
    lo, hi = sorted((raw_lo * scale + offset, raw_hi * scale + offset))
    return lo, hi


def check_fine(where: str, msg: Any, coarse: Any, fine: Any) -> None:
    """A ``fine`` signal must be able to fill every step of its coarse signal, in its unit.

    Otherwise the sum has gaps (or double counts), and the simulator could not encode
    every value either.
    """
    for sig in (coarse, fine):
        if sig.is_float:
            raise ProfileError(f"{where}: 'fine' needs integer signals, but {msg.name}.{sig.name} is a float")
    cu, fu = coarse.unit or "", fine.unit or ""
    if cu in UNIT_FACTORS and fu in UNIT_FACTORS and UNIT_FACTORS[cu] != UNIT_FACTORS[fu]:
        raise ProfileError(
            f"{where}: fine signal '{fine.name}' is in '{fu}' but '{coarse.name}' is in '{cu}'; "
            f"the two are added, so they must share a unit"
        )
    if cu and fu and cu != fu:  # units vdp does not know: maybe the same, maybe not
        log.warning(
            "%s: DBC gives %s.%s in '%s' and its fine signal %s in '%s'; they are added as they are",
            where,
            msg.name,
            coarse.name,
            cu,
            fine.name,
            fu,
        )
    step, fine_step = abs(coarse.conversion.scale), abs(fine.conversion.scale)
    if fine_step >= step:
        raise ProfileError(
            f"{where}: fine signal '{fine.name}' (steps of {fine_step:g}) is not finer than "
            f"'{coarse.name}' (steps of {step:g})"
        )
    # what the decoder accepts (limits() pads by a sliver) within what the bits carry
    lo, hi = limits(msg, fine)
    tol = fine_step * 1e-3
    reach_lo, reach_hi = reach(fine)
    lo, hi = max(lo + tol, reach_lo), min(hi - tol, reach_hi)
    if hi - lo + fine_step < step * (1 - 1e-6):
        raise ProfileError(
            f"{where}: fine signal '{fine.name}' carries [{lo:g}, {hi:g}] in steps of {fine_step:g}, "
            f"less than one step of '{coarse.name}' ({step:g}): their sum would have gaps"
        )


def compile_extractor(
    msg: Any, need: Sequence[tuple[str, bool, bool]], ranges: dict[tuple[str, str], tuple[float, float]] | None = None
) -> Callable[[Any], tuple] | None:
    """A function ``data -> (error kind or None, value1, value2, ...)`` for ``need``'s signals.

    Values are physical (``raw*scale+offset``), or raw ints where ``need`` says raw.
    Only plain integer signals of non-multiplexed messages; returns None otherwise
    (use cantools).  Built as Python source: one shift-and-mask expression per
    signal, no loops, no per-call lookups.
    """
    if msg.is_multiplexed():
        return None
    sigs = [msg.get_signal_by_name(name) for name, _, _ in need]
    if any(s.is_float for s in sigs):
        return None
    n_bytes = msg.length
    lines = ["def extract(data):"]
    if any(s.byte_order == "little_endian" for s in sigs):
        lines.append("    le = from_bytes(data, 'little')")
    if any(s.byte_order == "big_endian" for s in sigs):
        lines.append("    be = from_bytes(data, 'big')")
    checks = []
    for i, (sig, (_, raw, check)) in enumerate(zip(sigs, need)):
        if sig.byte_order == "little_endian":
            src, shift = "le", sig.start
        else:  # DBC start is the MSB in sawtooth numbering
            msb = (n_bytes - 1 - sig.start // 8) * 8 + sig.start % 8
            src, shift = "be", msb - sig.length + 1
        if shift < 0 or shift + sig.length > 8 * n_bytes:
            return None  # does not fit the message; let cantools report it
        mask = (1 << sig.length) - 1
        expr = f"(({src} >> {shift}) & {mask})"
        if sig.is_signed:
            half = 1 << (sig.length - 1)
            expr = f"(({expr} ^ {half}) - {half})"  # two's complement sign extension
        scale, offset = sig.conversion.scale, sig.conversion.offset
        if not raw and (scale != 1 or offset != 0):
            expr = f"{expr} * {float(scale)!r} + {float(offset)!r}"
        lines.append(f"    v{i} = {expr}")
        if check and not raw:
            lo, hi = range_limits(msg, sig, ranges)
            if lo > -math.inf:
                checks.append(f"v{i} >= {lo!r}")
            if hi < math.inf:
                checks.append(f"v{i} <= {hi!r}")
    values = "".join(f", v{i}" for i in range(len(sigs)))
    if checks:
        lines.append(f"    return (None if {' and '.join(checks)} else 'range'{values})")
    else:
        lines.append(f"    return (None{values})")
    scope: dict[str, Any] = {"from_bytes": int.from_bytes}
    exec(compile("\n".join(lines), f"<vdp extractor {msg.name}>", "exec"), scope)
    return scope["extract"]


def range_limits(msg: Any, sig: Any, ranges: dict[tuple[str, str], tuple[float, float]] | None) -> tuple[float, float]:
    """limits(), unless the profile gives the signal its own range."""
    r = ranges.get((msg.name, sig.name)) if ranges else None
    if r is None:
        return limits(msg, sig)
    tol = abs(sig.conversion.scale) * 1e-3
    return r[0] - tol, r[1] + tol


def cantools_extractor(
    msg: Any, need: Sequence[tuple[str, bool, bool]], ranges: dict[tuple[str, str], tuple[float, float]] | None = None
) -> Callable[[Any], tuple]:
    """Same contract as compile_extractor, through cantools (mux pages, float signals).

    A signal outside the frame's mux page comes back as None: the frame does not carry it.
    """
    specs = []
    for name, raw, check in need:
        sig = msg.get_signal_by_name(name)
        lo, hi = range_limits(msg, sig, ranges) if check else (-math.inf, math.inf)
        specs.append((name, raw, check, lo, hi, sig.conversion.scale, sig.conversion.offset))
    decode = msg.decode
    isfinite = math.isfinite

    def extract(data: Any) -> tuple:
        try:
            phys = decode(bytes(data), decode_choices=False, scaling=True)
        except _CantoolsDecodeError as exc:
            return ("mux",) if "multiplexer" in str(exc) else ("decode",)
        kind = None
        out: list[Any] = [None]
        for name, raw, check, lo, hi, scale, offset in specs:
            v = phys.get(name)
            if v is None:
                pass
            elif not isfinite(v):
                kind = kind or "nonfinite"
            elif raw:
                v = round((v - offset) / scale)  # counters and checksums are compared raw
            elif check and not lo <= v <= hi:
                kind = kind or "range"
            out.append(v)
        out[0] = kind
        return tuple(out)

    return extract
