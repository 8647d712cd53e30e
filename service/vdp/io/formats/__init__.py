"""One module per log format (as python-can's ``can/io/``), and the registry of their readers.

``READERS`` maps a file's format (its suffix, without ``.gz``) to its reader; a format not
listed is read by python-can's own reader (:class:`vdp.io.formats.pycan._PythonCanReader`).
``vdp.io.logs`` opens a file and picks the reader from here.
"""

from __future__ import annotations

from .asc import AscReader
from .base import _Reader
from .blf import BlfReader
from .candump import CandumpReader
from .csv import CsvReader
from .pycan import _PythonCanReader
from .trc import TrcReader

READERS: dict[str, type[_Reader]] = {
    ".log": CandumpReader,
    ".asc": AscReader,
    ".trc": TrcReader,
    ".csv": CsvReader,
    ".blf": BlfReader,
}
DEFAULT = _PythonCanReader

__all__ = ["DEFAULT", "READERS", "AscReader", "BlfReader", "CandumpReader", "CsvReader", "TrcReader"]
