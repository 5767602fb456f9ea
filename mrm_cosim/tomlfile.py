"""One reader for every TOML file a user gives (robots, experiments, lines).

Whatever is wrong with a file ends in one :class:`~mrm_cosim.errors.InputError` naming the
argument that gave it and saying what is wrong in the user's terms:

* it cannot be read (missing, a folder, no permission);
* it is larger than :data:`MAX_BYTES` (1 MiB): a description of a robot, an experiment or a
  line is a few kilobytes; anything far larger is the wrong file, and reading it whole would
  cost memory for nothing;
* it is not UTF-8 text (TOML is UTF-8 by its specification), with the offset of the first bad
  byte;
* it is not TOML, with tomllib's message — and for a key given twice, which tomllib reports
  only as "Cannot overwrite a value" without a place, the key's dotted name and line;
* it nests tables or arrays deeper than :data:`MAX_DEPTH` (tomllib recurses per level and
  ended in a RecursionError with thousands of lines of traceback): no description needs more
  than a handful of levels.
"""

from __future__ import annotations

import re
import tomllib

from mrm_cosim.errors import InputError

__all__ = ["MAX_BYTES", "MAX_DEPTH", "read_text", "read_toml", "parse_toml"]

MAX_BYTES = 1 << 20
"""The largest file read as a description (1 MiB)."""

MAX_DEPTH = 16
"""The deepest nesting of tables and arrays accepted."""

_HEADER = re.compile(r"^\s*\[\[?\s*([^\]]+?)\s*\]\]?\s*(#.*)?$")
_KEY = re.compile(r"^\s*([^=#\s][^=#]*?)\s*=")


def read_text(path, field: str, *, kind: str, max_bytes: int, encoding: str = "utf-8",
              why: str = "") -> str:
    """The text of the file at ``path``, at most ``max_bytes`` long; every problem (missing,
    a folder, unreadable, too large, not UTF-8) is an :class:`InputError` naming ``field``
    (the argument or option that gave the path) and the file, which ``kind`` names (``"TOML"``,
    ``"CSV"``). ``why``: what to add when the file is too large."""
    name = str(path)
    try:
        with open(path, "rb") as f:
            data = f.read(max_bytes + 1)
    except FileNotFoundError:
        raise InputError(field, f"{name!r} does not exist") from None
    except IsADirectoryError:
        raise InputError(field, f"{name!r} is a folder, not a {kind} file") from None
    except OSError as exc:
        raise InputError(field, f"cannot read {name!r}: {exc.strerror or exc}") from None
    if len(data) > max_bytes:
        size = f"{max_bytes >> 20} MiB" if max_bytes >= 1 << 22 else f"{max_bytes >> 10} KiB"
        raise InputError(field, f"{name!r} is larger than {size}{why}")
    try:
        return data.decode(encoding)
    except UnicodeDecodeError as exc:
        raise InputError(field, f"{name!r} is not UTF-8 text (byte 0x{data[exc.start]:02x} at "
                         f"offset {exc.start}); {kind} files are UTF-8") from None


def read_toml(path, field: str) -> dict:
    """The TOML document in ``path``; every problem is an :class:`InputError` naming
    ``field`` (the argument or option that gave the path) and the file."""
    text = read_text(path, field, kind="TOML", max_bytes=MAX_BYTES,
                     why="; a description is a few kilobytes (is it the right file?)")
    return parse_toml(text, field, str(path))


def parse_toml(text: str, field: str, name: str = "the document") -> dict:
    """``text`` parsed as TOML, with :func:`read_toml`'s errors (``name`` says which file)."""
    if len(text.encode("utf-8", "surrogatepass")) > MAX_BYTES:
        raise InputError(field, f"{name} is larger than {MAX_BYTES // 1024} KiB")
    depth = _bracket_depth(text)
    if depth > MAX_DEPTH:
        raise InputError(field, f"{name} nests arrays or inline tables {depth} deep; at most "
                         f"{MAX_DEPTH} levels are read")
    try:
        doc = tomllib.loads(text)
    except RecursionError:
        raise InputError(field, f"{name} nests too deep to be read (at most {MAX_DEPTH} "
                         "levels)") from None
    except tomllib.TOMLDecodeError as exc:
        raise InputError(field, f"{name} is not valid TOML: {_explain(text, exc)}") from None
    depth = _doc_depth(doc) - 1          # the containers below the document itself
    if depth > MAX_DEPTH:
        raise InputError(field, f"{name} nests tables {depth} deep; at most {MAX_DEPTH} "
                         "levels are read")
    return doc


def _bracket_depth(text: str) -> int:
    """Deepest nesting of ``[``/``{`` in values, outside strings and comments (an upper bound
    of the document's depth that is found without recursion)."""
    depth = deepest = 0
    quote = None
    i, n = 0, len(text)
    line_start = True
    while i < n:
        c = text[i]
        if quote:
            if c == "\\" and quote in ('"', '"""'):
                i += 2
                continue
            if text.startswith(quote, i):
                i += len(quote)
                quote = None
                continue
            i += 1
            continue
        if c in "\"'":
            quote = c * 3 if text.startswith(c * 3, i) else c
            i += len(quote)
            line_start = False
            continue
        if c == "#":
            j = text.find("\n", i)
            i = n if j < 0 else j
            continue
        if c == "[" and line_start and depth == 0:
            # a table header ([t] or [[t]]): not a value; skip to its end of line
            j = text.find("\n", i)
            i = n if j < 0 else j
            continue
        if c == "\n":
            line_start = depth == 0
        elif c in "[{":
            depth += 1
            deepest = max(deepest, depth)
            line_start = False
        elif c in "]}":
            depth = max(0, depth - 1)
        elif not c.isspace():
            line_start = False
        i += 1
    return deepest


def _doc_depth(value, level: int = 0) -> int:
    if level > MAX_DEPTH + 1:
        return level
    if isinstance(value, dict):
        return max((_doc_depth(v, level + 1) for v in value.values()), default=level + 1)
    if isinstance(value, list):
        return max((_doc_depth(v, level + 1) for v in value), default=level + 1)
    return level


def _explain(text: str, exc: tomllib.TOMLDecodeError) -> str:
    """tomllib's message, with the key's name where it gives none (a key given twice)."""
    message = str(exc)
    m = re.match(r"Cannot declare \((.*)\) twice \(at line (\d+)", message)
    if m:
        names = [n.strip().strip("'\"") for n in m.group(1).split(",") if n.strip()]
        return f"the table {'.'.join(names)!r} is declared more than once (again on line " \
               f"{m.group(2)})"
    if not message.startswith("Cannot overwrite a value"):
        return message
    lines = text.splitlines(keepends=True)

    def fails_here(k: int) -> bool:
        try:
            tomllib.loads("".join(lines[:k]))
        except tomllib.TOMLDecodeError as e:
            return str(e).startswith("Cannot overwrite a value")
        return False

    lo, hi = 1, len(lines)            # the shortest prefix that fails so: binary search
    if not fails_here(hi):
        return message
    while lo < hi:
        mid = (lo + hi) // 2
        if fails_here(mid):
            hi = mid
        else:
            lo = mid + 1
    table = ""
    for line in reversed(lines[:hi - 1]):
        m = _HEADER.match(line)
        if m:
            table = m.group(1).replace(" ", "")
            break
    m = _KEY.match(lines[hi - 1])
    key = m.group(1).replace(" ", "") if m else lines[hi - 1].strip()
    dotted = f"{table}.{key}" if table else key
    return f"the key {dotted!r} is given more than once (again on line {hi})"
