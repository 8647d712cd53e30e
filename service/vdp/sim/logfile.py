"""A simulated drive's files: its log (candump -L directly, else through python-can) and its truth."""

from __future__ import annotations

import gzip
import io
import json
from collections.abc import Iterator
from pathlib import Path

import can

from ..errors import LogFormatError
from ..outfile import replacing, write_text


# -- outputs ------------------------------------------------------------------------------
def truth_path(log_path: str | Path) -> Path:
    """``drive.log`` -> ``drive.truth.json`` (also for ``drive.log.gz`` and other suffixes)."""
    p = Path(log_path)
    name = p.name
    if name.lower().endswith(".gz"):
        name = name[:-3]
    stem = name.rsplit(".", 1)[0] if "." in name else name
    return p.with_name(stem + ".truth.json")


def write_truth(truth: dict, path: str | Path) -> Path:
    path = Path(path)
    write_text(path, json.dumps(truth, indent=2, sort_keys=False) + "\n")
    return path


def _candump_line(msg: can.Message, chan: str) -> str:
    fid = f"{msg.arbitration_id:08X}" if msg.is_extended_id else f"{msg.arbitration_id:03X}"
    sep = "##0" if msg.is_fd else "#"  # FD frames: flags nibble after '##'
    return f"({msg.timestamp:.6f}) {msg.channel or chan} {fid}{sep}{msg.data.hex().upper()}\n"


def check_writable(path: str | Path) -> None:
    """A LogFormatError unless ``path``'s format is one vdp replays and can be written here."""
    from ..io.logs import FORMATS

    path = Path(path)
    name = path.name.lower()
    suffix = "".join(path.suffixes[-2:]).lower() if name.endswith(".gz") else path.suffix.lower()
    if suffix.removesuffix(".gz") not in FORMATS:
        # python-can writes some formats (.txt, .db) that no reader of vdp's takes back
        raise LogFormatError(
            f"{path}: vdp cannot replay '{suffix or path.name}' logs; write one of "
            f"{', '.join(FORMATS)} (plain .log is candump -L, the bulk reader's)"
        )
    if suffix == ".mf4":
        try:
            import asammdf  # noqa: F401
        except ImportError:
            raise LogFormatError(f"{path}: python-can writes .mf4 only with asammdf: pip install 'vdp[mf4]'") from None


def write_log(frames: Iterator[can.Message], path: str | Path, channel: str = "can0") -> int:
    """Write frames to ``path``; the format follows the suffix.  Returns the frame count.

    ``.log`` and ``.log.gz`` are written directly as ``candump -L`` lines (deterministic,
    gzip without a timestamp); every other suffix goes through ``can.Logger``.
    """
    path = Path(path)
    name = path.name.lower()
    if not path.parent.is_dir():
        raise LogFormatError(f"{path}: directory {path.parent} does not exist")
    if not name.endswith((".log", ".log.gz")):
        check_writable(path)
    with replacing(path) as tmp:  # (the tmp's name ends in path's: python-can picks the same format)
        return _write_frames(frames, tmp, path, channel)


def _write_frames(frames: Iterator[can.Message], dest: Path, path: Path, channel: str) -> int:
    """write_log's work, into ``dest`` (the file that becomes ``path``)."""
    name = path.name.lower()
    n = 0
    if name.endswith((".log", ".log.gz")):
        raw = open(dest, "wb")
        try:
            if name.endswith(".gz"):
                gz = gzip.GzipFile(filename="", mode="wb", fileobj=raw, mtime=0)
                out = io.TextIOWrapper(gz, encoding="ascii", newline="\n")
            else:
                gz, out = None, io.TextIOWrapper(raw, encoding="ascii", newline="\n")
            buf = []
            for msg in frames:
                buf.append(_candump_line(msg, channel))
                n += 1
                if len(buf) >= 4096:
                    out.write("".join(buf))
                    buf.clear()
            out.write("".join(buf))
            out.flush()
            if gz is not None:
                out.detach()
                gz.close()
            else:
                out.detach()
        finally:
            raw.close()
        return n
    try:
        writer = can.Logger(str(dest))
    except ValueError as exc:
        raise LogFormatError(f"{path}: {exc}") from None
    except (NotImplementedError, ImportError) as exc:  # .mf4 needs asammdf
        raise LogFormatError(f"{path}: python-can cannot write it here ({exc}); pip install 'vdp[mf4]'") from None
    with writer:
        for msg in frames:
            writer.on_message_received(msg)
            n += 1
    return n
