"""Output paths checked before any work starts: a bad one is a one-line error, not a lost run."""

from __future__ import annotations

import os
import tempfile
from pathlib import Path

from ..errors import ConfigError


def _identity(path: str | Path) -> tuple:
    """What makes two names one file: its device and inode if it exists (a hard link, a symlink,
    another spelling of the path), else the path with every symlink resolved."""
    try:
        st = os.stat(path)
    except OSError:
        return ("path", os.path.realpath(path))
    return ("inode", st.st_dev, st.st_ino)


def check_dir(path: str | Path, what: str) -> Path:
    """Refuse a folder that no file can be written in (read-only, another owner's, a read-only
    file system), by writing a probe file there: the folder exists (made by the caller)."""
    p = Path(path)
    try:
        fd, probe = tempfile.mkstemp(prefix=".vdp-probe-", dir=p)
    except OSError as exc:
        raise ConfigError(
            f"{what} {p}: cannot write in it: {exc.strerror or exc}; give a folder you can write to"
        ) from None
    os.close(fd)
    os.unlink(probe)
    return p


def check_apart(outputs: dict[str, str | Path | None], inputs: dict | list[tuple[str, str | Path | None]]) -> None:
    """Refuse an output that is one of the run's inputs (or another output) before any work.

    ``outputs``: flag -> path (None: not given); ``inputs``: what it is ("the log", "--profile")
    -> path, or a list of such pairs.  ``vdp replay drive.log --json drive.log`` wrote the JSON
    over the log and exited 0.
    """
    taken: dict[tuple, str] = {}  # a file -> the input it is
    for what, path in inputs.items() if isinstance(inputs, dict) else inputs:
        if path is not None:
            taken.setdefault(_identity(path), f"{what} {path}")
    written: dict[tuple, str] = {}  # a file -> the flag of the output already there
    for flag, path in outputs.items():
        if path is None:
            continue
        ident = _identity(path)
        if ident in taken:
            raise ConfigError(
                f"{flag} {path}: is {taken[ident]}, an input of this run: writing there would overwrite it; "
                f"give {flag} another file"
            )
        if ident in written:
            raise ConfigError(f"{flag} {path}: is also the file of {written[ident]}; give each output its own file")
        written[ident] = flag


def profile_inputs(profile) -> dict[str, Path]:
    """A loaded profile's files, as inputs of check_apart: the TOML and its DBCs."""
    out = {"the profile": profile.path}
    for i, dbc in enumerate(profile.dbcs):
        out["its DBC" if i == 0 else f"its DBC {i + 1}"] = dbc
    return out


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
