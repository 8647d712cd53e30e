"""The raw log's directory: the closed files' names, a rotation, the index, a file left open salvaged,
and the oldest files deleted to keep ``max_files`` and the free-space floor."""

from __future__ import annotations

import json
import logging
import os
import shutil
import time
from pathlib import Path

from .rotating import _fsync_dir

log = logging.getLogger(__name__)

_TAIL = 1 << 16  # bytes read back when salvaging a file cut mid-line


class _Files:
    """The part of :class:`~vdp.live.rawlog.RawLog` that names, closes and deletes its files; its state
    is RawLog's."""

    def _next_name(self) -> Path:
        stamp = time.strftime("%Y%m%dT%H%M%SZ", time.gmtime(self._opened_at))
        path = self.dir / f"{self.prefix}-{self._seq:06d}-{stamp}.log"
        self._seq += 1
        return path

    def _rotate(self, source, dest, rolling: bool = False) -> None:
        """rotator of SizedRotatingLogger (``rolling``: the frame being written is not in the file yet);
        the writer is already closed (flushed) here."""
        src, dst = Path(source), Path(dest)
        fd = os.open(src, os.O_RDONLY)
        try:
            os.fsync(fd)
        finally:
            os.close(fd)
        os.replace(src, dst)
        if rolling:
            self._settled(len(self._held) - (0 if self._rolling_all else 1))
            self._verified = 0
        _fsync_dir(self.dir)
        self._note(dst)
        self._opened_at = time.time()
        self._start_file()
        self._prune()

    def _drops_now(self) -> dict:
        try:
            return dict(self.drops()) if self.drops is not None else {}
        except Exception:  # the index must never stop logging
            return {}

    def _start_file(self) -> None:
        self._in_file = 0
        self._drops_at_open = self._drops_now()

    def _note(self, closed: Path) -> None:
        """One line in the index for a file just closed: its frames, its span, and the frames lost before
        vdp read them (by cause) while it was the open file: where a replay of it has gaps."""
        now = self._drops_now()
        lost = {k: (v or 0) - (self._drops_at_open.get(k) or 0) for k, v in now.items() if v is not None}
        line = {
            "file": closed.name,
            "frames": self._in_file,
            "opened": round(self._opened_at, 3),
            "closed": round(time.time(), 3),
            "dropped": lost,
            "dropped_total": now,
        }
        try:
            with open(self.index, "a", encoding="utf-8") as f:
                f.write(json.dumps(line) + "\n")
        except OSError as exc:
            log.warning("raw CAN log: could not add %s to the index %s: %s", closed.name, self.index, exc)

    def _salvage(self, why: str = "left open by the last run") -> None:
        """A file left open by a crash (or by a close whose flush failed): cut a partial last line,
        then close it like any other."""
        size = self.current.stat().st_size
        if size == 0:
            self.current.unlink()
            return
        with open(self.current, "r+b") as f:
            f.seek(max(0, size - _TAIL))
            tail = f.read()
            if not tail.endswith(b"\n"):
                cut = tail.rfind(b"\n")
                keep = (size - len(tail) + cut + 1) if cut >= 0 else (0 if size <= _TAIL else size)
                f.truncate(keep)
                log.warning(
                    "%s: cut %d bytes of a line left unfinished (a crash, or a write the disk refused)",
                    self.current,
                    size - keep,
                )
            f.flush()
            os.fsync(f.fileno())
        if self.current.stat().st_size == 0:
            self.current.unlink()
            return
        self._opened_at = self.current.stat().st_mtime
        dst = self._next_name()
        os.replace(self.current, dst)
        _fsync_dir(self.dir)
        log.info("closed the raw log %s as %s", why, dst.name)

    def closed_files(self) -> list[Path]:
        """Closed files, oldest first."""
        try:
            names = [(int(m.group(1)), p) for p in self.dir.iterdir() if (m := self._pattern.match(p.name))]
        except OSError:
            return []
        return [p for _, p in sorted(names)]

    def _make_room(self) -> None:
        """Delete the oldest closed files while free space is under the floor (the newest data wins)."""
        closed = self.closed_files()
        while closed:
            try:
                free = shutil.disk_usage(self.dir).free
            except OSError:
                return
            if free >= self.min_free:
                return
            p = closed.pop(0)
            try:
                size = p.stat().st_size
                p.unlink()
            except OSError as exc:
                log.warning("could not delete old raw log %s to make room: %s", p, exc)
                continue
            self.deleted += 1
            self.deleted_for_space += 1
            log.warning(
                "deleted the oldest raw log %s (%d bytes): %d bytes free, under the floor of %d",
                p.name,
                size,
                free,
                self.min_free,
            )

    def _prune(self) -> None:
        self._make_room()
        closed = self.closed_files()
        extra = len(closed) - (self.max_files - 1)  # the open file is one of max_files
        for p in closed[: max(extra, 0)]:
            try:
                p.unlink()
                self.deleted += 1
                log.info("deleted the oldest raw log %s (keeping %d files)", p.name, self.max_files)
            except OSError as exc:
                log.warning("could not delete old raw log %s: %s", p, exc)
