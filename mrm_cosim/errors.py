"""Input errors shared by every layer: a bad value is reported with the field that holds it.

The field is what the library knows: an API argument (``duration``, ``backend``), a key of a
configuration or robot file (``gains.lam``), never a command-line flag. The CLI maps the
arguments to its flags (:mod:`mrm_cosim.mrm.flags`) and turns the error into a one-line
message on stderr and exit code 2.
"""

from __future__ import annotations

import math
import unicodedata
from collections.abc import Sequence

__all__ = ["InputError", "require_finite", "require_positive", "require_nonnegative",
           "require_vector", "reject_strings", "reject_control_characters"]


class InputError(ValueError):
    """A value given by the user is not acceptable.

    Parameters
    ----------
    field : str
        Dotted name of the offending field or argument (``"limits.translation.jerk"``,
        ``"duration"``, ``"params.slots"``).
    message : str
        What is wrong with it, in words a user understands.
    """

    def __init__(self, field: str, message: str):
        self.field = field
        self.message = message
        super().__init__(f"{field}: {message}")


def require_finite(value, field: str) -> float:
    """Return ``value`` as a float; raise :class:`InputError` if it is not a finite number."""
    if isinstance(value, bool):
        raise InputError(field, f"must be a number, not {value!r}")
    try:
        x = float(value)
    except (TypeError, ValueError):
        raise InputError(field, f"must be a number, not {value!r}") from None
    if not math.isfinite(x):
        raise InputError(field, f"must be finite, not {value!r}")
    return x


def require_positive(value, field: str) -> float:
    """Return ``value`` as a float; it must be finite and > 0."""
    x = require_finite(value, field)
    if x <= 0.0:
        raise InputError(field, f"must be positive, not {value!r}")
    return x


def require_nonnegative(value, field: str) -> float:
    """Return ``value`` as a float; it must be finite and >= 0."""
    x = require_finite(value, field)
    if x < 0.0:
        raise InputError(field, f"must be non-negative, not {value!r}")
    return x


def require_vector(value, length: int, field: str) -> list[float]:
    """Return ``value`` as a list of ``length`` finite floats."""
    if isinstance(value, str | bytes) or not isinstance(value, Sequence):
        raise InputError(field, f"must be a list of {length} numbers, not {value!r}")
    if len(value) != length:
        raise InputError(field, f"must have {length} elements, not {len(value)}")
    return [require_finite(v, f"{field}[{i}]") for i, v in enumerate(value)]


def reject_strings(value, field: str):
    """Return ``value`` unless it is a string (or a list holding one, named ``field[i]``).

    For numbers read from a file: ``twist_deg = "90"`` is a quoting mistake that ``float``
    would hide by reading the string, so a file's number must be written as one.
    """
    if isinstance(value, str | bytes):
        raise InputError(field, f"must be a number, not the string {value!r}")
    if isinstance(value, list):
        for i, v in enumerate(value):
            reject_strings(v, f"{field}[{i}]")
    return value


def reject_control_characters(text: str, field: str) -> str:
    """Return ``text`` unless it holds a control character (:class:`InputError` naming
    ``field``). Names are printed to the terminal and written into URDF, JSON and Markdown: an
    escape sequence or a newline would repaint the terminal or split a line."""
    bad = [c for c in text if unicodedata.category(c) in ("Cc", "Cf")]
    if bad:
        raise InputError(field, f"must not contain control characters ({bad[0]!r} in "
                         f"{text!r})")
    return text
