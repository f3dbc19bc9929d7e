"""Numbers as a user reads and types them, in reports and world files: no numpy, so the CLI's
report can use them without loading it."""

from __future__ import annotations


def decimal_text(v: float, places: int) -> str:
    """``v`` with at most ``places`` decimals and no trailing zeros, as a user would type it
    (28.95, not 28.950000000000003; ``-0`` is ``0``)."""
    text = f"{v:.{places}f}".rstrip("0").rstrip(".")
    return "0" if text in ("", "-0") else text


def minus(name: str, v: float) -> str:
    """``name`` minus ``v``, written for a human: 'x - 29.125', 'x + 0.125', or 'x' for 0;
    ``v`` rounded to the nanometre (28.95, not 28.950000000000003)."""
    text = decimal_text(abs(v), 9)
    if text == "0":
        return name
    return f"{name} - {text}" if v > 0 else f"{name} + {text}"
