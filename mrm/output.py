"""Result folders written atomically: a failed run leaves no half-written folder behind."""

from __future__ import annotations

import contextlib
import json
import os
import shutil
import tempfile
from pathlib import Path

from mrm.errors import InputError

__all__ = ["atomic_output_dir", "atomic_write_text", "check_output_dir", "write_json"]


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

    An existing file is refused: replacing the folder would delete it.
    """
    path = Path(path)
    if path.exists() and not path.is_dir():
        raise InputError(field, f"{str(path)!r} is a file, not a folder (it is left alone; "
                         "give a folder to write the results to)")
    return path


@contextlib.contextmanager
def atomic_output_dir(path, field: str = "--out"):
    """Yield a fresh temporary folder beside ``path``; on success it replaces ``path``.

    If the body raises, the temporary folder is removed and ``path`` is left as it was. A
    ``path`` that :func:`check_output_dir` refuses raises its :class:`InputError` (naming
    ``field``) before anything is made.
    """
    path = check_output_dir(path, field)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix=f".{path.name}.", dir=path.parent))
    try:
        yield tmp
        check_output_dir(path, field)   # a file made there while the body ran: not replaced
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    old = None
    if path.exists():
        old = Path(tempfile.mkdtemp(prefix=f".{path.name}.old.", dir=path.parent))
        os.replace(path, old / path.name)
    os.replace(tmp, path)
    if old is not None:
        shutil.rmtree(old, ignore_errors=True)


def write_json(path, obj) -> None:
    """Write ``obj`` as indented JSON (the folder it goes to is made atomic by the caller)."""
    Path(path).write_text(json.dumps(obj, indent=2, sort_keys=False) + "\n")
