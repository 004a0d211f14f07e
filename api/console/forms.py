"""Reading the console's GET forms: every field arrives as a string (empty when left blank), and
one that cannot be read raises :class:`FormProblem` naming the field, for the page to show."""

from __future__ import annotations

from datetime import datetime

from fleetbus.limits import read_iso_time
from fleetbus.schemas.identity import validate_name


class FormProblem(ValueError):
    """A field of a form that cannot be read; its message names the field."""


def moment(name: str, text: str) -> datetime | None:
    """A time (``2024-05-01T10:00:00``, as a datetime-local field sends it), UTC unless it says."""
    if not text.strip():
        return None
    try:
        return read_iso_time(text.strip())
    except ValueError:
        example = "2024-05-01T10:00:00 (UTC)"
        raise FormProblem(f"{name}: cannot read {text!r} as a time; write {example}") from None


def robot_name(text: str) -> str | None:
    if not text.strip():
        return None
    try:
        return validate_name(text.strip())
    except ValueError as error:
        raise FormProblem(f"robot: {error}") from None


def limit_of(text: str, default: int, most: int) -> int:
    """A number of rows: ``default`` when blank, at most ``most``."""
    if not text.strip():
        return min(default, most)
    try:
        asked = int(text)
    except ValueError:
        raise FormProblem(f"limit: {text!r} is not a whole number") from None
    if asked < 1:
        raise FormProblem("limit: at least 1")
    return min(asked, most)
