"""The option objects (issue 33, item 2): ``EncodeOptions``, ``TrainOptions`` and ``Execution``
each check their values against one table of constraints; a refusal is one line naming the
option, what it must be and the value; the command line refuses the same value with the same
line (its flag in place of the name) and takes the library's defaults; ``sb.encode`` and
``sb.train`` give the same bits with an options object as with keywords."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

import sparsebtf as sb
from sparsebtf.cli import encode as cli_encode
from sparsebtf.cli import train as cli_train
from sparsebtf.cli.main import build_parser, main
from sparsebtf.constraints import Interval, Options, check_option
from sparsebtf.errors import BTFInputError, OptionError
from sparsebtf.storage.coded_file import coded_image

from .conftest import smooth_btf, tiny_model

CLASSES = (sb.EncodeOptions, sb.TrainOptions, sb.Execution)
#: Values tried against every option: each option refuses at least one of them.
POOL = (-1, 0, 10**13, 1.5, math.nan, -math.inf, "bogus", "0,0,0", True, (1, 2), object())


def _table() -> list[tuple[type[Options], str]]:
    return [(cls, name) for cls in CLASSES for name in cls.constraints]


def _one_line(e: pytest.ExceptionInfo) -> str:
    text = str(e.value)
    assert text and "\n" not in text
    return text


# -- the tables ------------------------------------------------------------------------------


@pytest.mark.parametrize("cls", CLASSES, ids=lambda c: c.__name__)
def test_defaults_are_accepted_and_every_option_has_constraints(cls):
    default = cls()
    assert set(cls.constraints) == set(cls.names())  # one entry per option, no more
    assert default.changed() == {}
    with pytest.raises(dataclasses.FrozenInstanceError):
        default.progress = True  # type: ignore[misc]


def _shown(value) -> str:
    return f"{value:g}" if isinstance(value, float) else repr(value)


@pytest.mark.parametrize(("cls", "name"), _table(), ids=lambda x: getattr(x, "__name__", x))
def test_each_option_refuses_a_bad_value_in_one_line(cls, name):
    refused = 0
    for bad in POOL:
        try:
            cls(**{name: bad})
        except OptionError as e:  # one line: the option, what it must be, the value
            text = str(e)
            assert "\n" not in text and e.option == name, text
            assert text.startswith((f"{name} must be ", f"{name}: ")), text
            assert _shown(bad) in text, text
            refused += 1
        except BTFInputError:  # a rule between options (workers and scheduler): not this one
            pass
    assert refused, f"{cls.__name__}.{name} accepts every value of {POOL}"


def test_an_option_without_constraints_is_a_programming_error():
    with pytest.raises(TypeError, match="no constraints for"):

        @dataclasses.dataclass(frozen=True, kw_only=True)
        class Bad(Options):
            size: int = 1
            constraints = {}  # noqa: RUF012


def test_the_words_of_a_refusal():
    with pytest.raises(OptionError) as e:
        sb.EncodeOptions(candidates=0)
    assert _one_line(e) == ("candidates must be an integer >= 1 (dictionaries per data point) "
                            "or None, got 0")  # fmt: skip
    with pytest.raises(OptionError) as e:
        sb.EncodeOptions(objective="lin")
    assert _one_line(e) == ("objective: unknown coding objective 'lin'; choose one of log, "
                            "linear, display")  # fmt: skip
    with pytest.raises(OptionError) as e:
        sb.TrainOptions(log_offset=1e9)
    assert _one_line(e).endswith(", got 1e+09")
    with pytest.raises(OptionError, match=r"^sample must be a finite number in \(0, 1\]"):
        sb.TrainOptions(sample=math.nan)
    with pytest.raises(OptionError, match="every tau must be >= 1"):
        sb.TrainOptions(tau_train="0,0,0")
    with pytest.raises(BTFInputError, match=r"either workers .* or a scheduler, not both"):
        sb.Execution(workers=2, scheduler="tcp://127.0.0.1:1")
    check_option("n", 3, [Interval(int, 1, 3)])
    with pytest.raises(OptionError, match=r"^n must be an integer in \[1, 3\), got 3$"):
        check_option("n", 3, [Interval(int, 1, 3, closed="left")])


def test_build_replace_and_unknown_options():
    base = sb.EncodeOptions(eps=0.0)
    assert sb.EncodeOptions.build(base, candidates=None) == sb.EncodeOptions(eps=0.0,
                                                                             candidates=None)
    assert base.replace(batch_size=8).changed() == {"eps": 0.0, "batch_size": 8}
    with pytest.raises(OptionError, match="batch_size"):
        base.replace(batch_size=0)
    with pytest.raises(BTFInputError, match="unknown option 'epsilon' for EncodeOptions") as e:
        sb.EncodeOptions.build(epsilon=0.1)
    _one_line(e)


# -- the command line: same refusal, same defaults -------------------------------------------


def _cli_cases():
    """Every flag the CLI checks by a table, with its command, option and argparse type."""
    parser = build_parser()
    sub = next(a for a in parser._actions if a.dest == "command").choices
    cases = []
    for command, module, cls in (("encode", cli_encode, sb.EncodeOptions),
                                 ("train", cli_train, sb.TrainOptions)):  # fmt: skip
        types = {f: a.type for a in sub[command]._actions for f in a.option_strings}
        cases += [(command, cls, name, flag, types[flag]) for name, flag in module.FLAGS.items()]
    return cases


@pytest.mark.parametrize(("command", "cls", "name", "flag", "kind"), _cli_cases(),
                         ids=lambda x: getattr(x, "__name__", x))  # fmt: skip
def test_library_and_cli_refuse_a_bad_value_alike(command, cls, name, flag, kind, tmp_path,
                                                 capsys, monkeypatch):  # fmt: skip
    monkeypatch.chdir(tmp_path)
    for text in ("-1", "0", "99999999999", "nan"):
        try:
            cls(**{name: kind(text)})
        except ValueError as e:  # int("nan"), or the library's refusal
            if isinstance(e, OptionError):
                lib = str(e)
                break
    else:
        pytest.fail(f"no bad value found for {name}")
    argv = {"encode": ["encode", "synth:stone:8", "-m", "M", "-o", "c.h5"],
            "train": ["train", "synth:stone:8", "-o", "m.h5"]}[command]  # fmt: skip
    assert main([*argv, f"{flag}={text}"]) == 2
    err = capsys.readouterr().err.splitlines()
    assert err == [f"sparsebtf: error: {flag}{lib[len(name):]}"]
    assert list(tmp_path.iterdir()) == []  # refused before any work


def test_log_offset_is_refused_alike(tmp_path, capsys, monkeypatch):
    monkeypatch.chdir(tmp_path)
    with pytest.raises(OptionError) as e:
        sb.EncodeOptions(log_offset=1e9)
    assert main(["encode", "synth:stone:8", "-m", "M", "-o", "c.h5", "--log-offset", "1e9"]) == 2
    err = capsys.readouterr().err.splitlines()
    assert err == [f"sparsebtf: error: --log-offset{str(e.value)[len('log_offset'):]}"]


@pytest.mark.parametrize(("argv", "cls", "flags"), [
    (["encode", "b.h5", "-o", "c.h5"], sb.EncodeOptions,
     {"eps": "eps", "candidates": "candidates", "objective": "objective", "batch": "batch_size",
      "log_offset": "log_offset", "std_mode": "std_mode"}),
    (["train", "b.h5", "-o", "m.h5"], sb.TrainOptions,
     {"dicts": "n_dictionaries", "patch": "patch", "sample": "sample", "iters": "max_iter",
      "tol": "tol", "std_mode": "std_mode", "log_offset": "log_offset", "candidates":
      "candidates", "full_pass_every": "full_pass_every", "batch": "batch_size",
      "seed": "seed"}),
])  # fmt: skip
def test_the_cli_takes_the_library_defaults(argv, cls, flags):
    args = build_parser().parse_args(argv)
    default = cls()
    for dest, name in flags.items():
        assert getattr(args, dest) == getattr(default, name), dest
    if cls is sb.TrainOptions:
        assert args.tau_train == ",".join(map(str, default.tau_train))


# -- the library: options objects and keywords give the same bits ---------------------------


@pytest.fixture(scope="module")
def model():
    return tiny_model()


def test_encode_options_equal_keywords_bit_for_bit(model):
    btf = smooth_btf(5)
    kw = {"eps": 1e-4, "candidates": None, "objective": "linear", "log_offset": "release",
          "batch_size": 2, "progress": False}  # fmt: skip
    by_keywords = sb.encode(btf, model, target=(16, 4, 4), **kw)
    by_options = sb.encode(btf, model, target=(16, 4, 4), options=sb.EncodeOptions(**kw),
                           execution=sb.Execution())  # fmt: skip
    assert coded_image(by_options) == coded_image(by_keywords)
    # keywords set an options object's fields
    mixed = sb.encode(btf, model, target=(16, 4, 4), options=sb.EncodeOptions(**kw), eps=1e-4)
    assert coded_image(mixed) == coded_image(by_keywords)
    # a ratio, and many BTFs
    ratio = {"candidates": 1, "weighting": "log", "progress": False}
    a = sb.encode(btf, model, target="3x", **ratio)
    b = sb.encode(btf, model, target="3x", options=sb.EncodeOptions(**ratio))
    assert coded_image(a) == coded_image(b)
    crop = (slice(0, 4), slice(0, 8))
    many = [coded_image(c) for c in sb.encode([btf, smooth_btf(6)], model, target="16,4,4",
                                              crop=crop, progress=False)]  # fmt: skip
    opts = sb.EncodeOptions(crop=crop, progress=False)
    assert many == [coded_image(c) for c in sb.encode([btf, smooth_btf(6)], model,
                                                      target="16,4,4", options=opts)]


def test_train_options_equal_keywords_bit_for_bit():
    btfs = [smooth_btf(s) for s in range(2)]
    kw = {"n_dictionaries": 2, "tau_train": (8, 2, 2), "patch": 4, "sample": 0.5,
          "max_iter": 2, "seed": 1, "progress": False}  # fmt: skip
    a = sb.train(btfs, **kw)
    b = sb.train(btfs, options=sb.TrainOptions(**kw), execution=sb.Execution())
    assert a.content_hash == b.content_hash
    for ch in a.channels:
        for x, y in zip(a.dictionaries[ch], b.dictionaries[ch], strict=True):
            np.testing.assert_array_equal(x, y)
    with pytest.raises(OptionError, match=r"^n_dictionaries must be an integer in"):
        sb.train(btfs, n_dictionaries=0)
    with pytest.raises(BTFInputError, match="unknown option 'k' for TrainOptions"):
        sb.train(btfs, k=3)


def test_a_keyword_where_it_does_not_apply_is_one_line(model):
    btf = smooth_btf(5)
    with pytest.raises(BTFInputError, match="'weighting' does not apply to a tau target") as e:
        sb.encode(btf, model, target=(16, 4, 4), weighting="log")
    _one_line(e)
    with pytest.raises(BTFInputError, match="'checkpoint_dir' does not apply to one BTF"):
        sb.encode(btf, model, target="2x", checkpoint_dir="ck")
    with pytest.raises(OptionError, match=r"^workers must be an integer >= 1"):
        sb.encode(btf, model, target=(16, 4, 4), workers=0)
