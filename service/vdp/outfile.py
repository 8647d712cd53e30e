"""Every file vdp writes for the user is written here: to a temporary file beside it, then renamed.

A reader (or a crash) sees the old file or the whole new one, never half of one; and a file
given both as an input and as an output is no longer truncated as the output is opened (the
CLI refuses that case before it starts: cli.paths.check_apart).
"""

from __future__ import annotations

import contextlib
import os
import secrets
import shutil
import stat
from collections.abc import Iterator
from pathlib import Path


@contextlib.contextmanager
def replacing(path: str | Path) -> Iterator[Path]:
    """A new path beside ``path`` to write to, renamed over ``path`` when the block ends, removed
    if it raises.  Its name ends in ``path``'s own (a writer that goes by the suffix, matplotlib's
    or python-can's, picks the same format).  A symlink is written through, as ``open`` would;
    a FIFO or a device (``/dev/stdout``) is written in place: renaming over one would replace it."""
    try:
        st = os.stat(path)  # (through symlinks: /dev/stdout on a pipe resolves to no path at all)
    except OSError:
        st = None
    if st is not None and not stat.S_ISREG(st.st_mode):
        yield Path(path)
        return
    target = Path(os.path.realpath(path))
    tmp = target.with_name(f".vdp-{secrets.token_hex(4)}-{target.name[-200:]}")
    # created here (not by mkstemp, whose 0600 would stay on the output): the umask applies as to open()
    os.close(os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o666))
    try:
        yield tmp
        if target.exists():
            shutil.copymode(target, tmp)  # a file written again keeps its mode
        os.replace(tmp, target)
    except BaseException:
        with contextlib.suppress(OSError):
            tmp.unlink()
        raise


def write_text(path: str | Path, text: str) -> None:
    """``text`` as UTF-8 to ``path``, whole or not at all."""
    with replacing(path) as tmp:
        tmp.write_text(text, encoding="utf-8")


def write_bytes(path: str | Path, data: bytes) -> None:
    with replacing(path) as tmp:
        tmp.write_bytes(data)
