"""The Cartesian line's input file (``mrm plan line FILE``, ``mrm run line FILE``, sweeps of
kind ``line``): start and end poses and the translation and rotation limits::

    [start]
    pose = [[1, 0, 0, 0.3], [0, 1, 0, 0.0], [0, 0, 1, 0.4], [0, 0, 0, 1]]   # metres
    [end]
    pose = [[0, -1, 0, 0.1], [1, 0, 0, 0.2], [0, 0, 1, 0.5], [0, 0, 0, 1]]
    [limits]
    translation = { velocity = 1.0, acceleration = 4.0, jerk = 40.0 }   # m/s, m/s², m/s³
    rotation    = { velocity = 1.0, acceleration = 4.0, jerk = 40.0 }   # rad/s, rad/s², rad/s³
"""

from __future__ import annotations

from mrm_cosim.errors import InputError, require_positive
from mrm_cosim.tomlfile import read_toml

__all__ = ["LIMIT_KEYS", "parse_line_spec", "load_line_file"]

LIMIT_KEYS = ("velocity", "acceleration", "jerk")


def _check_keys(table, allowed: tuple[str, ...], field: str) -> None:
    if not isinstance(table, dict):
        raise InputError(field, f"must be a table, not {table!r}")
    for key in table:
        if key not in allowed:
            raise InputError(f"{field}.{key}" if field else key,
                             f"unknown key (expected {', '.join(allowed)})")
    for key in allowed:
        if key not in table:
            raise InputError(f"{field}.{key}" if field else key, "missing")


def parse_line_spec(doc: dict):
    """Validate a parsed ``FILE.toml`` and return ``(start, end, LineLimits)``.

    ``start`` and ``end`` are 4×4 lists (validated further by
    :func:`master.trig_planner.pose_from_matrix`); every problem raises :class:`InputError`
    naming its dotted field.
    """
    from mrm_cosim.master.trig_planner import AxisLimits, LineLimits

    _check_keys(doc, ("start", "end", "limits"), "")
    _check_keys(doc["start"], ("pose",), "start")
    _check_keys(doc["end"], ("pose",), "end")
    _check_keys(doc["limits"], ("translation", "rotation"), "limits")
    axes = {}
    for part in ("translation", "rotation"):
        table = doc["limits"][part]
        _check_keys(table, LIMIT_KEYS, f"limits.{part}")
        values = {}
        for key in LIMIT_KEYS:
            name = f"limits.{part}.{key}"
            value = table[key]
            if isinstance(value, bool) or not isinstance(value, int | float):
                raise InputError(name, f"must be a number, not {value!r}")
            values[key] = require_positive(value, name)
        axes[part] = AxisLimits(**values)
    return doc["start"]["pose"], doc["end"]["pose"], LineLimits(**axes)


def load_line_file(path: str):
    """Read and validate ``FILE.toml``; returns ``(start, end, LineLimits)``."""
    return parse_line_spec(read_toml(path, "FILE"))
