"""The command line's names for the library's fields: one mapping per command.

The library names what it refuses after its API arguments and configuration fields
(``InputError("duration", …)`` from :func:`cosim.track.run_track`); the user typed a flag
(``--duration``). Each command declares which flag sets which argument, and
:func:`named_by_flags` renames the field of an :class:`InputError` raised under it:
``duration`` → ``--duration``, ``params.slots`` → ``--param slots``, ``faults`` →
``--line-fault``. Fields of files (``gains.lam``, ``module_types.I.link_a``) match no
argument and pass unchanged.
"""

from __future__ import annotations

import functools

from mrm_cosim.errors import InputError

__all__ = ["flag_name", "named_by_flags", "OUT", "RUN_PREVIEW", "RUN_TRACK", "RUN_TABLE2",
           "RUN_LINE", "RUN_DMP_TABLE2",
           "HDL", "PLAN_SAMPLES", "BENCH", "SWEEP", "TUNE", "DMP_LEARN", "DMP_ROLLOUT"]

#: API argument -> flag, per command.
OUT = {"out": "--out"}
RUN_PREVIEW = {**OUT, "robot": "--robot", "duration": "--duration", "seed": "--seed",
               "uncertainty": "--uncertainty"}
RUN_TRACK = {**OUT, "robot": "--robot", "duration": "--duration", "seed": "--seed",
             "backend": "--backend", "controller": "--controller", "faults": "--line-fault",
             "vcd": "--vcd", "fst": "--fst", "signals": "--signals", "config": "--config"}
RUN_TABLE2 = {**OUT, "backend": "--backend", "duration": "--duration", "seed": "--seed",
              "config": "--config", "jobs": "--jobs"}
RUN_LINE = {**RUN_TRACK, "profile": "--profile", "file": "FILE"}
RUN_DMP_TABLE2 = {**OUT, "robot": "--robot", "backend": "--backend", "seed": "--seed",
                  "config": "--config", "paths": "--path", "jobs": "--jobs"}
HDL = {**OUT, "top": "--top", "family": "--family", "params": "--param"}
PLAN_SAMPLES = {"out": "--samples"}
BENCH = {"robot": "--robot", "backend": "--backend"}
SWEEP = {**OUT, "workers": "--workers", "scheduler": "--scheduler", "SPEC": "SPEC"}
TUNE = {**OUT, "workers": "--workers", "SPEC": "SPEC"}
DMP_LEARN = {**OUT, "n_basis": "--basis", "alpha": "--alpha", "alpha_s": "--alpha-s",
             "overlap": "--overlap", "columns": "--columns", "robot": "--robot"}
DMP_ROLLOUT = {"out": "--samples", "plot": "--plot", "g": "--goal", "tau": "--tau",
               "dt": "--dt", "duration": "--duration"}


def flag_name(field: str, flags: dict[str, str]) -> str:
    """``field`` as the user typed it: its leading argument replaced by its flag.

    ``"duration"`` → ``"--duration"``; a key below it (``"params.slots"``) follows the flag
    after a space (``"--param slots"``), an index directly (``"faults[1]"`` →
    ``"--line-fault[1]"``); a field of no argument in ``flags`` is returned unchanged.
    """
    for name, flag in flags.items():
        if field == name:
            return flag
        if field.startswith(name + "."):
            return f"{flag} {field[len(name) + 1:]}"
        if field.startswith(name + "["):
            return flag + field[len(name):]
    return field


def named_by_flags(flags: dict[str, str]):
    """Decorator of a command function: an :class:`InputError` it raises names the flag
    (:func:`flag_name`) instead of the API argument."""
    def wrap(func):
        @functools.wraps(func)
        def command(*args, **kwargs):
            try:
                return func(*args, **kwargs)
            except InputError as exc:
                renamed = flag_name(exc.field, flags)
                if renamed == exc.field:
                    raise
                raise InputError(renamed, exc.message) from None
        return command
    return wrap
