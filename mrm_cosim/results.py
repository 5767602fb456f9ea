"""Results written atomically: the one writer of every command's result folders and files.

A result folder (``mrm run … --out DIR``) is built in a hidden temporary folder beside it,
``.DIR.xxxx``, that replaces ``DIR`` only once complete; a result file (``--samples OUT.csv``,
``DIR/<top>.v``) is written to a hidden temporary file beside it, renamed over it when complete.
A failed or interrupted run therefore leaves the earlier results as they were.

What may be replaced: a regular file, an empty folder, or a folder this writer made (it holds
:data:`MARKER`; folders written before the marker existed are recognised by their
``summary.json`` beside a ``config.json`` or ``config.toml``). Refused, naming the field:
symbolic links, device nodes, FIFOs and sockets (writing "to" ``/dev/full`` used to replace the
device node with a regular file), other folders, and places where nothing can be made.

A temporary folder holds :data:`OWNER`, the process id and start time of the run that made
it; a run killed outright (SIGKILL) leaves it behind, and the next run writing beside it
removes it once that process is gone (:func:`remove_stale`). Temporary files carry the pid
in their name for the same purpose.

Errors name the API argument ``field`` (``"out"`` by default); the command line maps it to
its flag.
"""

from __future__ import annotations

import contextlib
import json
import os
import shutil
import stat
import tempfile
from pathlib import Path

from mrm_cosim.errors import InputError

__all__ = ["atomic_output_dir", "atomic_write_bytes", "atomic_write_text", "check_output_dir",
           "check_output_file", "check_writable_folder", "make_folder", "remove_empty",
           "remove_stale", "usual_mode", "write_json", "MARKER", "OWNER"]

#: File in every result folder this writer made: what made it (JSON).
MARKER = ".mrm-results"
#: File in every temporary folder: ``pid start_time`` of the process that owns it.
OWNER = ".mrm-owner"


# --- what may be replaced ------------------------------------------------------------------
def _kind(mode: int) -> str:
    for test, name in ((stat.S_ISLNK, "a symbolic link"), (stat.S_ISCHR, "a character device"),
                       (stat.S_ISBLK, "a block device"), (stat.S_ISFIFO, "a FIFO"),
                       (stat.S_ISSOCK, "a socket")):
        if test(mode):
            return name
    return "not a regular file or folder"


def _lstat(path: Path):
    try:
        return path.lstat()
    except FileNotFoundError:
        return None
    except OSError as exc:
        raise InputError("out", f"{str(path)!r}: {exc.strerror or exc}") from None


def _made_here(folder: Path) -> bool:
    """Whether ``folder`` may be replaced: empty, or a result folder (marker, or an older
    result folder's summary.json beside its config)."""
    try:
        names = set(os.listdir(folder))
    except OSError:
        return False
    return (not names or MARKER in names
            or ("summary.json" in names and bool(names & {"config.json", "config.toml"})))


def check_output_dir(path, field: str = "out") -> Path:
    """``path`` as a result folder that :func:`atomic_output_dir` may replace, or
    :class:`InputError` naming ``field``; commands call it before anything runs.

    Refused: an empty name; a symbolic link, device node, FIFO or socket; an existing file (
    replacing the folder would delete it); a folder that is neither empty nor a result folder
    (replacing it would delete what it holds); the current folder, a folder that holds it, or
    the root; a place where no folder can be made (under a file, read-only, ``/proc``).
    """
    text = str(path)
    if not text.strip():
        raise InputError(field, "must name a folder, not an empty string")
    path = Path(path)
    st = _lstat(path)
    if st is not None and not stat.S_ISDIR(st.st_mode):
        if stat.S_ISREG(st.st_mode):
            raise InputError(field, f"{text!r} is a file, not a folder (it is left alone; "
                             "give a folder to write the results to)")
        raise InputError(field, f"{text!r} is {_kind(st.st_mode)}: results are written only "
                         "as a folder of their own (it is left alone)")
    resolved = path.resolve()
    cwd = Path.cwd().resolve()
    if path.name in ("", ".", "..") or resolved == cwd or resolved in cwd.parents:
        raise InputError(field, f"{text!r} is the current folder, one that holds it, or the "
                         "root; the results replace the whole folder: name a folder of their "
                         "own, e.g. results/run")
    if st is not None and not _made_here(path):
        raise InputError(field, f"{text!r} is a folder that holds other files than results "
                         "of this tool; they would be deleted: name a new or empty folder "
                         "(it is left alone)")
    check_writable_folder(resolved.parent, field, text)
    return path


def check_output_file(path, field: str = "out") -> Path:
    """``path`` as a result file that :func:`atomic_write_text` may replace, or
    :class:`InputError` naming ``field``: a regular file or nothing yet, in an existing
    folder. Refused: a folder, a symbolic link, device node, FIFO or socket."""
    text = str(path)
    if not text.strip():
        raise InputError(field, "must name a file, not an empty string")
    path = Path(path)
    st = _lstat(path)
    if st is not None and stat.S_ISDIR(st.st_mode):
        raise InputError(field, f"{text!r} is a folder; name the file to write")
    if st is not None and not stat.S_ISREG(st.st_mode):
        raise InputError(field, f"{text!r} is {_kind(st.st_mode)}: only a regular file is "
                         "replaced (it is left alone)")
    if not path.absolute().parent.is_dir():
        raise InputError(field, f"folder {str(path.absolute().parent)!r} does not exist")
    return path


def check_writable_folder(path, field: str = "out", text: str | None = None) -> Path:
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


def make_folder(path, field: str = "out") -> list[Path]:
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


# --- who owns a temporary folder ---------------------------------------------------------
def _start_time(pid: int) -> str | None:
    """The start time of process ``pid`` (clock ticks since boot, from ``/proc``), so that a
    recycled pid is not taken for the owner; ``None`` where there is no ``/proc``."""
    try:
        text = Path(f"/proc/{pid}/stat").read_text()
    except OSError:
        return None
    return text.rsplit(")", 1)[1].split()[19]


def _owner_text() -> str:
    pid = os.getpid()
    return f"{pid} {_start_time(pid) or '-'}\n"


def _alive(owner: str) -> bool:
    """Whether the process an :data:`OWNER` file names still runs (unreadable: assumed so)."""
    try:
        pid_text, start = owner.split()
        pid = int(pid_text)
    except ValueError:
        return True
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except OSError:          # exists, owned by someone else
        return True
    now = _start_time(pid)
    return start == "-" or now is None or now == start


def _pid_alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except OSError:
        return True
    return True


def remove_stale(path) -> list[Path]:
    """Remove what runs killed outright left beside the result ``path``: hidden temporary
    folders ``.NAME.*`` whose :data:`OWNER` names a process that is gone, and hidden
    temporary files ``.NAME.PID.*.tmp`` of a pid that is gone. A folder put aside while
    results were replaced (``.NAME.old.*``) goes back to ``NAME`` if that is missing. Nothing
    without such proof is touched. Returns what was removed."""
    path = Path(path)
    parent = path.parent if str(path.parent) else Path(".")
    removed = []
    try:
        entries = list(parent.iterdir())
    except OSError:
        return removed
    prefix = f".{path.name}."
    for entry in entries:
        if not entry.name.startswith(prefix) or entry.is_symlink():
            continue
        rest = entry.name[len(prefix):]
        if entry.is_dir():
            try:
                owner = (entry / OWNER).read_text()
            except OSError:
                continue
            if _alive(owner):
                continue
            kept = entry / path.name
            if rest.startswith("old.") and kept.is_dir() and not os.path.lexists(path):
                with contextlib.suppress(OSError):
                    os.replace(kept, path)
            shutil.rmtree(entry, ignore_errors=True)
            removed.append(entry)
        elif entry.is_file() and entry.name.endswith(".tmp"):
            pid = rest.split(".", 1)[0]
            if pid.isdigit() and not _pid_alive(int(pid)):
                with contextlib.suppress(OSError):
                    entry.unlink()
                    removed.append(entry)
    return removed


def _owned_tempdir(path: Path, prefix: str) -> Path:
    tmp = Path(tempfile.mkdtemp(prefix=prefix, dir=path.parent))
    (tmp / OWNER).write_text(_owner_text())
    return tmp


# --- writers -------------------------------------------------------------------------------
def atomic_write_text(path, text: str, field: str = "out") -> None:
    """Write ``text`` to the result file ``path`` through a temporary file beside it that
    replaces it only once complete; the file gets the usual permissions (0666 less the umask).
    ``path`` must pass :func:`check_output_file` (before and again just before the rename);
    an error writing it is an :class:`InputError` naming ``field``."""
    _atomic_write(path, text, field)


def atomic_write_bytes(path, data: bytes, field: str = "out") -> None:
    """:func:`atomic_write_text` for binary contents (a PNG)."""
    _atomic_write(path, bytes(data), field)


def _atomic_write(path, data: str | bytes, field: str) -> None:
    path = check_output_file(path, field)
    remove_stale(path)
    try:
        fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.{os.getpid()}.", suffix=".tmp",
                                   dir=path.absolute().parent)
    except OSError as exc:
        raise InputError(field, f"cannot write {str(path)!r} ({exc.strerror or exc})") from None
    try:
        with (os.fdopen(fd, "wb") if isinstance(data, bytes)
              else os.fdopen(fd, "w", newline="")) as f:
            f.write(data)
        os.chmod(tmp, 0o666 & ~_umask())
        check_output_file(path, field)    # made a link or a FIFO meanwhile: left alone
        os.replace(tmp, path)
    except OSError as exc:      # /proc/x.csv, a read-only folder, a full disk
        Path(tmp).unlink(missing_ok=True)
        raise InputError(field, f"cannot write {str(path)!r} ({exc.strerror or exc})") from None
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


@contextlib.contextmanager
def atomic_output_dir(path, field: str = "out", made_by: str = "mrm"):
    """Yield a fresh temporary folder beside ``path``; on success it replaces ``path``.

    If the body raises (an interrupt included), the temporary folder (and any folder made
    above ``path``) is removed and ``path`` is left as it was. A ``path`` that
    :func:`check_output_dir` refuses raises its :class:`InputError` (naming ``field``) before
    anything is made. Stale temporary folders of killed runs are removed first
    (:func:`remove_stale`). The result folder holds :data:`MARKER` (``made_by``: the command).
    """
    path = check_output_dir(path, field)
    remove_stale(path)
    made = make_folder(path.parent, field)
    try:
        tmp = _owned_tempdir(path, f".{path.name}.")
    except OSError as exc:
        remove_empty(made)
        raise InputError(field, f"{str(path)!r}: cannot write in its folder "
                         f"({exc.strerror or exc})") from None
    try:
        yield tmp
        check_output_dir(path, field)   # a file made there while the body ran: not replaced
        (tmp / OWNER).unlink()
        write_json(tmp / MARKER, {"made_by": made_by})
        os.chmod(tmp, 0o777 & ~_umask())  # mkdtemp's 0700 would hide the results from others
        old = None
        if os.path.lexists(path):
            old = _owned_tempdir(path, f".{path.name}.old.")
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


def usual_mode(path) -> None:
    """Give the file ``path`` the mode a new file gets (0666 less the umask): files made with
    ``mkstemp`` (a VCD written beside its target, then renamed) are 0600 otherwise."""
    os.chmod(path, 0o666 & ~_umask())


def _umask() -> int:
    mask = os.umask(0o022)
    os.umask(mask)
    return mask


def write_json(path, obj) -> None:
    """Write ``obj`` as indented JSON (the folder it goes to is made atomic by the caller)."""
    Path(path).write_text(json.dumps(obj, indent=2, sort_keys=False) + "\n")
