"""The neural baselines' torch device: its resolution, its plumbing from ``bench quality
--device`` and ``$SPARSEBTF_TORCH_DEVICE`` to the methods, and a check that every tensor a tiny
training and decode creates is on the configured device (tiny shapes of tests/test_neural.py).

No GPU is needed: CUDA's presence is faked where only the resolution is tested, and the
plumbing check tells the configured device from the host's CPU by tagging tensors (see
:class:`DeviceTracker`); on a machine with CUDA it also runs on ``cuda``.
"""

from __future__ import annotations

import sys
import weakref
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

torch = pytest.importorskip("torch")

from torch.overrides import TorchFunctionMode  # noqa: E402

from sparsebtf.errors import OptionError  # noqa: E402
from sparsebtf.evaluation.benchmark_set import BenchConfig  # noqa: E402
from sparsebtf.evaluation.methods import method_class  # noqa: E402
from sparsebtf.evaluation.neural import _convergence, _torch, rgjw20, rjgw19  # noqa: E402
from sparsebtf.evaluation.neural._torch import (  # noqa: E402
    CPU,
    DEVICE_ENV,
    NeuralBTF,
    resolve_device,
)

from .conftest import smooth_btf  # noqa: E402
from .test_neural import NAMES, budgets, fitted  # noqa: E402

HAS_CUDA = torch.cuda.is_available()


@pytest.fixture(autouse=True)
def _no_env_device(monkeypatch):
    monkeypatch.delenv(DEVICE_ENV, raising=False)


def _fake_cuda(monkeypatch, available: bool, count: int = 1) -> None:
    monkeypatch.setattr(torch.cuda, "is_available", lambda: available)
    monkeypatch.setattr(torch.cuda, "device_count", lambda: count if available else 0)


# -- resolution ------------------------------------------------------------------------------
def test_cpu_and_auto_without_cuda_resolve_to_the_cpu(monkeypatch):
    _fake_cuda(monkeypatch, False)
    for spec in ("cpu", " CPU ", "auto", None, "", torch.device("cpu")):
        assert resolve_device(spec) == torch.device("cpu")
    # a new object, never the host's CPU constant (the plumbing check below relies on it)
    assert resolve_device("cpu") is not CPU


def test_auto_and_cuda_resolve_to_cuda_when_torch_finds_one(monkeypatch):
    _fake_cuda(monkeypatch, True, count=2)
    assert resolve_device("auto") == torch.device("cuda")
    assert resolve_device("cuda") == torch.device("cuda")
    assert resolve_device("cuda:1") == torch.device("cuda", 1)
    with pytest.raises(OptionError, match=r"sees 2 CUDA device\(s\)") as e:
        resolve_device("cuda:2")
    assert "\n" not in str(e.value)


@pytest.mark.parametrize("spec", ["cuda", "cuda:0", "auto"])
def test_cuda_is_refused_in_one_line_when_torch_finds_none(monkeypatch, spec):
    _fake_cuda(monkeypatch, False)
    if spec == "auto":
        assert resolve_device(spec).type == "cpu"
        return
    with pytest.raises(OptionError, match=r"torch.cuda.is_available\(\) is False") as e:
        resolve_device(spec)
    assert f"device {spec!r} requested" in str(e.value)
    assert "\n" not in str(e.value)


@pytest.mark.parametrize("spec", ["gpu", "cuda:x", "cuda:-1", "cuda0", "tpu", "mps", "cpu:0",
                                  "meta"])  # fmt: skip
def test_unknown_devices_are_refused(spec):
    with pytest.raises(OptionError, match="unknown device; expected cpu, cuda, cuda:N or auto"):
        resolve_device(spec)


def test_the_environment_variable_is_the_default(monkeypatch):
    _fake_cuda(monkeypatch, False)
    monkeypatch.setenv(DEVICE_ENV, "auto")
    assert resolve_device(None) == torch.device("cpu")
    monkeypatch.setenv(DEVICE_ENV, "cuda")
    with pytest.raises(OptionError, match=r"^\$SPARSEBTF_TORCH_DEVICE 'cuda' requested"):
        resolve_device(None)
    monkeypatch.setenv(DEVICE_ENV, "bogus")
    with pytest.raises(OptionError, match=r"^\$SPARSEBTF_TORCH_DEVICE 'bogus': unknown"):
        resolve_device(None)
    assert resolve_device("cpu") == torch.device("cpu")  # an explicit device wins


def test_a_remote_device_is_checked_by_name_only(monkeypatch):
    _fake_cuda(monkeypatch, False)
    assert resolve_device("cuda:1", available=False) == torch.device("cuda", 1)
    with pytest.raises(OptionError, match="unknown device"):
        resolve_device("gpu", available=False)


# -- the methods -----------------------------------------------------------------------------
@pytest.mark.parametrize("name", NAMES)
def test_methods_take_check_and_describe_their_device(monkeypatch, name):
    _fake_cuda(monkeypatch, False)
    cls = method_class(name)
    assert cls().device is None and cls().device_ == torch.device("cpu")
    assert cls(device=" CPU").device == "cpu"
    assert cls(device="cpu").describe()["device"] == "cpu"
    with pytest.raises(OptionError, match="unknown device"):
        cls(device="gpu")
    with pytest.raises(OptionError, match="is_available"):
        cls(device="cuda")
    for cfg in (BenchConfig(), BenchConfig.quick()):
        assert cls.from_config(cfg).device is None
        assert cls.from_config(replace(cfg, torch_device="cpu")).device == "cpu"
    # None: resolved where the method runs (a Dask worker: its own environment)
    monkeypatch.setenv(DEVICE_ENV, "cuda")
    method = cls()
    assert method.device is None
    with pytest.raises(OptionError, match="SPARSEBTF_TORCH_DEVICE"):
        method.device_  # noqa: B018


def _arrays(codings) -> list[np.ndarray]:
    out = []
    for c in codings:
        if c.reconstruction is not None:
            out += list(c.reconstruction.stored().values())
            out.append(c.reconstruction.read(slice(None), slice(None), slice(None),
                                             slice(None)))  # fmt: skip
    return out


@pytest.mark.parametrize("name", NAMES)
def test_an_explicit_cpu_device_gives_the_default_results(monkeypatch, name):
    btf = smooth_btf(7, size=4, name="test7")
    default = fitted(name).code(btf, budgets(name))
    monkeypatch.setattr(rgjw20, "_TRAINED", {})  # train again, not from the cache
    explicit = fitted(name, device="cpu").code(btf, budgets(name))
    monkeypatch.setattr(rgjw20, "_TRAINED", {})
    monkeypatch.setenv(DEVICE_ENV, "cpu")
    env = fitted(name).code(btf, budgets(name))
    for other in (explicit, env):
        for a, b in zip(_arrays(default), _arrays(other), strict=True):
            assert a.dtype == b.dtype and np.array_equal(a, b)
        for a, b in zip(default, other, strict=True):
            assert a.info["loss_curve"] == b.info["loss_curve"]
            assert b.info["device"] == "cpu"


def test_a_gpu_reads_its_losses_at_the_evaluations_with_the_same_numbers():
    def run(lazy):
        gen = _torch.seed_generator(3)
        w = torch.rand(8, 3, generator=gen).requires_grad_()
        x, y = torch.rand(64, 3, generator=gen), torch.rand(64, 8, generator=gen)
        return _convergence.train_to_convergence(
            [w], lambda *_: ((x @ w.T - y) ** 2).mean(), lambda: float(((x @ w.T - y) ** 2).mean()),
            1.0, (1e-2, 1e-3), _convergence.StopRule(200, 10), "t", False, lazy=lazy)

    eager, lazy = run(False), run(True)
    eager.pop("cpu_seconds"), lazy.pop("cpu_seconds")
    assert eager == lazy


def test_a_pickled_reconstruction_builds_its_tables_again(monkeypatch):
    import pickle

    rec = fitted("neumip").code(smooth_btf(7, size=4, name="t7"), budgets("neumip"))[0]
    rec = rec.reconstruction
    state = rec.__getstate__()
    assert not any(k in state for k in NeuralBTF._TABLES) and state["device"] == "cpu"
    copy = pickle.loads(pickle.dumps(rec))
    assert copy.device == torch.device("cpu")
    assert np.array_equal(copy.read(slice(None), 0, slice(None), slice(None)),
                          rec.read(slice(None), 0, slice(None), slice(None)))  # fmt: skip
    # made on a GPU, loaded where PyTorch finds none: decoded on the CPU
    _fake_cuda(monkeypatch, False)
    state["device"] = "cuda:0"
    other = NeuralBTF.__new__(NeuralBTF)
    other.__setstate__(state)
    assert other.device == torch.device("cpu")
    _fake_cuda(monkeypatch, True, count=1)
    state["device"] = "cuda:1"  # a second GPU this machine lacks
    other = NeuralBTF.__new__(NeuralBTF)
    other.__setstate__(state)
    assert other.device == torch.device("cpu")


# -- the command line ------------------------------------------------------------------------
def _bench_args(*extra):
    from sparsebtf.cli.main import build_parser

    return build_parser().parse_args(["bench", "quality", "--out", "x", *extra])


def test_bench_quality_device_reaches_the_methods(monkeypatch, tmp_path):
    from sparsebtf.cli import bench

    seen = {}

    def fake_run(out, cfg, **kw):
        seen["methods"] = [method_class(n).from_config(cfg) for n in kw["methods"]]
        seen["cfg"] = cfg
        return {"summary": {}}

    monkeypatch.setattr("sparsebtf.evaluation.runner.run_quality", fake_run)
    args = _bench_args("--quick", "--methods", "rjgw19,neumip", "--device", "CPU")
    args.out = str(tmp_path / "run")
    assert bench.cmd_bench_quality(args) == 0
    assert seen["cfg"].torch_device == "cpu"
    assert [m.device for m in seen["methods"]] == ["cpu", "cpu"]
    args = _bench_args("--quick", "--methods", "rjgw19")
    args.out = str(tmp_path / "run2")
    bench.cmd_bench_quality(args)
    assert seen["cfg"].torch_device is None and seen["methods"][0].device is None


def test_bench_quality_refuses_a_bad_device_before_any_work(monkeypatch, tmp_path):
    from sparsebtf.cli import bench

    _fake_cuda(monkeypatch, False)
    monkeypatch.setattr("sparsebtf.evaluation.runner.run_quality",
                        lambda *a, **k: pytest.fail("ran"))  # fmt: skip
    for device, match in (("gpu", "^--device 'gpu': unknown device"),
                          ("cuda", r"^--device 'cuda' requested but torch.cuda.is_available\(\) "
                                   "is False")):  # fmt: skip
        args = _bench_args("--quick", "--device", device)
        args.out = str(tmp_path / device)
        with pytest.raises(OptionError, match=match):
            bench.cmd_bench_quality(args)
    monkeypatch.setenv(DEVICE_ENV, "cuda")
    args = _bench_args("--quick")
    args.out = str(tmp_path / "env")
    with pytest.raises(OptionError, match=r"^\$SPARSEBTF_TORCH_DEVICE 'cuda' requested"):
        bench.cmd_bench_quality(args)
    # a remote cluster's workers may have the GPU this machine lacks: the name is checked only
    seen = {}
    monkeypatch.setattr("sparsebtf.evaluation.runner.run_quality",
                        lambda out, cfg, **k: seen.update(cfg=cfg) or {"summary": {}})
    args = _bench_args("--quick", "--device", "cuda:1", "--scheduler", "tcp://127.0.0.1:1")
    args.out = str(tmp_path / "remote")
    bench.cmd_bench_quality(args)
    assert seen["cfg"].torch_device == "cuda:1"


# -- every tensor on the configured device ---------------------------------------------------
NEURAL_DIR = str(Path(_torch.__file__).parent)
TORCH_DIR = str(Path(torch.__file__).parent)
#: torch's tensor factories, by name (the mode is handed other objects than ``torch.ones``)
FACTORIES = {"rand", "randn", "randint", "randperm", "arange", "zeros", "ones", "empty", "full",
             "tensor", "as_tensor", "linspace", "eye"}  # fmt: skip


def _tensors(x, out):
    if isinstance(x, torch.Tensor):
        out.append(x)
    elif isinstance(x, (list, tuple)):
        for y in x:
            _tensors(y, out)
    elif isinstance(x, dict):
        for y in x.values():
            _tensors(y, out)
    return out


def _host_target(d) -> bool:
    """Whether a ``device=`` argument names the host's CPU (the :data:`CPU` constant or the
    string "cpu"), not the configured device (a device object :func:`resolve_device` made)."""
    return d is CPU or (isinstance(d, str) and d.strip().lower() == "cpu")


class DeviceTracker(TorchFunctionMode):
    """Tags every tensor as *host* (on the CPU by intent: NumPy's, drawn with ``device="cpu"``
    or the :data:`CPU` constant, moved there, or computed from host tensors) or *configured*
    (moved to or created on the configured device, whose object is never the :data:`CPU`
    constant, or computed from such), as a GPU would place them, and records:

    * ``factories``: tensor factories called from the neural package without ``device=``
      (on a GPU they would land on the CPU);
    * ``mixed``: operations that combine host and configured tensors of more than one value
      (on a GPU: a device error, or an index copied over on every call);
    * ``outside``: configured tensors whose device is not the configured one.

    Works on the CPU, where both kinds live on the same device, and on CUDA. The mode does not
    see ``torch.from_numpy``: the tracker wraps it while it is active.
    """

    def __init__(self, device: torch.device) -> None:
        super().__init__()
        self.device = device
        self.host: dict[int, weakref.ref] = {}
        self.factories: list[str] = []
        self.mixed: list[str] = []
        self.outside: list[str] = []

    def __enter__(self):
        self._from_numpy = torch.from_numpy

        def from_numpy(a):
            t = self._from_numpy(a)
            self.host[id(t)] = weakref.ref(t)
            return t

        torch.from_numpy = from_numpy
        return super().__enter__()

    def __exit__(self, *exc):
        torch.from_numpy = self._from_numpy
        return super().__exit__(*exc)

    def on_device(self, t: torch.Tensor) -> bool:
        d = self.device
        return t.device.type == d.type and (d.index is None or t.device.index == d.index)

    def is_host(self, t: torch.Tensor) -> bool:
        r = self.host.get(id(t))
        return r is not None and r() is t

    @staticmethod
    def caller() -> tuple[str, str]:
        f = sys._getframe(2)
        while f is not None and (f.f_code.co_filename.startswith(TORCH_DIR)
                                 or f.f_code.co_filename == __file__):  # fmt: skip
            f = f.f_back
        if f is None:
            return "", "?"
        return f.f_code.co_filename, f"{Path(f.f_code.co_filename).name}:{f.f_lineno}"

    def __torch_function__(self, func, types, args=(), kwargs=None):
        kwargs = kwargs or {}
        file, where = self.caller()
        ours = file.startswith(NEURAL_DIR)
        name = getattr(func, "__name__", str(func))
        method = bool(args) and isinstance(args[0], torch.Tensor)
        factory = name in FACTORIES and not method
        if ours and factory and "device" not in kwargs:
            self.factories.append(f"{where} {name}")
        inputs = [t for t in _tensors((args, kwargs), []) if t.dim() > 0]
        host = [self.is_host(t) for t in inputs]
        if any(host) and not all(host):
            self.mixed.append(f"{where} {name}")
        out = func(*args, **kwargs)
        # where the result lives, as a GPU would place it
        target = kwargs.get("device", args[1] if len(args) > 1 else None)
        if factory and "device" in kwargs:
            to_host = _host_target(kwargs["device"])
        elif method and name == "cpu":
            to_host = True
        elif method and name == "cuda":
            to_host = False
        elif method and name == "to" and isinstance(target, (str, torch.device)):
            to_host = _host_target(target)
        else:
            to_host = bool(host) and all(host)
        for t in _tensors(out, []):
            if to_host:
                self.host[id(t)] = weakref.ref(t)
            else:
                self.host.pop(id(t), None)
                if ours and t.dim() > 0 and not self.on_device(t):
                    self.outside.append(f"{where} {name} {t.device}")
        return out


DEVICES = ["cpu", pytest.param("cuda", marks=pytest.mark.skipif(not HAS_CUDA,
                                                                 reason="no CUDA here"))]


def _no_tensors(x, where="info"):
    if isinstance(x, torch.Tensor):
        pytest.fail(f"{where} holds a tensor")
    if isinstance(x, dict):
        for k, v in x.items():
            _no_tensors(v, f"{where}.{k}")
    elif isinstance(x, (list, tuple)):
        for v in x:
            _no_tensors(v, where)


@pytest.mark.parametrize("device", DEVICES)
@pytest.mark.parametrize("name", NAMES)
def test_every_tensor_of_a_training_and_decode_is_on_the_configured_device(
        monkeypatch, name, device):  # fmt: skip
    monkeypatch.setattr(rgjw20, "_TRAINED", {})  # train under the tracker
    btf = smooth_btf(7, size=4, name="test7")
    rng = np.random.default_rng(0)
    wi = rng.normal(size=(20, 3))
    wi[:, 2] = abs(wi[:, 2])
    wi /= np.linalg.norm(wi, axis=1)[:, None]
    with DeviceTracker(resolve_device(device)) as tracker:
        codings = fitted(name, device=device).code(btf, budgets(name))
        recs = [c.reconstruction for c in codings if c.reconstruction is not None]
        assert recs
        results = []
        for rec in recs:
            results += [rec.read(slice(None), slice(0, 2), slice(None), slice(0, 3)),
                        rec.query([0, 1], [1, 2], [0, 3], [2, 1]),
                        rec.lookup(rng.integers(0, 4, 20), rng.integers(0, 4, 20), wi,
                                   wi[::-1].copy())]  # fmt: skip
    assert not tracker.factories, f"tensor factories without device=: {tracker.factories}"
    assert not tracker.mixed, f"host and device tensors mixed: {sorted(set(tracker.mixed))}"
    assert not tracker.outside, f"tensors off the device: {sorted(set(tracker.outside))}"
    for c in codings:
        assert c.info["device"] == str(resolve_device(device))
        _no_tensors(c.info)
    for rec in recs:
        assert rec.device == resolve_device(device)
        assert all(isinstance(a, np.ndarray) for a in rec.stored().values())
    assert all(isinstance(r, np.ndarray) and r.dtype == np.float32 for r in results)


def test_the_tracker_catches_a_tensor_made_without_the_device(monkeypatch):
    """The check above sees a NumPy array or a host tensor used with the configured device's,
    though both are on the CPU here."""
    dev = resolve_device("cpu")
    with DeviceTracker(dev) as tracker:
        a = torch.ones(3, device=dev)
        b = torch.from_numpy(np.ones(3, np.float32))
        _ = a + b
        _ = a + b.to(dev)
        _ = a + torch.arange(3, device=CPU)
    assert tracker.mixed and len(tracker.mixed) == 2
    assert not tracker.factories
    with DeviceTracker(dev) as tracker:  # a factory without device= in the neural package
        exec(compile("torch.arange(3); torch.rand(2, device=d)", f"{NEURAL_DIR}/fake.py",
                     "exec"), {"torch": torch, "d": dev})  # fmt: skip
    assert tracker.factories == ["fake.py:1 arange"]
    monkeypatch.setattr(_torch, "direction_xy", lambda d, device=CPU: torch.from_numpy(
        np.ascontiguousarray(d.xyz[:, :2], dtype=np.float32)))  # the .to(device) forgotten
    monkeypatch.setattr(rjgw19, "direction_xy", _torch.direction_xy)
    with DeviceTracker(dev) as tracker:
        fitted("rjgw19", device="cpu").code(smooth_btf(7, size=4, name="t7"), budgets("rjgw19"))
    assert any("_torch.py" in m for m in tracker.mixed)  # direction_terms: lights @ w0
