"""Atomic file output: write to a temporary file beside the target, rename on success.

A crash, an exception or Ctrl-C leaves either the old file or no file, never a half-written one.
A write that fails for lack of space, quota or permission ends in one
:class:`~sparsebtf.errors.OutputError` ("no space left on device while writing X; nothing was
written"), with the temporary file removed. Temporaries carry their writer's process id
(``.NAME.PID-HOST.XXXX.part``), so the next write into the folder removes those whose writer
was killed (``kill -9`` runs no cleanup).
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

__all__ = ["atomic_output", "output_error", "remove_stale_parts"]

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


_PART_RE = re.compile(r"^(\d+)-([0-9a-f]{8})\.")


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


def remove_stale_parts(target: Path) -> list[Path]:
    """Remove ``.NAME.PID-HOST.*.part`` temporaries of ``target`` left by dead writers on this
    host (a live writer's, or another host's, are kept). Returns the paths removed."""
    removed: list[Path] = []
    prefix = f".{target.name}."
    host = _host()
    with contextlib.suppress(OSError):
        for entry in os.scandir(target.parent):
            name = entry.name
            if not (name.startswith(prefix) and name.endswith(".part")):
                continue
            m = _PART_RE.match(name[len(prefix):])
            if m is None or m.group(2) != host or _alive(int(m.group(1))):
                continue
            with contextlib.suppress(FileNotFoundError):
                os.unlink(entry.path)
                removed.append(Path(entry.path))
    return removed


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
        os.close(fd)
        os.chmod(tmp, 0o666 & ~_umask())
    except OSError as e:
        raise output_error(e, target, any_errno=True) from None  # type: ignore[misc]
    tmp_path = Path(tmp)
    try:
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
