"""Training points of several BTFs (paper §3.1), as a learning ``PointSource``.

The paper trains on a seeded 10% sample of the data points of 18 BTFs. :func:`training_points`
gathers each BTF's standardisation statistics and draws that sample; the result streams
standardised log-YUV points from the BTFs themselves (:class:`BTFPointSource`, memory = one
batch). Training reads every point K + 4 times per iteration and channel, so
:func:`channel_sources` preprocesses the sample **once** into a temporary HDF5 file
(:class:`StagedPoints`) when it fits on disk, and serves one contiguous float32 dataset per
channel from there.
"""

from __future__ import annotations

import contextlib
import shutil
import tempfile
from collections.abc import Callable, Iterator, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from .._hdf5 import check_written, close_file, create_file
from .._progress import bar
from ..data.btf import BTF
from ..errors import BTFInputError, OutputError
from .grid import PatchGrid, iter_points, sample_points
from .preprocessing import RELEASE_LOG_OFFSET, LogOffset, Preprocessor, StdMode, Transform
from .statistics import gather_statistics, statistics_with_offset

__all__ = [
    "STAGE_LIMIT_BYTES",
    "BTFPointSource",
    "StagedPoints",
    "channel_sources",
    "check_same_directions",
    "training_points",
]

#: Training points are staged on disk when they need at most this many bytes.
STAGE_LIMIT_BYTES = 32 * 2**30


class BTFPointSource:
    """Training points of several BTFs for one channel, streamed from the BTFs themselves.

    ``items`` are (BTF, its :class:`Preprocessor`, point indices). ``channel`` is 0/1/2
    (Y/U/V: 4D points) or None (all three: 5D points with colour as the last mode).
    Memory is one batch; every pass re-reads the patches.
    """

    def __init__(
        self,
        items: Sequence[tuple[BTF, Preprocessor, np.ndarray]],
        patch: int,
        channel: int | None,
    ) -> None:
        self.items = list(items)
        self.patch = patch
        self.channel = channel
        self._starts = np.cumsum([0] + [len(ix) for _, _, ix in self.items])
        btf0 = self.items[0][0]
        spatial = (patch, patch, btf0.shape[2], btf0.shape[3])
        self._shape = spatial if channel is not None else (*spatial, 3)

    def for_channel(self, channel: int | None) -> BTFPointSource:
        """The same points restricted to one colour channel (or all, for None)."""
        return BTFPointSource(self.items, self.patch, channel)

    @property
    def n_points(self) -> int:
        return int(self._starts[-1])

    @property
    def mode_sizes(self) -> tuple[int, ...]:
        return self._shape

    @property
    def n_bytes(self) -> int:
        """float32 bytes of every point (all three colour channels)."""
        return self.n_points * int(np.prod(self._shape[:4])) * 3 * 4

    def _pick(self, x: np.ndarray) -> np.ndarray:
        return np.ascontiguousarray(x[..., self.channel]) if self.channel is not None else x

    def batches(self, batch_size: int) -> Iterator[tuple[np.ndarray, np.ndarray]]:
        for j, (btf, pre, idx) in enumerate(self.items):
            done = 0
            for _, x in iter_points(btf, pre, self.patch, idx, batch_size):
                g = np.arange(done, done + x.shape[0]) + self._starts[j]
                done += x.shape[0]
                yield g, self._pick(x)

    def item_ranges(self, lo: int, hi: int) -> list[tuple[int, int, int]]:
        """Points ``[lo, hi)`` as (item, first, end) runs of the items' own point lists."""
        runs = []
        for j in range(len(self.items)):
            a, b = max(lo, int(self._starts[j])), min(hi, int(self._starts[j + 1]))
            if a < b:
                runs.append((j, a - int(self._starts[j]), b - int(self._starts[j])))
        return runs

    def part(self, lo: int, hi: int) -> BTFPointSource:
        """Points ``[lo, hi)``: the same BTFs, statistics and channel, fewer point indices."""
        items = [(self.items[j][0], self.items[j][1], self.items[j][2][a:b])
                 for j, a, b in self.item_ranges(lo, hi)]  # fmt: skip
        return BTFPointSource(items, self.patch, self.channel)

    def take(self, indices: np.ndarray) -> np.ndarray:
        out = np.empty((len(indices), *self._shape), dtype=np.float32)
        for n, g in enumerate(np.asarray(indices)):
            j = int(np.searchsorted(self._starts, g, side="right") - 1)
            btf, pre, idx = self.items[j]
            _, x = next(iter_points(btf, pre, self.patch, [int(idx[g - self._starts[j]])], 1))
            out[n] = self._pick(x)[0]
        return out


class StagedPoints:
    """Training points preprocessed once into a temporary HDF5 file, one dataset per channel.

    Reading contiguous float32 points back is far cheaper than re-reading and re-preprocessing
    the BTFs each pass. Memory stays at one batch: points are written and read one batch at a
    time. ``source`` yields all three colour channels (``channel=None``); each staged dataset
    keeps one of them, or all for the 5D channel "YUV".
    """

    def __init__(
        self,
        path: str,
        source: BTFPointSource,
        channels: Sequence[str],
        batch_size: int = 4,
        progress: bool | None = None,
    ) -> None:

        self.path = path
        # Written through the sink of sparsebtf._hdf5: libhdf5 does not survive a failed write
        # (a full temporary folder), so the failure is raised here, as one OutputError.
        self._file = create_file(path)
        n = source.n_points
        shape = (source.patch, source.patch, *source.mode_sizes[2:4])
        full = (*shape, 3) if tuple(channels) == ("YUV",) else shape
        try:
            self._ds = {
                ch: self._file.create_dataset(ch, shape=(n, *full), dtype="float32",
                                              chunks=(1, *full))
                for ch in channels
            }  # fmt: skip
            with bar(n, f"stage points {'/'.join(channels)}", "pt", progress) as pb:
                for g, x in source.batches(batch_size):
                    lo, hi = int(g[0]), int(g[-1]) + 1
                    for ch in channels:
                        self._ds[ch][lo:hi] = x if ch == "YUV" else x[..., "YUV".index(ch)]
                    check_written(self._file)
                    pb.update(hi - lo)
        except OSError as e:
            with contextlib.suppress(OSError):
                close_file(self._file)
            raise OutputError(
                f"{e.strerror or e} while staging the training points in {path}; give a "
                "stage_dir (or TMPDIR) with room, or stage=False to stream them"
            ) from None

    def source(self, channel: str) -> _StagedChannel:
        return _StagedChannel(self._ds[channel])

    def close(self) -> None:
        with contextlib.suppress(OSError):  # the points were read; a failed flush is moot
            close_file(self._file)


class _StagedChannel:
    """:class:`~sparsebtf.learning.ensemble.PointSource` over points ``[lo, hi)`` (default:
    all) of one staged dataset."""

    def __init__(self, ds: Any, lo: int = 0, hi: int | None = None) -> None:
        self._ds = ds
        self._lo = lo
        self._hi = int(ds.shape[0]) if hi is None else hi

    @property
    def n_points(self) -> int:
        return self._hi - self._lo

    @property
    def mode_sizes(self) -> tuple[int, ...]:
        return tuple(int(v) for v in self._ds.shape[1:])

    def batches(self, batch_size: int) -> Iterator[tuple[np.ndarray, np.ndarray]]:
        for s in range(0, self.n_points, batch_size):
            e = min(s + batch_size, self.n_points)
            yield np.arange(s, e), self._ds[self._lo + s : self._lo + e]

    def take(self, indices: np.ndarray) -> np.ndarray:
        return np.stack([self._ds[self._lo + int(i)] for i in np.asarray(indices)])

    def part(self, lo: int, hi: int) -> _StagedChannel:
        return _StagedChannel(self._ds, self._lo + lo, self._lo + hi)


def check_same_directions(btfs: Sequence[BTF]) -> None:
    """One model needs one angular sampling: every BTF must share the first one's tables."""
    ref = btfs[0]
    for b in btfs[1:]:
        if not (b.lights.equals(ref.lights) and b.views.equals(ref.views)):
            raise BTFInputError(
                f"{b.label}: its direction tables ({len(b.lights)} lights, {len(b.views)} views) "
                f"differ from {ref.label}'s; one model needs one angular sampling"
            )


def training_points(
    btfs: Sequence[BTF],
    patch: int,
    sample: float,
    seed: int,
    std_mode: StdMode = "shared",
    transform: Transform = "log_yuv",
    progress: bool | None = None,
    log_offset: LogOffset = "auto",
) -> BTFPointSource:
    """The training set of §3.1: a seeded ``sample`` fraction of every BTF's data points,
    standardised with each BTF's own statistics (all three channels) after ln(x + offset), the
    offset by ``log_offset`` (:func:`~sparsebtf.points.statistics.choose_log_offset`)."""
    if not btfs:
        raise BTFInputError("training needs at least one BTF")
    check_same_directions(btfs)
    grids = [PatchGrid.for_btf(b, patch) for b in btfs]
    pres = [
        Preprocessor(
            statistics_with_offset(b, std_mode, log_offset, progress) if transform == "log_yuv"
            else gather_statistics(b, std_mode, log_offset=RELEASE_LOG_OFFSET,
                                   progress=progress, transform=transform)
        )
        for b in btfs
    ]  # fmt: skip
    samples = sample_points([g.n_points for g in grids], sample, seed)
    return BTFPointSource([(btfs[b], pres[b], idx) for b, idx in samples], patch, None)


@contextlib.contextmanager
def channel_sources(
    source: BTFPointSource,
    channels: Sequence[str],
    stage: bool | None = None,
    stage_dir: str | None = None,
    batch_size: int = 4,
    progress: bool | None = None,
) -> Iterator[Callable[[str], Any]]:
    """Yield ``channel name → PointSource`` for training, staged on disk or streamed.

    ``stage=None`` stages when the points need at most :data:`STAGE_LIMIT_BYTES` and less
    than half the free disk of ``stage_dir`` (default: the system's temporary folder). When
    all channels together do not fit but one does (the paper's 2880 points: 79 GB for Y, U
    and V, 26 GB each), each channel is staged when it is asked for, replacing the previous
    one (one more pass over the BTFs per channel instead of re-reading them every pass). The
    temporary files are removed when the block ends, however it ends.
    """
    colour = tuple(channels) == ("YUV",)
    per_channel = False
    if stage is None:
        need = source.n_bytes
        free = shutil.disk_usage(stage_dir or tempfile.gettempdir()).free
        stage = need <= STAGE_LIMIT_BYTES and need < free // 2
        one = need // len(channels) if not colour else need
        per_channel = not stage and one <= STAGE_LIMIT_BYTES and one < free // 2
    if not stage and not per_channel:
        yield lambda ch: source.for_channel(None if colour else list(channels).index(ch))
        return
    with tempfile.TemporaryDirectory(dir=stage_dir, prefix="sparsebtf-stage-") as tmp:
        held: list[StagedPoints] = []

        def staged_channel(ch: str) -> Any:
            while held:
                held.pop().close()
                Path(f"{tmp}/points.h5").unlink(missing_ok=True)
            held.append(StagedPoints(f"{tmp}/points.h5", source, [ch], batch_size, progress))
            return held[0].source(ch)

        try:
            if per_channel:
                yield staged_channel
            else:
                held.append(StagedPoints(f"{tmp}/points.h5", source, channels, batch_size,
                                         progress))
                yield held[0].source
        finally:
            for st in held:
                st.close()
