"""Files written whole or not at all.

Every file the package writes goes through :func:`write_atomically`: the
bytes go to a temporary file in the target's own folder, which is flushed
to the disk and renamed over the target only when it is complete. A failure
at any point (a full disk, a read-only folder, Ctrl-C) removes the
temporary and leaves an existing target as it was. :func:`check_writable`
and :func:`check_folder` say, before a long computation, whether its output
could be written at all.
"""

from __future__ import annotations

import os
import shutil
import tempfile
from contextlib import contextmanager
from pathlib import Path
from typing import BinaryIO, Callable

from .errors import Error
from .interrupt import held_off, put_in_place
from .system import proc_field

#: Temporary files and folders not yet renamed into place. A process that
#: must end at once (Ctrl-C while stuck in a long computation) removes
#: them with :func:`discard_pending`.
_pending: set[Path] = set()


class WriteError(Error, OSError):
    """A file or folder could not be written; the message says which and why."""


class ReadError(Error, OSError):
    """A file to read is missing, or is a folder."""


def check_readable(path: str | Path, what: str = "scene file") -> Path:
    """``path`` if it is a file, else a :class:`ReadError` that says why."""
    path = Path(path)
    if path.is_dir():
        raise ReadError(f"{what} '{path}' is a folder, not a file.")
    if not path.is_file():
        raise ReadError(f"{what} '{path}' does not exist.")
    return path


def cannot_write(path, why: str) -> WriteError:
    return WriteError(f"cannot write '{path}': {why}.")


def reason(error: OSError) -> str:
    """What the system said went wrong, without the file name (the
    sentence names it); never empty."""
    text = error.strerror or str(error)
    return text[0].lower() + text[1:] if text else f"{type(error).__name__} without a reason"


def check_writable(path: str | Path) -> Path:
    """``path`` if a file can be written there: it is not a folder, and its
    folder exists or can be made, and takes a new file (tried with a probe
    file, created and removed). Raises :class:`WriteError` otherwise."""
    path = Path(path)
    if path.is_dir():
        raise cannot_write(path, "it is a folder")
    _probe(path, Path(os.path.realpath(path)).parent)
    return path


def check_folder(folder: str | Path) -> Path:
    """``folder`` if files can be written in it (as :func:`check_writable`)."""
    folder = Path(folder)
    if folder.exists() and not folder.is_dir():
        raise cannot_write(folder, "it is a file, not a folder")
    _probe(folder, folder)
    return folder


def _probe(target: Path, folder: Path) -> None:
    """Create and remove a file in ``folder``'s nearest existing ancestor
    (the folders below it are made when the file is written)."""
    existing = Path(os.path.abspath(folder))
    while not existing.exists():
        existing = existing.parent
    if not existing.is_dir():
        raise cannot_write(target, f"'{existing}' is a file, not a folder")
    try:
        with held_off():  # made and removed, never left behind
            handle, name = tempfile.mkstemp(dir=existing, prefix=".mitsuba-whitted-probe-")
            os.close(handle)
            os.unlink(name)
    except OSError as error:
        raise cannot_write(target, reason(error)) from error


def write_atomically(path: str | Path, write: Callable[[BinaryIO], None]) -> Path:
    """Write ``path`` whole or not at all: ``write(file)`` fills a temporary
    file next to it, which replaces ``path`` once it is complete and on
    the disk. An existing file keeps its permissions; a new one gets those
    the umask allows; a symbolic link is written through. Raises
    :class:`WriteError` (with the system's reason) and leaves no temporary
    behind, whatever stopped it."""
    path = Path(path)
    target = Path(os.path.realpath(path))
    with held_off():  # the temporary is noted for removal as soon as it exists
        try:
            target.parent.mkdir(parents=True, exist_ok=True)
            mode = _mode_for(target, 0o666)
            handle = tempfile.NamedTemporaryFile(dir=target.parent, prefix=f".{target.name}.",
                                                 suffix=".partial", delete=False)
        except OSError as error:
            raise cannot_write(path, reason(error)) from error
        temporary = Path(handle.name)
        _pending.add(temporary)
    try:
        with handle:
            write(handle)
            handle.flush()
            os.fchmod(handle.fileno(), mode)
            os.fsync(handle.fileno())
        put_in_place(temporary, target)
    except WriteError:
        raise
    except OSError as error:
        raise cannot_write(path, reason(error)) from error
    finally:
        temporary.unlink(missing_ok=True)
        _pending.discard(temporary)
    return path


def write_text(path: str | Path, text: str) -> Path:
    """``text`` (UTF-8) written to ``path`` by :func:`write_atomically`."""
    return write_atomically(path, lambda file: file.write(text.encode()))


def _mode_for(path: Path, full: int) -> int:
    """The permissions of ``path`` if it exists, else ``full`` less the umask."""
    if path.exists():
        return path.stat().st_mode & 0o7777
    umask = proc_field("/proc/self/status", "Umask")
    return full & ~(int(umask, 8) if umask else 0o022)


@contextmanager
def replaced_folder(target: str | Path):
    """A new, empty folder to fill in place of ``target``: when the block
    ends normally it takes ``target``'s place (the old folder is then
    removed); when it fails it is removed and ``target`` stays as it was."""
    target = Path(target)
    if target.exists() and not target.is_dir():
        raise cannot_write(target, "it is a file, not a folder")
    with held_off():  # the staging folder is noted for removal as soon as it exists
        try:
            target.parent.mkdir(parents=True, exist_ok=True)
            mode = _mode_for(target, 0o777)
            staging = Path(tempfile.mkdtemp(dir=target.parent, prefix=f".{target.name}.",
                                            suffix=".partial"))
        except OSError as error:
            raise cannot_write(target, reason(error)) from error
        _pending.add(staging)
    try:
        staging.chmod(mode)
        yield staging
        _swap_in(staging, target)
    finally:
        shutil.rmtree(staging, ignore_errors=True)
        _pending.discard(staging)


def _swap_in(staging: Path, target: Path) -> None:
    """Put ``staging`` at ``target``. The old ``target``, moved aside
    first, is put back if that fails (or is interrupted), and removed once
    a folder is at ``target`` again."""
    aside = staging.with_suffix(".old")
    try:
        if target.exists():
            os.rename(target, aside)
        os.rename(staging, target)
    except BaseException as error:
        if aside.exists() and not target.exists():
            os.rename(aside, target)
        if isinstance(error, OSError):
            raise cannot_write(target, reason(error)) from error
        raise
    finally:
        if target.exists():
            shutil.rmtree(aside, ignore_errors=True)


def discard_pending() -> None:
    """Remove every temporary file and folder not yet in place."""
    for path in list(_pending):
        if path.is_dir():
            shutil.rmtree(path, ignore_errors=True)
        else:
            path.unlink(missing_ok=True)
