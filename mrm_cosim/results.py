"""Result folders written atomically: a failed run leaves no half-written folder behind."""

from __future__ import annotations

import contextlib
import json
import os
import shutil
import tempfile
from pathlib import Path

from mrm_cosim.errors import InputError

__all__ = ["atomic_output_dir", "atomic_write_text", "check_output_dir", "check_writable_folder",
           "make_folder", "remove_empty", "write_json"]


def atomic_write_text(path, text: str) -> None:
    """Write ``text`` to ``path`` through a temporary file beside it that replaces it only once
    complete; the file gets the usual permissions (0666 less the umask)."""
    path = Path(path)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent)
    try:
        with os.fdopen(fd, "w", newline="") as f:
            f.write(text)
        umask = os.umask(0)
        os.umask(umask)
        os.chmod(tmp, 0o666 & ~umask)
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


def check_output_dir(path, field: str = "--out") -> Path:
    """``path`` as a result folder that :func:`atomic_output_dir` may replace, or
    :class:`InputError` naming ``field``; commands call it before anything runs.

    Refused: an empty name; an existing file (replacing the folder would delete it); the
    current folder, a folder that holds it, or the root (``.``, ``..``, ``/``: they cannot be
    replaced, and the attempt left temporary folders behind); a place where no folder can be
    made (under a file, read-only, ``/proc``).
    """
    text = str(path)
    if not text.strip():
        raise InputError(field, "must name a folder, not an empty string")
    path = Path(path)
    if path.exists() and not path.is_dir():
        raise InputError(field, f"{text!r} is a file, not a folder (it is left alone; "
                         "give a folder to write the results to)")
    resolved = path.resolve()
    cwd = Path.cwd().resolve()
    if path.name in ("", ".", "..") or resolved == cwd or resolved in cwd.parents:
        raise InputError(field, f"{text!r} is the current folder, one that holds it, or the "
                         "root; the results replace the whole folder: name a folder of their "
                         "own, e.g. results/run")
    check_writable_folder(resolved.parent, field, text)
    return path


def check_writable_folder(path, field: str = "--out", text: str | None = None) -> Path:
    """``path`` as a folder to write files in, or :class:`InputError` naming ``field``: it
    is a folder, or the nearest of its ancestors that exists is a folder, and something can be
    made there (nothing is left behind by the check)."""
    text = str(path) if text is None else text
    folder = Path(path).resolve()
    while not folder.exists():
        folder = folder.parent
    if not folder.is_dir():
        raise InputError(field, f"{text!r}: {str(folder)!r} is a file, not a folder")
    try:
        os.rmdir(tempfile.mkdtemp(prefix=".mrm-probe.", dir=folder))
    except OSError as exc:
        raise InputError(field, f"{text!r}: cannot write in {str(folder)!r} "
                         f"({exc.strerror or exc})") from None
    return Path(path)


def make_folder(path, field: str = "--out") -> list[Path]:
    """Make the folder ``path`` and its missing ancestors; return the folders made, deepest
    first (for :func:`remove_empty` on a later failure). :class:`InputError` naming ``field``
    if it cannot be made; then nothing is left behind."""
    path = Path(path)
    made = [p for p in (path, *path.parents) if not p.exists()]
    try:
        path.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        remove_empty(made)
        raise InputError(field, f"cannot make the folder {str(path)!r} "
                         f"({exc.strerror or exc})") from None
    return made


def remove_empty(folders: list[Path]) -> None:
    """Remove each of ``folders`` that is empty, in order (deepest first)."""
    for folder in folders:
        with contextlib.suppress(OSError):
            folder.rmdir()


@contextlib.contextmanager
def atomic_output_dir(path, field: str = "--out"):
    """Yield a fresh temporary folder beside ``path``; on success it replaces ``path``.

    If the body raises, the temporary folder (and any folder made above ``path``) is removed
    and ``path`` is left as it was. A ``path`` that :func:`check_output_dir` refuses raises
    its :class:`InputError` (naming ``field``) before anything is made.
    """
    path = check_output_dir(path, field)
    made = make_folder(path.parent, field)
    try:
        tmp = Path(tempfile.mkdtemp(prefix=f".{path.name}.", dir=path.parent))
    except OSError as exc:
        remove_empty(made)
        raise InputError(field, f"{str(path)!r}: cannot write in its folder "
                         f"({exc.strerror or exc})") from None
    try:
        yield tmp
        check_output_dir(path, field)   # a file made there while the body ran: not replaced
        os.chmod(tmp, 0o777 & ~_umask())  # mkdtemp's 0700 would hide the results from others
        old = None
        if path.exists():
            old = Path(tempfile.mkdtemp(prefix=f".{path.name}.old.", dir=path.parent))
            os.replace(path, old / path.name)
        try:
            os.replace(tmp, path)
        except BaseException:
            if old is not None:                     # put the old results back
                os.replace(old / path.name, path)
            raise
        finally:
            if old is not None:
                shutil.rmtree(old, ignore_errors=True)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        remove_empty(made)
        raise


def _umask() -> int:
    mask = os.umask(0o022)
    os.umask(mask)
    return mask


def write_json(path, obj) -> None:
    """Write ``obj`` as indented JSON (the folder it goes to is made atomic by the caller)."""
    Path(path).write_text(json.dumps(obj, indent=2, sort_keys=False) + "\n")
