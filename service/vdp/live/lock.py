"""One service per estimate store and raw-log directory.

Two services on the same files would each rename the other's open raw log
and interleave commits.  ``InstanceLock`` takes an exclusive ``flock`` on
``STORE.lock`` beside the store and ``.vdp.lock`` in the raw-log directory (in it, not
beside it: a logger writing straight to a USB stick's mount point may not write the
mount point's parent; the raw log's own files are named by their prefix, and a hidden
``.lock`` is no log to ``vdp batch``);
the kernel drops it when the process ends however it ends (``kill -9``
included), so a stale lock file never blocks a restart.  The lock file holds
the owner's pid, to name it in the refusal.
"""

from __future__ import annotations

import errno
import fcntl
import logging
import os
from pathlib import Path

from ..errors import ConfigError

log = logging.getLogger(__name__)


class InstanceLock:
    def __init__(self, targets: list[tuple[str, Path]]):
        """``targets``: (what, lock file path), e.g. ("estimate store", Path("vdp.sqlite.lock"))."""
        self.targets = targets
        self._fds: list[int] = []

    def acquire(self) -> InstanceLock:
        try:
            for what, path in self.targets:
                self._take(what, path)
        except BaseException:
            self.release()
            raise
        return self

    def _take(self, what: str, path: Path) -> None:
        blocked = next((p for p in (path.parent, *path.parent.parents) if p.exists() and not p.is_dir()), None)
        if blocked is not None:  # (mkdir's "File exists" named neither the file nor the setting)
            raise ConfigError(f"the {what} needs the folder {path.parent}, but {blocked} is a file")
        try:
            path.parent.mkdir(parents=True, exist_ok=True)
            fd = os.open(path, os.O_RDWR | os.O_CREAT, 0o644)
        except OSError as exc:
            raise ConfigError(
                f"the {what}: cannot create its lock file {path}: {exc.strerror or exc}; give it a "
                f"folder this user can write"
            ) from None
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError as exc:
            os.close(fd)
            if exc.errno not in (errno.EWOULDBLOCK, errno.EAGAIN, errno.EACCES):
                raise ConfigError(f"cannot lock {path}: {exc.strerror or exc}") from None
            owner = _read_pid(path)
            who = f"another vdp serve (pid {owner})" if owner else "another vdp serve"
            held = path.parent if path.name == ".vdp.lock" else path.with_suffix("")
            raise ConfigError(
                f"the {what} {held} is in use by {who}; stop it first, or give this one its own --db and --raw-dir"
            ) from None
        os.ftruncate(fd, 0)
        os.write(fd, f"{os.getpid()}\n".encode())
        self._fds.append(fd)

    def release(self) -> None:
        for fd in self._fds:
            try:
                os.close(fd)  # closing drops the flock; the file stays (deleting it would race a new owner)
            except OSError:
                pass
        self._fds = []

    def __enter__(self) -> InstanceLock:
        return self.acquire()

    def __exit__(self, *exc: object) -> None:
        self.release()


def service_lock(settings) -> InstanceLock:
    """The lock of a service's store and raw-log directory (not yet acquired)."""
    store = Path(settings.store.path)
    targets = [("estimate store", store.with_name(store.name + ".lock"))]
    if settings.raw_log.enabled:
        targets.append(("raw log directory", Path(settings.raw_log.dir) / ".vdp.lock"))
    return InstanceLock(targets)


def _read_pid(path: Path) -> int | None:
    try:
        text = path.read_text().strip()
    except OSError:
        return None
    return int(text) if text.isdigit() else None
