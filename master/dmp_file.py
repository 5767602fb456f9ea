"""A learned DMP (:class:`master.dmp.Dmp`) as a TOML file: ``mrm dmp learn`` writes it,
``mrm dmp rollout`` reads it.

The file holds every parameter of the primitive and where it came from::

    format = "mrm-dmp"
    version = 1

    [dmp]                      # master/dmp.py, docs/trajectories.md §4
    alpha = 25.0               # spring gain α (β = α/4 unless given)
    beta = 6.25
    alpha_s = 2.0              # phase decay α_s
    tau = 1.0                  # s, the demo's duration
    x0 = [0.0, 0.1]            # start, one per DOF (rad for joints)
    g = [1.0, 0.5]             # goal
    xd0 = [0.0, 0.0]           # initial velocity, per s
    goal_scaling = [true, true]
    centers = [1.0, …]         # n_basis phases
    widths = [0.05, …]         # σ_i on the phase
    weights = [[…], […]]       # n_dof rows, one weight per centre

    [provenance]               # what it was learned from (free-form, kept as written)
    source = "demo.csv"
    basis = 10
    …

Every float is written with ``repr`` (Python's shortest round-trip form), so reading the file
back gives the same bits: the round trip is exact. Reading validates every field and names it
(``dmp.weights[1][3]: must be finite``, ``dmp.centers: must have 10 elements, not 9``).
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from mrm_cosim.errors import InputError
from mrm_cosim.master.dmp import Dmp
from mrm_cosim.results import atomic_write_text
from mrm_cosim.tomlfile import read_toml

__all__ = ["FORMAT", "VERSION", "write_dmp", "read_dmp", "read_dmp_file", "dmp_toml"]

FORMAT = "mrm-dmp"
VERSION = 1
_SCALARS = ("alpha", "beta", "alpha_s", "tau")
_VECTORS = ("x0", "g", "xd0")
_KEYS = (*_SCALARS, *_VECTORS, "goal_scaling", "centers", "widths", "weights")


# --- writing -------------------------------------------------------------------------------
def _value(value, field: str) -> str:
    """One TOML value: floats by ``repr`` (bit-exact), ints, bools, strings, flat lists."""
    if isinstance(value, bool | np.bool_):
        return "true" if value else "false"
    if isinstance(value, int | np.integer):
        return str(int(value))
    if isinstance(value, float | np.floating):
        x = float(value)
        if not math.isfinite(x):
            raise InputError(field, f"must be finite, not {x!r}")
        return repr(x)
    if isinstance(value, str):
        return _string(value)
    if isinstance(value, list | tuple | np.ndarray):
        return "[" + ", ".join(_value(v, f"{field}[{i}]") for i, v in enumerate(value)) + "]"
    raise InputError(field, f"cannot be written to TOML: {value!r}")


def _string(text: str) -> str:
    """A TOML basic string (JSON's escapes are TOML's, for the characters JSON escapes)."""
    import json

    return json.dumps(text, ensure_ascii=False)


def dmp_toml(dmp: Dmp, meta: dict | None = None) -> str:
    """The file's text for ``dmp`` with ``meta`` as its ``[provenance]`` table.

    ``meta`` maps names to strings, numbers, booleans or flat lists of them.
    """
    lines = ["# A discrete DMP learned by `mrm dmp learn` (master/dmp.py; docs/trajectories.md)",
             f'format = "{FORMAT}"', f"version = {VERSION}", "", "[dmp]"]
    fields = {"alpha": dmp.alpha, "beta": dmp.beta, "alpha_s": dmp.alpha_s, "tau": dmp.tau,
              "x0": dmp.x0, "g": dmp.g, "xd0": dmp.xd0,
              "goal_scaling": [bool(b) for b in dmp.goal_scaling],
              "centers": dmp.centers, "widths": dmp.widths}
    for key, value in fields.items():
        lines.append(f"{key} = {_value(value, f'dmp.{key}')}")
    lines.append("weights = [")
    for i, row in enumerate(np.asarray(dmp.weights, dtype=float)):
        lines.append(f"    {_value(row, f'dmp.weights[{i}]')},")
    lines.append("]")
    if meta:
        lines += ["", "[provenance]"]
        for key, value in meta.items():
            if not key.replace("_", "").isalnum() or not key.isascii():
                raise InputError("meta", f"key {key!r} must be letters, digits and _")
            lines.append(f"{key} = {_value(value, f'provenance.{key}')}")
    return "\n".join(lines) + "\n"


def write_dmp(path, dmp: Dmp, meta: dict | None = None, field: str = "out") -> None:
    """Write ``dmp`` (and ``meta`` as ``[provenance]``) to ``path`` atomically: a temporary
    file beside it replaces it only once complete (:func:`mrm_cosim.results.atomic_write_text`,
    whose refusals name ``field``)."""
    atomic_write_text(path, dmp_toml(dmp, meta), field)


# --- reading -------------------------------------------------------------------------------
def _float(value, field: str) -> float:
    if isinstance(value, bool) or not isinstance(value, int | float):
        raise InputError(field, f"must be a number, not {value!r}")
    x = float(value)
    if not math.isfinite(x):
        raise InputError(field, f"must be finite, not {value!r}")
    return x


def _positive(value, field: str) -> float:
    x = _float(value, field)
    if x <= 0.0:
        raise InputError(field, f"must be positive, not {value!r}")
    return x


def _floats(value, n: int | None, field: str) -> np.ndarray:
    if not isinstance(value, list):
        raise InputError(field, f"must be a list of numbers, not {value!r}")
    if n is not None and len(value) != n:
        raise InputError(field, f"must have {n} elements, not {len(value)}")
    return np.array([_float(v, f"{field}[{i}]") for i, v in enumerate(value)], dtype=float)


def parse_dmp(doc: dict, field: str = "dmp") -> tuple[Dmp, dict]:
    """Validate a parsed DMP document; returns ``(Dmp, provenance)``. Every problem is an
    :class:`InputError` naming its dotted field (``dmp.tau``, ``dmp.weights[0][2]``)."""
    for key in doc:
        if key not in ("format", "version", "dmp", "provenance"):
            raise InputError(key, "unknown key (expected format, version, dmp, provenance)")
    if doc.get("format") != FORMAT:
        raise InputError("format", f'must be "{FORMAT}" (is this a DMP file?), not '
                         f"{doc.get('format')!r}")
    if doc.get("version") != VERSION or isinstance(doc.get("version"), bool):
        raise InputError("version", f"must be {VERSION}, not {doc.get('version')!r}")
    table = doc.get("dmp")
    if not isinstance(table, dict):
        raise InputError(field, "missing table" if table is None else "must be a table")
    for key in table:
        if key not in _KEYS:
            raise InputError(f"{field}.{key}", f"unknown key (expected {', '.join(_KEYS)})")
    for key in _KEYS:
        if key not in table:
            raise InputError(f"{field}.{key}", "missing")
    rows = table["weights"]
    if not isinstance(rows, list) or not rows or not all(isinstance(r, list) for r in rows):
        raise InputError(f"{field}.weights", "must be a non-empty list of rows (one per DOF)")
    centers = _floats(table["centers"], None, f"{field}.centers")
    n_dof, n_basis = len(rows), len(centers)
    if n_basis < 2:
        raise InputError(f"{field}.centers", f"must have at least 2 elements, not {n_basis}")
    weights = np.array([_floats(r, n_basis, f"{field}.weights[{i}]")
                        for i, r in enumerate(rows)])
    scalars = {k: _positive(table[k], f"{field}.{k}") for k in _SCALARS}
    vectors = {k: _floats(table[k], n_dof, f"{field}.{k}") for k in _VECTORS}
    flags = table["goal_scaling"]
    if not isinstance(flags, list) or len(flags) != n_dof:
        raise InputError(f"{field}.goal_scaling", f"must be a list of {n_dof} booleans")
    for i, b in enumerate(flags):
        if not isinstance(b, bool):
            raise InputError(f"{field}.goal_scaling[{i}]", f"must be true or false, not {b!r}")
    widths = _floats(table["widths"], n_basis, f"{field}.widths")
    for i, w in enumerate(widths):
        if w <= 0.0:
            raise InputError(f"{field}.widths[{i}]", f"must be positive, not {w!r}")
    provenance = doc.get("provenance", {})
    if not isinstance(provenance, dict):
        raise InputError("provenance", "must be a table")
    dmp = Dmp(weights, centers, widths, scalars["alpha"], scalars["beta"], scalars["alpha_s"],
              scalars["tau"], vectors["x0"], vectors["g"], vectors["xd0"],
              np.array(flags, dtype=bool))
    return dmp, provenance


def read_dmp_file(path, field: str = "DMP") -> tuple[Dmp, dict]:
    """The DMP in ``path`` and its provenance table; a file that cannot be read or parsed is
    an :class:`InputError` naming ``field``, a bad value one naming its own field."""
    return parse_dmp(read_toml(Path(path), field))


def read_dmp(path, field: str = "DMP") -> Dmp:
    """The DMP in ``path`` (:func:`read_dmp_file` without the provenance)."""
    return read_dmp_file(path, field)[0]
