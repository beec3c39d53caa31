"""Small argument helpers shared by the commands (vision, calibration, hardware, benchmarks)."""

from __future__ import annotations

import re

from cell.errors import BadInput
from cell.fileio import short_repr

# let "-120.5,30" or "-1e2,5" be a value, not an option (argparse only knows plain negative numbers)
_NUM = r"(?:\d+\.?\d*|\.\d+)(?:[eE][-+]?\d+)?"
_NEG_VALUE = re.compile(rf"^-{_NUM}(?:,-?{_NUM})*$|^-?{_NUM}(?:,-?{_NUM})+$")


def allow_negative_pairs(parser) -> None:
    parser._negative_number_matcher = _NEG_VALUE


def pair(text: str, what: str) -> tuple[float, float]:
    """'12.5,-3' -> (12.5, -3.0); anything else is bad input naming `what`."""
    parts = str(text).split(",")
    if len(parts) != 2:
        raise BadInput(f"{what} must be two numbers A,B (got {short_repr(text)})")
    try:
        a, b = float(parts[0]), float(parts[1])
    except ValueError:
        raise BadInput(f"{what} must be two numbers A,B (got {short_repr(text)})") from None
    if not all(map(_finite, (a, b))):
        raise BadInput(f"{what} must be finite numbers (got {short_repr(text)})")
    return a, b


def numbers(text: str, n: int, what: str) -> list[float]:
    parts = str(text).split(",")
    try:
        vals = [float(x) for x in parts]
    except ValueError:
        raise BadInput(f"{what} must be {n} comma-separated numbers (got {short_repr(text)})") from None
    if len(vals) != n or not all(map(_finite, vals)):
        raise BadInput(f"{what} must be {n} comma-separated finite numbers (got {short_repr(text)})")
    return vals


def grid(text: str, what: str) -> tuple[int, int]:
    m = re.fullmatch(r"\s*(\d+)\s*[xX,]\s*(\d+)\s*", str(text))
    if not m or int(m.group(1)) < 2 or int(m.group(2)) < 2:
        raise BadInput(f"{what} must be COLSxROWS with both at least 2, e.g. 9x6 (got {short_repr(text)})")
    return int(m.group(1)), int(m.group(2))


def finite(value: float | None, what: str, minimum: float | None = None) -> float | None:
    """An option's number, refused when NaN or infinite (or below `minimum`); None passes."""
    if value is None:
        return None
    if not _finite(value):
        raise BadInput(f"{what} must be a finite number (got {value!r})")
    if minimum is not None and value < minimum:
        raise BadInput(f"{what} must be at least {minimum:g} (got {value!r})")
    return value


def count(value: int, what: str, maximum: int) -> int:
    """A count option, 1..`maximum`: a count that would run without end is bad input with its range."""
    if not 1 <= value <= maximum:
        raise BadInput(f"{what} must be 1..{maximum}, got {value}")
    return value


def seconds(value: float | None, what: str) -> float | None:
    """A time in seconds: finite and not negative (NaN would wait forever on a SimClock); None passes."""
    if value is not None and not (_finite(value) and value >= 0):
        raise BadInput(f"{what} {value:g}: give a finite number of seconds, 0 or more")
    return value


def plane_z(value: float | None, what: str = "--z") -> float | None:
    """A plane's height: finite, and no further from the table than a part's top can be."""
    from cell.scene import MAX_COORD_MM

    finite(value, what)
    if value is not None and abs(value) > MAX_COORD_MM:
        raise BadInput(f"{what} must be within {MAX_COORD_MM:g} mm of the table, got {value:g}")
    return value


def _finite(x: float) -> bool:
    return x == x and abs(x) != float("inf")


def refuse_out_over_an_input(out, inputs, option: str = "--out") -> None:
    """--out naming one of the command's own input files would replace it with the result."""
    from pathlib import Path

    target = Path(out).resolve()
    for path in inputs:
        if path is not None and Path(path).resolve() == target:
            raise BadInput(f"{option} {out} is one of the inputs: it would be overwritten; name another file")
