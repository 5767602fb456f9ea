"""Helpers for building the gateware: shapes of the protocol's enums, parameter checks.

* :func:`shaped_enum` — the protocol room (:mod:`mrm_cosim.protocol`) defines each encoded
  field once, as a plain :class:`enum.IntEnum` that the master and the references use. The
  gateware needs the same values as an :class:`amaranth.lib.enum.Enum` with an explicit width,
  so that a field of a :class:`~amaranth.lib.data.Struct` has its wire width and
  ``m.Case(Kind.X)`` matches by name; this makes one from the other, so names and values are
  written only once.
* :func:`rejecting` — check a component's parameters without Amaranth reporting the refused
  component as created but never used.
"""

import contextlib
import enum as py_enum

from amaranth.lib import enum

__all__ = ["shaped_enum", "rejecting"]


def shaped_enum(values: type[py_enum.IntEnum], shape: int, module: str) -> type[enum.Enum]:
    """An Amaranth enum with the members of ``values`` (same names, same values, same order).

    Parameters
    ----------
    values : IntEnum subclass
        The protocol room's definition.
    shape : int
        Width in bits of the field that holds it.
    module : str
        Module the new class belongs to (``__name__`` of the caller), for docs and messages.

    Returns
    -------
    amaranth.lib.enum.Enum subclass
        Named as ``values``, with ``shape`` bits.
    """
    if any(member.value >= 1 << shape or member.value < 0 for member in values):
        raise ValueError(f"{values.__name__} does not fit {shape} unsigned bits")
    namespace = enum.EnumMeta.__prepare__(values.__name__, (enum.Enum,), shape=shape)
    namespace["__module__"] = module
    namespace["__qualname__"] = values.__name__
    namespace["__doc__"] = values.__doc__
    for member in values:
        namespace[member.name] = member.value
    return enum.EnumMeta(values.__name__, (enum.Enum,), namespace, shape=shape)


@contextlib.contextmanager
def rejecting(elaboratable):
    """Validate inside this block: if it raises, ``elaboratable`` (just created, now useless)
    is not reported by Amaranth as created but never used."""
    try:
        yield
    except BaseException:
        elaboratable._MustUse__silence = True
        raise
