"""What the backends keep between runs, listed and pruned (``mrm cache``).

Everything lives under :func:`cosim.compiled.cache_dir` (``$MRM_CACHE_DIR``, else
``$XDG_CACHE_HOME/mrm-cosim``, else ``~/.cache/mrm-cosim``), in one folder a kind:

* ``verilog``: a design's Verilog and its signed ports (``<key>-<sources>.v`` and ``.json``),
  named by the design and a digest of the gateware's sources, so every change of the
  gateware adds entries and leaves the old ones;
* ``verilator``: a Verilator build of a Verilog text (``<top>-<digest>/``);
* ``split``: the C++ loop of the compiled backend on threads (``<digest>/``);
* ``numba``: the model backend's compiled inner loop (``<digest>/``);
* ``pin``: that loop's call into pinocchio, a small shared library (``<digest>/``,
  :mod:`cosim.pin_shim`).

An entry is used when a run takes it from the cache (its modification time is set then:
:func:`mark_used`), so ``--older-than`` means "not used for that long". A folder whose name
starts with a dot is a build under way, or one a killed process left; it is removed only
when an hour old. Removing an entry a running simulation has loaded does not disturb it
(its code stays mapped); a run that looks for it afterwards builds it again.
"""

from __future__ import annotations

import dataclasses
import os
import shutil
import time
from pathlib import Path

from mrm_cosim.errors import InputError

__all__ = ["KINDS", "Entry", "entries", "mark_used", "prune"]

#: the cache's folders, in the order they are listed
KINDS = ("verilog", "verilator", "split", "numba", "pin")

#: an unfinished build (a dot folder) younger than this is left alone: it may be under way
UNFINISHED_GRACE_S = 3600.0


@dataclasses.dataclass(frozen=True)
class Entry:
    """One cache entry: its files (a Verilog entry has two), bytes, last use (Unix time)."""

    kind: str
    name: str
    paths: tuple[Path, ...]
    size: int
    used: float
    unfinished: bool = False


def _size(path: Path) -> int:
    if path.is_symlink() or not path.is_dir():
        return path.lstat().st_size
    total = 0
    for root, _, files in os.walk(path):
        for f in files:
            try:
                total += (Path(root) / f).lstat().st_size
            except FileNotFoundError:          # removed meanwhile
                pass
    return total


def entries(root: Path | None = None) -> list[Entry]:
    """Every entry under ``root`` (default the cache folder), kind by kind, oldest use
    first."""
    from mrm_cosim.cosim.compiled import cache_dir

    root = cache_dir() if root is None else Path(root)
    found = []
    for kind in KINDS:
        folder = root / kind
        if not folder.is_dir():
            continue
        groups: dict[str, list[Path]] = {}
        for path in folder.iterdir():
            # a Verilog entry is its .v and .json; atomic writes' temporaries are dot files
            name = path.stem if kind == "verilog" and path.is_file() else path.name
            groups.setdefault(name, []).append(path)
        for name, paths in groups.items():
            try:
                used = max(p.lstat().st_mtime for p in paths)
                size = sum(_size(p) for p in paths)
            except FileNotFoundError:              # removed meanwhile
                continue
            found.append(Entry(kind, name, tuple(sorted(paths)), size, used,
                               unfinished=name.startswith(".")))
    return sorted(found, key=lambda e: (KINDS.index(e.kind), e.used, e.name))


def mark_used(*paths: Path) -> None:
    """Set the modification time of cache entries a run takes (best effort: a read-only
    cache is still a cache)."""
    for path in paths:
        try:
            os.utime(path)
        except OSError:
            pass


def _remove(path: Path) -> None:
    """Remove one file or folder; a folder is first renamed to a dot name beside it, so no
    run ever finds it half removed under its own name."""
    if path.is_dir() and not path.is_symlink():
        doomed = path.with_name(f".{path.name}.removing-{os.getpid()}")
        try:
            os.replace(path, doomed)
        except FileNotFoundError:
            return
        shutil.rmtree(doomed, ignore_errors=True)
    else:
        try:
            path.unlink()
        except FileNotFoundError:
            pass


def prune(older_than_days: float | None = None, kinds=KINDS, *, dry_run: bool = False,
          root: Path | None = None, now: float | None = None) -> list[Entry]:
    """Remove the entries of ``kinds`` not used for ``older_than_days`` days (all of them
    when None), and unfinished builds over an hour old; return what was (or, with
    ``dry_run``, would be) removed."""
    if older_than_days is not None:
        if isinstance(older_than_days, bool) or not isinstance(older_than_days, (int, float)) \
                or not older_than_days >= 0:
            raise InputError("older_than", f"must be a number of days >= 0, not "
                             f"{older_than_days!r}")
    kinds = tuple(kinds)
    for kind in kinds:
        if kind not in KINDS:
            raise InputError("kind", f"must be one of {', '.join(KINDS)}, not {kind!r}")
    now = time.time() if now is None else now
    limit = None if older_than_days is None else now - older_than_days * 86400.0
    doomed = []
    for entry in entries(root):
        if entry.kind not in kinds:
            continue
        if entry.unfinished:
            if entry.used > now - UNFINISHED_GRACE_S:
                continue
        elif limit is not None and entry.used > limit:
            continue
        doomed.append(entry)
    if not dry_run:
        for entry in doomed:
            # a Verilog entry's signed ports first: its .v alone is not taken from the cache
            for path in sorted(entry.paths, key=lambda p: p.suffix != ".json"):
                _remove(path)
    return doomed
