"""Atomic file output: write to a temporary file beside the target, rename on success.

A crash, an exception or Ctrl-C leaves either the old file or no file, never a half-written one.
A write that fails for lack of space, quota or permission ends in one
:class:`~sparsebtf.errors.OutputError` ("no space left on device while writing X; nothing was
written"), with the temporary file removed. Temporaries carry their writer's process id
(``.NAME.PID-HOST.XXXX.part``), so the next write into the folder removes those whose writer
was killed (``kill -9`` runs no cleanup), whichever output they were for.
The file gets the permissions any other tool's would (0666 less the umask), not mkstemp's 0600.
"""

from __future__ import annotations

import contextlib
import errno
import hashlib
import os
import re
import socket
import tempfile
from collections.abc import Iterator
from pathlib import Path

from .errors import OutputError

__all__ = ["atomic_output", "output_error", "remove_stale_parts", "temporary_dir"]

#: errno values that can only come from writing (a read of an input never raises them).
_WRITE_ERRNOS = {
    errno.ENOSPC: "no space left on device",
    errno.EDQUOT: "disk quota exceeded",
    errno.EFBIG: "file size limit exceeded",
    errno.EROFS: "read-only file system",
}
#: errno values that mean a bad output path when raised by the output's own file operations.
_PATH_ERRNOS = {
    errno.EACCES: "permission denied",
    errno.EPERM: "operation not permitted",
    errno.ENOTDIR: "a parent of the path is a file, not a folder",
    errno.EISDIR: "the path is a folder",
    errno.ENOENT: "the folder does not exist",
    errno.ENAMETOOLONG: "the name is too long",
    errno.EEXIST: "a parent of the path is a file, not a folder",
}


def _host() -> str:
    return hashlib.sha1(socket.gethostname().encode()).hexdigest()[:8]


def _owner() -> str:
    return f"{os.getpid()}-{_host()}"


#: Our temporaries: ``.NAME.PID-HOST.XXXX.part`` (files and folders being written) and
#: ``.NAME.PID-HOST.XXXX.old`` (a folder being replaced); mkstemp's XXXX has no dots.
_TEMP_RE = re.compile(r"^\.(?P<name>.+)\.(?P<pid>\d+)-(?P<host>[0-9a-f]{8})\.[A-Za-z0-9_]+\."
                      r"(?:part|old)$")
#: Another host's temporaries cannot be asked whether their writer lives: they are removed
#: only when untouched this long (a live writer keeps its file's mtime fresh).
FOREIGN_STALE_SECONDS = 7 * 24 * 3600


def _alive(pid: int) -> bool:
    if os.name == "nt":  # os.kill would terminate it there: never guess, keep the file
        return True
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except OSError:  # exists, owned by someone else
        return True
    return True


def _stale(entry: os.DirEntry[str], host: str, now: float) -> bool:
    """Whether ``entry`` is one of our temporaries whose writer is gone: on this host, its
    process id is not alive; from another host, it is older than FOREIGN_STALE_SECONDS."""
    m = _TEMP_RE.match(entry.name)
    if m is None:
        return False
    if m.group("host") == host:
        return int(m.group("pid")) != os.getpid() and not _alive(int(m.group("pid")))
    try:
        return now - entry.stat(follow_symlinks=False).st_mtime > FOREIGN_STALE_SECONDS
    except OSError:
        return False


def remove_stale_parts(target: Path) -> list[Path]:
    """Remove the temporaries of dead writers (``kill -9`` runs no cleanup) from the folder
    of ``target``, whatever output they were for: ``.NAME.PID-HOST.XXXX.part`` / ``.old``
    files and folders whose process is gone on this host (or, from another host, untouched
    for a week). A live writer's temporaries, and any other file, are kept. Returns the
    paths removed."""
    import shutil
    import time

    removed: list[Path] = []
    host, now = _host(), time.time()
    with contextlib.suppress(OSError):
        for entry in os.scandir(target.parent):
            if not _stale(entry, host, now):
                continue
            _restore_replaced(entry)
            with contextlib.suppress(FileNotFoundError):
                if entry.is_dir(follow_symlinks=False):
                    shutil.rmtree(entry.path)
                else:
                    os.unlink(entry.path)
                removed.append(Path(entry.path))
    return removed


def _restore_replaced(entry: os.DirEntry[str]) -> None:
    """A dead writer's ``.NAME.….old`` folder holds the previous output as ``x`` while the new
    one is renamed into place (:func:`sparsebtf.rendering.viewer.export`); killed between the
    two renames, NAME is missing: put the previous output back rather than delete it."""
    m = _TEMP_RE.match(entry.name)
    if m is None or not entry.name.endswith(".old"):
        return
    previous, target = Path(entry.path) / "x", Path(entry.path).parent / m.group("name")
    with contextlib.suppress(OSError):
        if previous.exists() and not target.exists():
            os.replace(previous, target)


def temporary_dir(target: Path, suffix: str = ".part") -> Path:
    """A new empty folder beside ``target`` named as our temporaries are (so a later run
    removes it if this process is killed), with the permissions ``mkdir`` would give it
    (0777 less the umask, not mkdtemp's 0700)."""
    tmp = Path(tempfile.mkdtemp(prefix=f".{target.name}.{_owner()}.", suffix=suffix,
                                dir=target.parent))  # fmt: skip
    os.chmod(tmp, 0o777 & ~_umask())
    return tmp


def output_error(exc: OSError, target: Path, *, any_errno: bool = False) -> OutputError | None:
    """The one-line :class:`OutputError` for an ``OSError`` met while writing ``target``, or
    None when the error is not about the output (``any_errno`` accepts path errors too)."""
    what = _WRITE_ERRNOS.get(exc.errno or 0)
    if what is None and any_errno:
        what = _PATH_ERRNOS.get(exc.errno or 0) or (exc.strerror or str(exc)).lower()
    if what is None:
        return None
    kept = " (the previous file is unchanged)" if target.exists() else ""
    return OutputError(f"{what} while writing {target}; nothing was written{kept}")


@contextlib.contextmanager
def atomic_output(path: str | os.PathLike[str]) -> Iterator[Path]:
    """Yield a temporary path beside ``path``; move it onto ``path`` if the block succeeds."""
    target = Path(path)
    try:
        target.parent.mkdir(parents=True, exist_ok=True)
        remove_stale_parts(target)
        fd, tmp = tempfile.mkstemp(
            prefix=f".{target.name}.{_owner()}.", suffix=".part", dir=target.parent
        )
    except OSError as e:
        raise output_error(e, target, any_errno=True) from None  # type: ignore[misc]
    tmp_path = Path(tmp)
    # From here on the temporary is removed on any way out: a SIGTERM (SystemExit) in the
    # moment after its creation left it behind (seen on a loaded machine).
    try:
        try:
            os.close(fd)
            os.chmod(tmp, 0o666 & ~_umask())
        except OSError as e:
            raise output_error(e, target, any_errno=True) from None  # type: ignore[misc]
        yield tmp_path
        try:
            os.replace(tmp_path, target)
        except OSError as e:
            raise output_error(e, target, any_errno=True) from None  # type: ignore[misc]
    except OSError as e:
        with contextlib.suppress(FileNotFoundError):
            tmp_path.unlink()
        err = output_error(e, target)
        if err is None:
            raise
        raise err from None
    except BaseException:
        with contextlib.suppress(FileNotFoundError):
            tmp_path.unlink()
        raise


def _umask() -> int:
    """The process umask (read from /proc where it can be, else set and restored at once)."""
    try:
        with open("/proc/self/status") as fh:
            for line in fh:
                if line.startswith("Umask:"):
                    return int(line.split()[1], 8)
    except (OSError, ValueError):
        pass
    mask = os.umask(0o022)
    os.umask(mask)
    return mask
