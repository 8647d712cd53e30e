"""Options more than one subcommand takes, spelt once."""

from __future__ import annotations

from ..settings import MASS_MODES


def mass_option() -> dict:
    """``--mass [MODE]``: auto by default; the bare flag (before "auto", a switch) means on."""
    return {"nargs": "?", "const": "on", "default": "auto", "choices": MASS_MODES, "metavar": "MODE"}
