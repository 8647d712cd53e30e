"""Output paths checked before any work starts: a bad one is a one-line error, not a lost run."""

from __future__ import annotations

import os
import tempfile
from pathlib import Path

from ..errors import ConfigError


def check_output(path: str | Path, what: str, suffixes: tuple[str, ...] | None = None) -> Path:
    """Refuse ``path`` now if a file cannot be written there later (or its suffix is not one of ``suffixes``).

    Writing a probe file in the directory is the only honest test: permission bits say
    nothing for root, and nothing about a read-only or full file system.
    """
    p = Path(path)
    if suffixes is not None and not any(p.name.lower().endswith(s) for s in suffixes):
        raise ConfigError(f"{what} {p}: unknown file type; use a name ending in {', '.join(suffixes)}")
    if p.is_dir():
        raise ConfigError(f"{what} {p}: is a directory; give a file name")
    parent = p.parent if str(p.parent) else Path(".")
    if not parent.is_dir():
        raise ConfigError(f"{what} {p}: directory {parent} does not exist; create it first")
    if p.exists() and not os.access(p, os.W_OK):
        raise ConfigError(f"{what} {p}: exists and is not writable")
    try:
        fd, probe = tempfile.mkstemp(prefix=".vdp-probe-", dir=parent)
    except OSError as exc:
        raise ConfigError(f"{what} {p}: cannot write in {parent}: {exc.strerror or exc}") from None
    os.close(fd)
    os.unlink(probe)
    return p
