"""HDF5 as this package writes and reads it: checksummed files, full-disk-safe writes and a
watchdog around every open of an input.

Writing (:func:`create`, :func:`create_dataset`)
    Files use the HDF5 1.10 object formats (``libver=("v110", "v110")``, readable by HDF5 ≥
    1.10 and h5py ≥ 2.10): object headers, the superblock and chunk indexes carry
    checksums, so a flipped bit in an attribute or in the file's structure is reported, not
    read. Every non-empty dataset gets the ``fletcher32`` filter, so a flipped bit in the data
    is reported by whichever HDF5 reader reads it. libhdf5 does not survive a failed write
    (after one, closing the file crashes the process, at the latest at exit), so writes go
    through a file object that records the first ``OSError`` and hides it from HDF5; the
    writer checks :func:`check_written` and the recorded error is raised once the file is
    closed, for :func:`~sparsebtf._atomic.atomic_output` to report in one line.

Reading (:func:`open_h5`)
    A damaged file can make libhdf5 loop forever or crash (segfault) while it reads the file's
    structure. Before the first open in this process, a forked child walks the whole file —
    every link, object, attribute, chunk index, and every dataset under 64 MiB — under a time
    limit (``$SPARSEBTF_HDF5_TIMEOUT``, default 10 s) and a 512 MiB memory cap. A loop becomes a
    :class:`~sparsebtf.errors.FileFormatError` after the limit, a crash an error that names
    the signal; only then does this process open the file. Links to other files are refused.
"""

from __future__ import annotations

import contextlib
import errno
import io
import os
import select
import signal
import stat
import time
import zlib
from collections import OrderedDict
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import h5py
import numpy as np

from .errors import FileFormatError, SparseBTFError

__all__ = [
    "DEFLATE_LEVEL",
    "LIBVER",
    "CompressedGroup",
    "check_written",
    "close_file",
    "create",
    "create_dataset",
    "create_file",
    "open_h5",
    "read_error",
    "shrinks",
    "write_str_attr",
]

LIBVER = ("v110", "v110")
#: gzip level of compressed datasets (HDF5's built-in deflate filter; any reader has it).
DEFLATE_LEVEL = 9
TIMEOUT_ENV = "SPARSEBTF_HDF5_TIMEOUT"
GUARD_ENV = "SPARSEBTF_HDF5_GUARD"
_SIGNATURE = b"\x89HDF\r\n\x1a\n"
_WALK_READ_LIMIT = 64 * 2**20  # datasets up to this size are read whole by the watchdog
_WALK_MAX_OBJECTS = 200_000
_WALK_MEMORY = 512 * 2**20  # address space the watchdog may add


# --------------------------------------------------------------------------- writing


class _Sink(io.RawIOBase):
    """A binary file for h5py's ``fileobj`` driver that never reports a write failure to
    HDF5: the first ``OSError`` is kept in :attr:`error` and later writes are discarded."""

    def __init__(self, path: str | os.PathLike[str]) -> None:
        super().__init__()
        self.path = Path(path)
        # Unbuffered: a buffered file would report a failed write from a later seek or close.
        self._f = open(self.path, "w+b", buffering=0)  # closed in close()
        self.error: OSError | None = None

    def readable(self) -> bool:
        return True

    def writable(self) -> bool:
        return True

    def seekable(self) -> bool:
        return True

    def readinto(self, b: Any) -> int:
        return self._f.readinto(b) or 0

    def write(self, b: Any) -> int:
        view = memoryview(b).cast("B")
        n = view.nbytes
        start = self._f.tell()
        if self.error is None:
            try:
                done = 0
                while done < n:
                    k = self._f.write(view[done:])
                    if not k:
                        raise OSError(errno.EIO, "short write")
                    done += k
                return n
            except OSError as e:
                self.error = e
        self._f.seek(start + n)
        return n

    def seek(self, pos: int, whence: int = os.SEEK_SET) -> int:
        return self._f.seek(pos, whence)

    def tell(self) -> int:
        return self._f.tell()

    def truncate(self, size: int | None = None) -> int:
        if self.error is None:
            try:
                return self._f.truncate(size)
            except OSError as e:
                self.error = e
        return self._f.tell() if size is None else size

    def flush(self) -> None:
        if self.error is None and not self._f.closed:
            try:
                self._f.flush()
            except OSError as e:
                self.error = e

    def close(self) -> None:
        if not self._f.closed:
            self.flush()
            try:
                self._f.close()
            except OSError as e:
                self.error = self.error or e
        super().close()


def create_file(path: str | os.PathLike[str]) -> h5py.File:
    """A new HDF5 file at ``path`` in our format, written through the failure-hiding sink;
    close it with :func:`close_file`. (:func:`create` is the context-manager form.)"""
    sink = _Sink(path)
    try:
        f = h5py.File(sink, "w", libver=LIBVER)
    except BaseException:
        sink.close()
        raise
    f._sparsebtf_sink = sink  # type: ignore[attr-defined]
    return f


def close_file(f: h5py.File) -> None:
    """Close a file from :func:`create_file`; then raise the ``OSError`` of a failed write."""
    sink = getattr(f, "_sparsebtf_sink", None)
    try:
        f.close()
    finally:
        if sink is not None:
            sink.close()
    if sink is not None and sink.error is not None:
        raise sink.error


@contextlib.contextmanager
def create(path: str | os.PathLike[str]) -> Iterator[h5py.File]:
    """A new HDF5 file at ``path`` (normally :func:`atomic_output`'s temporary) in our format.

    A failed write (full disk, quota, size limit) is raised as its ``OSError`` after the file
    is closed; :func:`check_written` raises it early so long writers stop at once.
    """
    f = create_file(path)
    try:
        yield f
    except BaseException:
        with contextlib.suppress(OSError):
            close_file(f)
        raise
    close_file(f)


def check_written(f: h5py.File) -> None:
    """Raise the ``OSError`` of a failed write to ``f`` (made by :func:`create`), if any."""
    sink = getattr(f, "_sparsebtf_sink", None)
    if sink is not None and sink.error is not None:
        raise sink.error


def create_dataset(
    group: h5py.Group, name: str, data: Any = None, *, compress: bool = False, **kwargs: Any
) -> h5py.Dataset:
    """``group.create_dataset`` with the ``fletcher32`` checksum (chunked, as HDF5 requires).

    Unless ``chunks`` is given, chunks are whole rows, at most 1 MiB and of equal size (h5py's
    guess splits (n, 3) location tables into column chunks; HDF5 stores edge chunks whole).
    ``compress`` adds HDF5's built-in ``shuffle`` and ``deflate`` (gzip level
    :data:`DEFLATE_LEVEL`) filters, lossless and readable by any HDF5 reader without plugins,
    unless they would not shrink the data (:func:`shrinks`: a few bytes); so does a
    :class:`CompressedGroup` for every dataset created in it. Empty and scalar
    datasets hold no data to protect and are written plainly.
    """
    shape = tuple(kwargs.get("shape", None if data is None else np.shape(data)) or ())
    if shape and int(np.prod(shape, dtype=np.int64)) > 0:
        if (compress or isinstance(group, CompressedGroup)) and shrinks(data):
            kwargs.setdefault("shuffle", True)
            kwargs.setdefault("compression", "gzip")
            kwargs.setdefault("compression_opts", DEFLATE_LEVEL)
        elif isinstance(group, CompressedGroup):
            kwargs["compression"] = None  # tells the group this one was decided here
        if kwargs.get("chunks") in (None, True):
            itemsize = np.dtype(kwargs.get("dtype") or np.asarray(data).dtype).itemsize
            row = itemsize * int(np.prod(shape[1:], dtype=np.int64))
            per = max(1, 2**20 // max(row, 1))
            n = -(-shape[0] // per)  # chunks of equal rows: the last one wastes < n rows
            kwargs["chunks"] = (-(-shape[0] // n), *shape[1:])
        kwargs["fletcher32"] = True
    return group.create_dataset(name, data=data, **kwargs)


class CompressedGroup(h5py.Group):
    """An HDF5 group whose datasets are all stored with the lossless ``shuffle`` + ``deflate``
    (+ ``fletcher32``) filters, however they are created (:func:`create_dataset` or
    ``group.create_dataset``): a policy for a whole group (a coded file's ``stats/``), so a
    dataset added there later is compressed without a special case.

    ``CompressedGroup(parent.create_group(name).id)`` wraps a new group.
    """

    def create_dataset(self, name: Any, shape: Any = None, dtype: Any = None, data: Any = None,
                       **kwds: Any) -> h5py.Dataset:  # fmt: skip
        shp = shape if shape is not None else (None if data is None else np.shape(data))
        if shp and int(np.prod(shp, dtype=np.int64)) > 0:
            if "compression" not in kwds and shrinks(data):
                kwds.setdefault("shuffle", True)
                kwds["compression"] = "gzip"
                kwds["compression_opts"] = DEFLATE_LEVEL
            kwds.setdefault("fletcher32", True)
            kwds.setdefault("chunks", True)
        return super().create_dataset(name, shape=shape, dtype=dtype, data=data, **kwds)


def shrinks(data: Any) -> bool:
    """Whether ``shuffle`` + ``deflate`` make ``data`` smaller in the file: always for data of
    64 KiB or more (or not given yet); below, the zlib stream of its byte planes (what the
    two filters store) must be shorter than the raw bytes — a dataset of a few bytes would
    grow."""
    if data is None:
        return True
    a = np.ascontiguousarray(data)
    if a.nbytes >= 1 << 16 or a.dtype.kind not in "fiub":
        return True
    planes = a.view(np.uint8).reshape(-1, a.dtype.itemsize).T.tobytes()
    return len(zlib.compress(planes, DEFLATE_LEVEL)) < a.nbytes


def write_str_attr(obj: h5py.HLObject, key: str, text: str) -> None:
    """A fixed-length UTF-8 string attribute: its bytes live in the (checksummed) object
    header, where h5py's default variable-length strings would live in the unchecksummed
    global heap."""
    raw = text.encode("utf-8")
    obj.attrs.create(key, np.array(raw, dtype=h5py.string_dtype("utf-8", max(len(raw), 1))))


# --------------------------------------------------------------------------- reading


def read_error(exc: BaseException, where: str) -> FileFormatError:
    """A :class:`FileFormatError` for an exception h5py raised while reading ``where``."""
    text = str(exc)
    low = text.lower()
    if "checksum" in low or "filter returned failure" in low:
        return FileFormatError(f"{where}: checksum mismatch: the data is corrupted ({text})")
    kind = type(exc).__name__
    return FileFormatError(f"{where}: damaged or truncated HDF5 file ({kind}: {text})")


def _timeout() -> float:
    text = os.environ.get(TIMEOUT_ENV)
    if not text:
        return 10.0
    try:
        value = float(text)
    except ValueError:
        value = float("nan")
    if not (value > 0 and value < 1e6):
        raise SparseBTFError(f"${TIMEOUT_ENV} must be a positive number of seconds, got {text!r}")
    return value


def _check_regular(path: Path) -> os.stat_result:
    try:
        st = path.stat()
    except FileNotFoundError:
        raise FileFormatError(f"{path}: no such file") from None
    except OSError as e:
        raise FileFormatError(f"{path}: cannot read ({e.strerror or e})") from None
    if not stat.S_ISREG(st.st_mode):
        raise FileFormatError(f"{path}: not a regular file (a folder, FIFO or device)")
    return st


def _has_signature(path: Path, size: int) -> bool:
    """HDF5's signature at offset 0, 512, 1024, … (after a user block, e.g. MATLAB's)."""
    try:
        with open(path, "rb") as fh:
            off = 0
            while off + 8 <= size:
                fh.seek(off)
                if fh.read(8) == _SIGNATURE:
                    return True
                off = 512 if off == 0 else off * 2
    except OSError:
        return False
    return False


_probed: OrderedDict[tuple[int, ...], None] = OrderedDict()


def open_h5(path: str | os.PathLike[str], **kwargs: Any) -> h5py.File:
    """Open an HDF5 input read-only, after the watchdog walk (see the module docstring);
    ``kwargs`` go to :class:`h5py.File` (e.g. the chunk cache size ``rdcc_nbytes``).

    Raises :class:`FileFormatError` naming the file: no such file, not a regular file, not
    HDF5, truncated or damaged, a link to another file, or a structure libhdf5 loops or
    crashes on.
    """
    p = Path(path)
    st = _check_regular(p)
    if not _has_signature(p, st.st_size):
        raise FileFormatError(f"{p}: not a readable HDF5 file (no HDF5 signature)")
    key = (st.st_dev, st.st_ino, st.st_size, st.st_mtime_ns, st.st_ctime_ns)
    if key not in _probed:
        _probe(p)
        _probed[key] = None
        while len(_probed) > 256:
            _probed.popitem(last=False)
    try:
        return h5py.File(p, "r", **kwargs)
    except OSError as e:
        raise FileFormatError(f"{p}: not a readable HDF5 file, or truncated ({e})") from None


def _probe(path: Path) -> None:
    """Walk ``path`` in a forked child under a time limit (in-process where fork is absent)."""
    if os.environ.get(GUARD_ENV) == "0" or not hasattr(os, "fork"):
        msg = _walk_message(str(path))
        if msg:
            raise FileFormatError(f"{path}: {msg}")
        return
    limit = _timeout()
    r, w = os.pipe()
    # h5py's global lock is held across fork so that no other thread owns it in the child.
    with h5py._objects.phil:
        pid = os.fork()
    if pid == 0:  # pragma: no cover - the child
        try:
            os.close(r)
            _limit_child_memory()
            msg = _walk_message(str(path))
            os.write(w, msg.encode("utf-8", "replace")[:8000])
        finally:
            os._exit(0)
    os.close(w)
    chunks: list[bytes] = []
    deadline = time.monotonic() + limit
    timed_out = False
    try:
        while True:
            left = deadline - time.monotonic()
            if left <= 0:
                timed_out = True
                break
            ready, _, _ = select.select([r], [], [], left)
            if not ready:
                continue
            data = os.read(r, 65536)
            if not data:
                break
            chunks.append(data)
    finally:
        os.close(r)
        if timed_out:
            with contextlib.suppress(ProcessLookupError):
                os.kill(pid, signal.SIGKILL)
        _, status = _waitpid(pid)
    if timed_out:
        raise FileFormatError(
            f"{path}: the HDF5 library did not finish reading the file's structure within "
            f"{limit:g} s (a damaged file can make it loop); the file was not opened "
            f"(${TIMEOUT_ENV} sets the limit)"
        )
    if os.WIFSIGNALED(status):
        sig = os.WTERMSIG(status)
        name = signal.Signals(sig).name if sig in signal.Signals._value2member_map_ else sig
        raise FileFormatError(
            f"{path}: the HDF5 library crashed ({name}) reading the file's structure; the file "
            "is damaged and was not opened"
        )
    msg = b"".join(chunks).decode("utf-8", "replace")
    if msg:
        raise FileFormatError(f"{path}: {msg}")


def _waitpid(pid: int) -> tuple[int, int]:
    while True:
        try:
            return os.waitpid(pid, 0)
        except InterruptedError:  # pragma: no cover
            continue
        except ChildProcessError:  # reaped elsewhere (a SIGCHLD handler)
            return pid, 0


def _limit_child_memory() -> None:  # pragma: no cover - runs in the child
    """Address-space cap of the watchdog: what it has now plus 512 MiB (it reads datasets of
    at most 64 MiB; more is libhdf5 misreading a damaged size)."""
    import resource

    try:
        with open("/proc/self/statm") as fh:
            vsize = int(fh.read().split()[0]) * os.sysconf("SC_PAGE_SIZE")
    except (OSError, ValueError):
        return
    _, hard = resource.getrlimit(resource.RLIMIT_AS)
    cap = vsize + _WALK_MEMORY
    if hard != resource.RLIM_INFINITY:
        cap = min(cap, hard)
    with contextlib.suppress(ValueError, OSError):
        resource.setrlimit(resource.RLIMIT_AS, (cap, hard))


def _walk_message(path: str) -> str:
    """'' when every object of the file reads; else what failed, naming the object."""
    where = "/"
    try:
        with h5py.File(path, "r") as f:
            external: list[str] = []

            def link(name: str, lnk: Any) -> None:
                if isinstance(lnk, h5py.ExternalLink):
                    external.append(f"/{name} -> {lnk.filename}:{lnk.path}")

            f.visititems_links(link)
            if external:
                return f"{external[0]}: a link to another file; such links are not followed"
            size = os.path.getsize(path)
            count = 0

            def visit(name: str, obj: Any) -> None:
                nonlocal where, count
                count += 1
                if count > _WALK_MAX_OBJECTS:
                    raise FileFormatError(f"more than {_WALK_MAX_OBJECTS} objects")
                where = f"/{name}"
                _walk_object(obj, size)

            _walk_object(f, size)
            f.visititems(visit)
    except SparseBTFError as e:
        return f"{where}: {e}"
    except MemoryError:
        return f"{where}: the HDF5 library ran out of memory (the watchdog's 512 MiB) reading it"
    except Exception as e:  # any failure goes to the parent
        return str(read_error(e, where))
    return ""


def _walk_object(obj: Any, file_size: int) -> None:
    """Read an object's attributes, chunk index and (small) data."""
    for name in obj.attrs:
        aid = obj.attrs.get_id(name)
        nbytes = int(np.prod(aid.shape or (), dtype=np.int64)) * max(int(aid.dtype.itemsize), 1)
        if nbytes > _WALK_READ_LIMIT:
            raise FileFormatError(f"attribute {name!r} claims {nbytes} bytes")
        obj.attrs[name]
    if not isinstance(obj, h5py.Dataset):
        return
    if obj.chunks is not None:
        obj.id.chunk_iter(lambda info: None)
    nbytes = int(obj.size) * max(int(obj.dtype.itemsize), 1)
    if nbytes <= min(_WALK_READ_LIMIT, max(file_size, 1) * 1100) and obj.size:
        obj[()]
