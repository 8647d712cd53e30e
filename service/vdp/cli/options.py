"""Options more than one subcommand takes, spelt once."""

from __future__ import annotations

MASS_MODES = ("auto", "on", "report", "off")  # core.mass.MODES (the CLI does not import the core to list them)


def mass_option() -> dict:
    """``--mass [MODE]``: auto by default; the bare flag (before "auto", a switch) means on."""
    return {"nargs": "?", "const": "on", "default": "auto", "choices": MASS_MODES, "metavar": "MODE"}
