"""The line every benchmark prints first: the machine, the versions, the commit and the date.

BENCHMARKS.md gives each table its command, machine, versions and date; a benchmark that
prints them itself makes a regenerated table carry them.
"""

from __future__ import annotations

import datetime
import importlib.metadata
import os
import platform
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
PACKAGES = ("numpy", "numba", "python-can", "cantools")


def _cpu() -> str:
    try:
        with open("/proc/cpuinfo") as f:
            for line in f:
                if line.startswith("model name"):
                    return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or platform.machine()


def _memory() -> str:
    try:
        with open("/proc/meminfo") as f:
            kb = int(f.readline().split()[1])
        return f"{kb / 2**20:.0f} GB RAM"
    except (OSError, ValueError, IndexError):
        return "RAM unknown"


def _version(name: str) -> str:
    try:
        return importlib.metadata.version(name)
    except importlib.metadata.PackageNotFoundError:
        return "absent"


def _commit() -> str:
    try:
        out = subprocess.run(
            ["git", "rev-parse", "--short", "HEAD"], cwd=ROOT, capture_output=True, text=True, check=True
        )
        status = ["git", "status", "--porcelain", "--untracked-files=no"]
        dirty = subprocess.run(status, cwd=ROOT, capture_output=True, text=True)
        return out.stdout.strip() + ("+" if dirty.stdout.strip() else "")
    except (OSError, subprocess.CalledProcessError):
        return "unknown"


def header() -> str:
    """One line: machine, versions, commit, date and load average."""
    machine = f"{os.cpu_count()} cores ({_cpu()}), {_memory()}, {platform.system()} {platform.release()}"
    versions = ", ".join([f"python {platform.python_version()}"] + [f"{name} {_version(name)}" for name in PACKAGES])
    now = datetime.datetime.now(datetime.timezone.utc).strftime("%Y-%m-%d %H:%M UTC")
    try:
        load = f"load average {os.getloadavg()[0]:.1f}"
    except OSError:
        load = "load average unknown"
    lines = (
        f"python {' '.join(sys.argv)}",
        f"machine: {machine}",
        f"versions: {versions}",
        f"{now} at {_commit()}, {load}",
    )
    return "\n".join("# " + line for line in lines)


def announce() -> None:
    """Print :func:`header` first (not for ``--help``)."""
    if not {"-h", "--help"} & set(sys.argv[1:]):
        print(header(), flush=True)
