"""``python -m vdp``: the same CLI as the ``vdp`` command (where the venv's scripts are not on PATH)."""

import sys

from .cli import main

if __name__ == "__main__":
    sys.exit(main())
