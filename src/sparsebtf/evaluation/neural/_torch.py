"""What the neural baselines share: features, the log1p domain, binary16 storage, seeding,
sample pools with their held-out queries, and the lazy reconstruction (the training loop and
its stop rule: :mod:`._convergence`).

Conventions (docs/neural-baselines.md):

* a direction enters a network as the (x, y) of its unit vector (z implied), light then view;
* targets are log1p(max(y, 0)) of linear RGB ``y``; a log1p network's output ``o`` decodes to
  ``expm1(o)``, clamped at 0;
* everything stored (latents, textures, weights) is rounded to binary16 before the
  reconstruction is built, so what is scored is what would be stored;
* every decoder's first layer is affine in [code, ω_i.xy, ω_o.xy], so its pre-activation splits
  exactly into a per-texel, a per-light and a per-view term, each computed once:
  ``W₀·[c, l, v] + b₀ = (W_c·c + b₀) + W_l·l + W_v·v``. A query then costs the layers after
  the first only (training and decoding alike).

Devices (:func:`resolve_device`): the trainings, encoders, decoders and lookups run on one
torch device, ``"cpu"`` (default), ``"cuda"``, ``"cuda:N"`` or ``"auto"``; the sample pools are
read on the CPU (the same random draws on every device) and moved there, the initial weights
are drawn on the CPU and moved there, and every array that leaves a method is a NumPy array.
On the CPU every operation is the one it was before devices existed, in the same order.
"""

from __future__ import annotations

import contextlib
import itertools
import math
import os
import re
import zlib
from collections.abc import Iterator, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
import torch
import torch.nn.functional as F

from ..._progress import bar
from ...data.btf import BTF, Index, as_index
from ...data.directions import DirectionSet
from ...errors import BTFInputError, OptionError

__all__ = [
    "BATCH",
    "CPU",
    "DEVICE_ENV",
    "FP16_MAX",
    "HeldOut",
    "NeuralBTF",
    "SamplePool",
    "binary16",
    "check_device",
    "decode_latents",
    "direction_terms",
    "direction_xy",
    "heldout_pairs",
    "init_mlp",
    "mlp_params",
    "read_pool",
    "resolve_device",
    "seed_generator",
    "step_generator",
    "tail",
    "torch_threads",
]

#: The largest finite binary16 value: stored values are clamped to ±this before rounding.
FP16_MAX = 65504.0
#: Queries evaluated at once when decoding (a (BATCH, width) float32 activation at a time).
BATCH = 1 << 16
#: A pool read holds at most this many bytes of a material's float32 values at once.
READ_BYTES = 64 * 2**20
#: The environment variable that names the neural methods' default device.
DEVICE_ENV = "SPARSEBTF_TORCH_DEVICE"
#: The CPU, where pools are read and initial weights drawn on every device.
CPU = torch.device("cpu")

Layers = list[tuple[torch.Tensor, torch.Tensor]]


# -- devices ----------------------------------------------------------------------------------
def _no_cuda() -> str:
    if torch.version.cuda is None:
        return (f"this PyTorch {torch.__version__} is a CPU build: install a CUDA build of "
                "torch, or use device 'cpu'")  # fmt: skip
    return (f"this PyTorch is built for CUDA {torch.version.cuda} but sees no GPU: check the "
            "driver and CUDA_VISIBLE_DEVICES, or use device 'cpu'")  # fmt: skip


def resolve_device(spec: str | torch.device | None = None, what: str = "device",
                   available: bool = True) -> torch.device:  # fmt: skip
    """The torch device of the neural methods: ``spec`` is ``"cpu"``, ``"cuda"``,
    ``"cuda:N"`` or ``"auto"`` (CUDA when ``torch.cuda.is_available()``, else the CPU); None or
    blank: ``$SPARSEBTF_TORCH_DEVICE``, else ``"cpu"``. An unknown name, or CUDA where PyTorch
    finds none, is one :class:`~sparsebtf.errors.OptionError` line that starts with ``what``;
    ``available=False`` checks the name only (a device of a remote cluster's workers)."""
    where = what
    if spec is None or (isinstance(spec, str) and not spec.strip()):
        env = os.environ.get(DEVICE_ENV, "").strip()
        if not env:
            return torch.device("cpu")
        spec, where = env, f"${DEVICE_ENV}"
    text = str(spec).strip().lower()
    # a new device object, never the host's :data:`CPU`: tests/test_neural_device.py tells the
    # configured device from the host's CPU (pools, initial weights) by identity
    if text == "auto":
        return torch.device("cuda" if torch.cuda.is_available() else "cpu")
    if text == "cpu":
        return torch.device("cpu")
    m = re.fullmatch(r"cuda(?::(\d+))?", text)
    if m is None:
        raise OptionError(where, f" {str(spec)!r}: unknown device; expected cpu, cuda, cuda:N "
                          "or auto")  # fmt: skip
    if not available:
        return torch.device(text)
    if not torch.cuda.is_available():
        raise OptionError(where, f" {text!r} requested but torch.cuda.is_available() is False "
                          f"({_no_cuda()})")  # fmt: skip
    if m.group(1) is not None and int(m.group(1)) >= torch.cuda.device_count():
        raise OptionError(where, f" {text!r} requested but PyTorch sees "
                          f"{torch.cuda.device_count()} CUDA device(s) (cuda:0 to "
                          f"cuda:{torch.cuda.device_count() - 1})")  # fmt: skip
    return torch.device(text)


def check_device(spec: str | torch.device | None, what: str = "device",
                 available: bool = True) -> str | None:  # fmt: skip
    """``spec`` as a method or a configuration keeps it (stripped, lower case; None or blank:
    None, that is :func:`resolve_device`'s default where the method runs), after checking
    that it resolves here (``available=False``: its name only)."""
    if spec is None or (isinstance(spec, str) and not spec.strip()):
        return None
    resolve_device(spec, what, available)
    return str(spec).strip().lower()


# -- seeding and threads ---------------------------------------------------------------------
def seed_generator(*keys: int | str, device: torch.device | None = None) -> torch.Generator:
    """A :class:`torch.Generator` (on the CPU, or on ``device``) seeded from ``keys`` (ints,
    or strings hashed with CRC-32): the same keys give the same stream on every machine (a
    CUDA generator's stream differs from the CPU's)."""
    ints = [zlib.crc32(k.encode()) if isinstance(k, str) else abs(int(k)) for k in keys]
    state = np.random.SeedSequence(ints).generate_state(1, np.uint64)[0]
    gen = torch.Generator() if device is None or device.type == "cpu" else torch.Generator(
        device=device)  # fmt: skip
    gen.manual_seed(int(state) & (2**63 - 1))
    return gen


def step_generator(gen: torch.Generator, device: torch.device, *keys: int | str
                   ) -> torch.Generator:  # fmt: skip
    """The generator of a training's random steps on ``device``: ``gen`` itself on the CPU
    (its stream goes on from the initial weights, as it always did), else a generator on
    ``device`` seeded from ``keys`` and ``"steps"``."""
    return gen if device.type == "cpu" else seed_generator(*keys, "steps", device=device)


def default_threads() -> int:
    """One intra-op thread unless asked for more (``threads=``; ``$SPARSEBTF_TORCH_THREADS``).

    These networks are small (widths 25–128) and their batches a few thousand queries: a
    second thread gains little, and on a busy machine it loses badly (measured: 100 NeuMIP
    iterations took 1.0 s on one thread and 10–18 s on two with the other core loaded), while
    one thread leaves the other core to the benchmark's scoring.
    """
    env = os.environ.get("SPARSEBTF_TORCH_THREADS", "")
    return max(1, int(env)) if env.strip().isdigit() else 1


@contextlib.contextmanager
def torch_threads(n: int | None) -> Iterator[None]:
    """Run the block with ``n`` intra-op threads (None: :func:`default_threads`)."""
    old = torch.get_num_threads()
    torch.set_num_threads(max(1, int(n)) if n else default_threads())
    try:
        yield
    finally:
        torch.set_num_threads(old)


# -- features, storage -----------------------------------------------------------------------
def direction_xy(directions: DirectionSet, device: torch.device = CPU) -> torch.Tensor:
    """(n, 2) float32 on ``device``: the x, y of each unit direction (z implied)."""
    return torch.from_numpy(np.ascontiguousarray(directions.xyz[:, :2], dtype=np.float32)
                            ).to(device)  # fmt: skip


def binary16(t: torch.Tensor) -> np.ndarray:
    """``t`` as stored: clamped to ±:data:`FP16_MAX` and rounded to binary16 (numpy)."""
    return t.detach().clamp(-FP16_MAX, FP16_MAX).to(torch.float16).cpu().numpy().copy()


def as_f32(a: np.ndarray, device: torch.device = CPU) -> torch.Tensor:
    """A stored binary16 array as a float32 tensor on ``device`` (exact: every binary16 is a
    float32)."""
    return torch.from_numpy(np.asarray(a, dtype=np.float32)).to(device)


def to_device(layers: Layers, device: torch.device) -> Layers:
    """``layers`` on ``device`` (the same tensors where they are there already)."""
    return [(w.to(device), b.to(device)) for w, b in layers]


# -- MLPs -------------------------------------------------------------------------------------
def init_mlp(sizes: Sequence[int], gen: torch.Generator, device: torch.device = CPU) -> Layers:
    """Layers (W (out, in), b (out,)) for widths ``sizes``, drawn U(±1/√fan_in) like
    ``torch.nn.Linear`` but from the CPU generator ``gen`` (the same weights on every device),
    then moved to ``device``; they require gradients."""
    layers: Layers = []
    for fan_in, fan_out in itertools.pairwise(sizes):
        bound = 1.0 / math.sqrt(fan_in)
        w = (torch.rand(fan_out, fan_in, generator=gen, device=CPU) * 2 - 1) * bound
        b = (torch.rand(fan_out, generator=gen, device=CPU) * 2 - 1) * bound
        layers.append((w.to(device).requires_grad_(), b.to(device).requires_grad_()))
    return layers


def mlp_params(sizes: Sequence[int]) -> int:
    """Weights and biases of an MLP with widths ``sizes``: Σ (in + 1)·out."""
    return sum((a + 1) * b for a, b in itertools.pairwise(sizes))


def flat(layers: Layers) -> list[torch.Tensor]:
    """The tensors of ``layers`` (for an optimiser)."""
    return [t for wb in layers for t in wb]


def activate(h: torch.Tensor, slope: float) -> torch.Tensor:
    """LeakyReLU with ``slope`` (0: ReLU)."""
    return F.leaky_relu(h, slope) if slope else F.relu(h)


def tail(pre: torch.Tensor, layers: Layers, slope: float) -> torch.Tensor:
    """The MLP after its first layer: ``pre`` is the first layer's pre-activation (…, width₀);
    every later layer but the last is followed by the activation."""
    h = pre
    for w, b in layers[1:]:
        h = F.linear(activate(h, slope), w, b)
    return h


def direction_terms(
    w0: torch.Tensor, n_code: int, lights: torch.Tensor, views: torch.Tensor
) -> tuple[torch.Tensor, torch.Tensor]:
    """The per-light (nL, width) and per-view (nV, width) terms of a first layer whose input
    is [code (n_code), light.xy, view.xy]."""
    return lights @ w0[:, n_code:n_code + 2].T, views @ w0[:, n_code + 2:n_code + 4].T


def decode_latents(
    layers: Layers, z: torch.Tensor, li: torch.Tensor, vi: torch.Tensor,
    lights: torch.Tensor, views: torch.Tensor, slope: float,
) -> torch.Tensor:
    """A decoder [z, ω_i.xy, ω_o.xy] → … at queries (B, Q): texel b's latents ``z[b]`` (B, n)
    with the light and view indices ``li``, ``vi`` (B, Q) into the tables ``lights``,
    ``views`` (n_dirs, 2). Returns the raw output (B, Q, k)."""
    w0, b0 = layers[0]
    n = z.shape[-1]
    a_l, a_v = direction_terms(w0, n, lights, views)
    pre = (z @ w0[:, :n].T + b0)[:, None] + a_l[li] + a_v[vi]
    return tail(pre, layers, slope)


def output(o: torch.Tensor, head: str) -> torch.Tensor:
    """Linear RGB from a network's output (…, k), before the final clamp at 0.

    ``"log1p"``: expm1(o) (k = 3). ``"neumip"``: channels 0–2 are log-YUV, mapped to log-RGB
    (R = Y + 1.13983 V, G = Y − 0.39465 U − 0.58060 V, B = Y + 2.03211 U) and by expm1, times
    the shadow term 0.1 + sigmoid(channels 3–5) (k = 6), as NeuMIP's code does.
    """
    if head == "log1p":
        return torch.expm1(o)
    if head == "neumip":
        y, u, v = o[..., 0], o[..., 1], o[..., 2]
        log_rgb = torch.stack(
            (y + 1.13983 * v, y - 0.39465 * u - 0.58060 * v, y + 2.03211 * u), dim=-1
        )
        return torch.expm1(log_rgb) * (0.1 + torch.sigmoid(o[..., 3:6]))
    raise ValueError(f"unknown output head {head!r}")


# -- sample pools -----------------------------------------------------------------------------
@dataclass
class HeldOut:
    """Held-out queries of a pool's texels: (light, view) pairs that are **not** among that
    texel's training samples nor the encoder's shared pairs, so a loss on them measures how
    well a training generalises over directions, not how well it memorises its pool.

    ``rows`` (m,) int64 pool rows (texels), ``values`` (m, 3) float32 log1p targets,
    ``lights``, ``views`` (m,) int64 direction indices.
    """

    rows: torch.Tensor
    values: torch.Tensor
    lights: torch.Tensor
    views: torch.Tensor

    def to(self, device: torch.device) -> HeldOut:
        """The same queries on ``device`` (itself where they are there already)."""
        return HeldOut(*(t.to(device) for t in (self.rows, self.values, self.lights,
                                                 self.views)))  # fmt: skip


def heldout_pairs(taken: np.ndarray, n_pairs: int, per_texel: int,
                  gen: torch.Generator) -> tuple[np.ndarray, np.ndarray]:  # fmt: skip
    """Up to ``per_texel`` random flat pairs in [0, ``n_pairs``) per row of ``taken`` (k, S)
    that are not in that row: (row index (m,), pair (m,)), at most ``per_texel`` per row
    (fewer where a row leaves fewer free pairs among the draws)."""
    k = taken.shape[0]
    draws = torch.randint(0, n_pairs, (k, 4 * per_texel), generator=gen, device=CPU).numpy()
    row_keys = np.sort(taken.astype(np.int64) + (np.arange(k, dtype=np.int64) * n_pairs)[:, None],
                       axis=None)  # fmt: skip
    keys = draws.astype(np.int64) + (np.arange(k, dtype=np.int64) * n_pairs)[:, None]
    pos = np.minimum(np.searchsorted(row_keys, keys), row_keys.size - 1)
    free = row_keys[pos] != keys
    # a pair drawn twice for one row counts once
    order = np.argsort(keys, axis=1, kind="stable")
    s = np.take_along_axis(keys, order, axis=1)
    first = np.ones_like(free)
    first[:, 1:] = s[:, 1:] != s[:, :-1]
    uniq = np.empty_like(free)
    np.put_along_axis(uniq, order, first, axis=1)
    free &= uniq
    rank = np.cumsum(free, axis=1)
    keep = free & (rank <= per_texel)
    rows, cols = np.nonzero(keep)
    return rows.astype(np.int64), draws[rows, cols].astype(np.int64)


@dataclass
class SamplePool:
    """Random (light, view) samples of some texels of one material, held for training.

    ``values`` (n, S, 3) float32 log1p(max(y, 0)); ``lights``, ``views`` (n, S) int16
    direction indices (drawn uniformly, with replacement, per texel); ``texels`` (n,) int64
    flat texel indices row·W + col; ``shared`` (n, P, 3) log1p values at the P pairs
    ``shared_pairs`` common to every texel (an encoder's fixed input), or None; ``heldout``
    the queries a training is judged on (:class:`HeldOut`), or None.
    """

    values: torch.Tensor
    lights: torch.Tensor
    views: torch.Tensor
    texels: np.ndarray
    shared: torch.Tensor | None = None
    shared_pairs: np.ndarray | None = None
    heldout: HeldOut | None = None

    def to(self, device: torch.device) -> SamplePool:
        """The pool's tensors on ``device`` (the pool itself where they are there already);
        ``texels`` and ``shared_pairs`` stay NumPy arrays."""
        return SamplePool(self.values.to(device), self.lights.to(device),
                          self.views.to(device), self.texels,
                          None if self.shared is None else self.shared.to(device),
                          self.shared_pairs,
                          None if self.heldout is None else self.heldout.to(device))  # fmt: skip

    def take(self, rows: torch.Tensor, cols: torch.Tensor
             ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:  # fmt: skip
        """(values (…, 3), light index, view index) at pool rows ``rows`` and sample
        positions ``cols`` (broadcast together)."""
        return (self.values[rows, cols], self.lights[rows, cols].long(),
                self.views[rows, cols].long())  # fmt: skip


def read_pool(
    btf: BTF,
    n_samples: int,
    gen: torch.Generator,
    texels: np.ndarray | None = None,
    shared_pairs: np.ndarray | None = None,
    progress: bool | None = None,
    heldout: int = 0,
    heldout_texels: int = 4096,
) -> SamplePool:
    """Read ``n_samples`` random (light, view) samples of each texel of ``btf`` (``texels``:
    flat indices, default all) in bands of rows of at most :data:`READ_BYTES`, plus the
    values at the flat pairs ``shared_pairs`` (light·V + view) if given, plus ``heldout``
    held-out queries (:class:`HeldOut`) on each of at most ``heldout_texels`` random texels
    of them: pairs outside that texel's samples, and outside ``shared_pairs`` unless these
    cover half the grid or more (a tiny direction set, where nothing would be left).

    The pool is read on the CPU (:meth:`SamplePool.to` moves it): its random draws are the
    same whatever device trains on it."""
    h, w, nl, nv, _ = btf.shape
    want = np.arange(h * w) if texels is None else np.unique(np.asarray(texels, np.int64))
    judged = np.zeros(want.size, bool)
    if heldout > 0:
        judged[torch.randperm(want.size, generator=gen, device=CPU)[:heldout_texels]
               .numpy()] = True  # fmt: skip
    held: list[tuple[np.ndarray, np.ndarray, np.ndarray]] = []
    offset = 0
    row_bytes = 12 * w * nl * nv
    band = max(1, READ_BYTES // row_bytes)
    vals, lis, vis, shared = [], [], [], []
    rows_needed = np.unique(want // w)
    starts = list(range(int(rows_needed[0]), int(rows_needed[-1]) + 1, band))
    with bar(len(starts), f"read {btf.label}", "band", progress) as pb:
        for r0 in starts:
            r1 = min(r0 + band, h)
            sel = want[(want >= r0 * w) & (want < r1 * w)]
            pb.update(1)
            if not sel.size:
                continue
            block = btf.region(slice(r0, r1), slice(None)).reshape((r1 - r0) * w, nl * nv, 3)
            block = np.log1p(np.maximum(block[sel - r0 * w], 0))
            pairs = torch.randint(0, nl * nv, (sel.size, n_samples), generator=gen,
                                  device=CPU).numpy()  # fmt: skip
            vals.append(np.take_along_axis(block, pairs[..., None], axis=1))
            lis.append((pairs // nv).astype(np.int16))
            vis.append((pairs % nv).astype(np.int16))
            if shared_pairs is not None:
                shared.append(block[:, shared_pairs])
            if heldout > 0:
                here = np.flatnonzero(judged[offset:offset + sel.size])
                taken = pairs[here]
                if shared_pairs is not None and 2 * len(shared_pairs) < nl * nv:
                    taken = np.concatenate(
                        [taken, np.broadcast_to(shared_pairs, (here.size, len(shared_pairs)))],
                        axis=1)  # fmt: skip
                r_i, p_i = heldout_pairs(taken, nl * nv, heldout, gen)
                held.append((offset + here[r_i], p_i, block[here[r_i], p_i]))
            offset += sel.size
    ho = None
    if heldout > 0:
        r_h, p_h, v_h = (np.concatenate(x) for x in zip(*held, strict=True))
        if not r_h.size:
            raise BTFInputError(f"{btf.label}: no held-out (light, view) pair is left outside "
                                f"{n_samples} samples per texel of {nl} x {nv} directions; "
                                "draw fewer samples per texel")  # fmt: skip
        ho = HeldOut(torch.from_numpy(r_h), torch.from_numpy(np.ascontiguousarray(v_h)),
                     torch.from_numpy(p_h // nv), torch.from_numpy(p_h % nv))  # fmt: skip
    return SamplePool(
        torch.from_numpy(np.concatenate(vals)), torch.from_numpy(np.concatenate(lis)),
        torch.from_numpy(np.concatenate(vis)), want,
        torch.from_numpy(np.concatenate(shared)) if shared_pairs is not None else None,
        None if shared_pairs is None else np.asarray(shared_pairs), ho,
    )  # fmt: skip


# -- the lazy reconstruction ------------------------------------------------------------------
class NeuralBTF(BTF):
    """A neural method's reconstruction, decoded on demand from its stored binary16 arrays.

    ``code`` (H, W, n) is the per-texel input (latents or a neural texture), ``layers`` the
    MLP's (W (out, in), b (out,)) whose first layer takes [code, ω_i.xy, ω_o.xy]; ``head`` maps
    the output to linear RGB (:func:`output`), clamped at 0. All arrays are binary16
    (:func:`binary16`); they are decoded in float32. Queries are evaluated ``batch`` at a time,
    on ``device`` (:func:`resolve_device`; its tables are built there, the answers are NumPy
    arrays). A pickle holds the stored arrays only: the copy builds its tables again, on
    ``device`` where PyTorch finds it, else on the CPU.
    """

    #: what :meth:`_build` derives from the stored arrays (not pickled)
    _TABLES = ("_net", "_texel", "_light", "_view", "_w_light", "_w_view")

    def __init__(
        self,
        code: np.ndarray,
        layers: Sequence[tuple[np.ndarray, np.ndarray]],
        lights: DirectionSet,
        views: DirectionSet,
        *,
        head: str,
        slope: float,
        name: str = "neural",
        attrs: dict[str, Any] | None = None,
        batch: int = BATCH,
        threads: int | None = None,
        device: str | torch.device | None = None,
    ) -> None:
        h, w, _ = code.shape
        super().__init__(h, w, lights, views, name, attrs)
        self.code = np.asarray(code, dtype=np.float16)
        self.layers = [(np.asarray(a, np.float16), np.asarray(b, np.float16)) for a, b in layers]
        self.head, self.slope = head, float(slope)
        self.batch, self.threads = max(1, int(batch)), threads
        self.device = resolve_device(device)
        self._build()

    def _build(self) -> None:
        """The decoding tables on :attr:`device`: the network in float32, the per-texel,
        per-light and per-view terms of its first layer."""
        dev, n = self.device, self.code.shape[-1]
        net = [(as_f32(a, dev), as_f32(b, dev)) for a, b in self.layers]
        w0, b0 = net[0]
        self._net = net
        self._texel = as_f32(self.code, dev).reshape(-1, n) @ w0[:, :n].T + b0
        self._light, self._view = direction_terms(
            w0, n, direction_xy(self.lights, dev), direction_xy(self.views, dev)
        )
        self._w_light = w0[:, n:n + 2].T.contiguous()
        self._w_view = w0[:, n + 2:n + 4].T.contiguous()

    def __getstate__(self) -> dict[str, Any]:
        state = {k: v for k, v in self.__dict__.items() if k not in self._TABLES}
        state["device"] = str(self.device)
        return state

    def __setstate__(self, state: dict[str, Any]) -> None:
        self.__dict__.update(state)
        dev = torch.device(state.get("device", "cpu"))
        usable = dev.type == "cpu" or (torch.cuda.is_available()
                                       and (dev.index or 0) < torch.cuda.device_count())
        self.device = dev if usable else torch.device("cpu")
        self._build()

    def stored(self) -> dict[str, np.ndarray]:
        """Every stored array by name (binary16): ``code``, ``layer{i}.weight``/``.bias``."""
        out = {"code": self.code}
        for i, (a, b) in enumerate(self.layers):
            out[f"layer{i}.weight"], out[f"layer{i}.bias"] = a, b
        return out

    def decoder_values(self) -> int:
        """Values of the MLP (weights and biases)."""
        return sum(a.size + b.size for a, b in self.layers)

    def _decode(self, pre: torch.Tensor) -> torch.Tensor:
        return output(tail(pre, self._net, self.slope), self.head).clamp_min_(0)

    def read(self, rows: Index, cols: Index, lights: Index, views: Index) -> np.ndarray:
        r, c, li, vi = self.indices(rows, cols, lights, views)
        dev = self.device
        tex = torch.from_numpy((r[:, None] * self.width + c[None, :]).ravel()).to(dev)
        li_t, vi_t = torch.from_numpy(li).to(dev), torch.from_numpy(vi).to(dev)
        out = np.empty((tex.numel(), li.size, vi.size, 3), dtype=np.float32)
        n_v = max(vi.size, 1)
        per_tex = li.size * n_v
        kt = max(1, self.batch // max(per_tex, 1))  # texels per batch
        kl = li.size if kt > 1 else max(1, self.batch // n_v)  # lights per batch
        view_term = self._view[vi_t][None, None]
        with torch.inference_mode(), torch_threads(self.threads):
            for t0 in range(0, tex.numel(), kt):
                tk = self._texel[tex[t0:t0 + kt]][:, None, None]
                for l0 in range(0, li.size, kl):
                    pre = tk + self._light[li_t[l0:l0 + kl]][None, :, None] + view_term
                    val = self._decode(pre.reshape(-1, pre.shape[-1]))
                    out[t0:t0 + kt, l0:l0 + kl] = val.reshape(*pre.shape[:3], 3).cpu().numpy()
        return out.reshape(r.size, c.size, li.size, vi.size, 3)

    def lookup(self, rows: np.ndarray, cols: np.ndarray, wi: np.ndarray, wo: np.ndarray
               ) -> np.ndarray:  # fmt: skip
        """A renderer's query: texels (rows, cols) and continuous unit directions wi, wo
        (n, 3) in the local frame → (n, 3) float32. The decoder's input is [code, ω_i.xy,
        ω_o.xy], so an unmeasured direction costs two (n, 2) × (2, width) products instead of
        the per-direction tables of :meth:`query`."""
        r, c = (np.asarray(a, dtype=np.int64) for a in (rows, cols))
        wi, wo = (np.asarray(a, dtype=np.float32) for a in (wi, wo))
        if not (r.shape == c.shape == wi.shape[:1] == wo.shape[:1]) or wi.shape != wo.shape:
            raise BTFInputError(f"{self.label}: lookup needs rows, cols (n,) and wi, wo (n, 3), "
                                f"got {r.shape}, {c.shape}, {wi.shape}, {wo.shape}")  # fmt: skip
        dev = self.device
        tex = torch.from_numpy(r * self.width + c).to(dev)
        li_xy = torch.from_numpy(wi[:, :2].copy()).to(dev)
        vi_xy = torch.from_numpy(wo[:, :2].copy()).to(dev)
        out = np.empty((r.size, 3), dtype=np.float32)
        with torch.inference_mode(), torch_threads(self.threads):
            for s in range(0, r.size, self.batch):
                e = s + self.batch
                pre = torch.addmm(self._texel[tex[s:e]], li_xy[s:e], self._w_light)
                pre.addmm_(vi_xy[s:e], self._w_view)
                out[s:e] = self._decode(pre).cpu().numpy()
        return out

    def query(self, rows: Index, cols: Index, lights: Index, views: Index) -> np.ndarray:
        """Values at point queries: four equal-length integer arrays → (n, 3) float32."""
        arrays = [as_index(ix, n, f) for ix, n, f in zip(
            (rows, cols, lights, views), (self.height, self.width, len(self.lights),
                                          len(self.views)), ("row", "col", "light", "view"),
            strict=True)]  # fmt: skip
        sizes = {a.size for a in arrays}
        if len(sizes) != 1:
            raise BTFInputError(f"{self.label}: query arrays differ in length: "
                                f"{[a.size for a in arrays]}")  # fmt: skip
        r, c, li, vi = (torch.from_numpy(a).to(self.device) for a in arrays)
        out = np.empty((r.numel(), 3), dtype=np.float32)
        with torch.inference_mode(), torch_threads(self.threads):
            for s in range(0, r.numel(), self.batch):
                e = s + self.batch
                pre = (self._texel[r[s:e] * self.width + c[s:e]] + self._light[li[s:e]]
                       + self._view[vi[s:e]])  # fmt: skip
                out[s:e] = self._decode(pre).cpu().numpy()
        return out
