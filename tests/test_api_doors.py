"""Issue 47, items 3–5: the front doors refuse what they cannot use in one line naming the
function, the argument, what it must be and what was given; options that would have no effect
are refused (the library and the command line by one rule); every command prints any text,
whatever stdout's encoding."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

import sparsebtf as sb
from sparsebtf import errors
from sparsebtf.cli.main import main
from sparsebtf.errors import BTFInputError, OptionError, SparseBTFError

from .conftest import smooth_btf

SRC = str(Path(sb.__file__).resolve().parents[1])


def _refusal(call, *words: str) -> str:
    """The one-line TypeError (also a BTFInputError) of ``call``, holding ``words``."""
    with pytest.raises(TypeError) as e:
        call()
    assert isinstance(e.value, BTFInputError)  # errors.ArgumentTypeError
    text = str(e.value)
    assert "\n" not in text and len(text) < 400, text
    for w in words:
        assert w in text, (w, text)
    return text


def _cli(argv: list, capsys) -> tuple[int, str, str]:
    try:
        code = main([str(a) for a in argv])
    except SystemExit as e:  # argparse's usage errors
        code = int(e.code or 0)
    out = capsys.readouterr()
    return code, out.out, out.err


def _cli_error(argv: list, capsys) -> str:
    """The command's one error line (exit status 2), without the ``sparsebtf: error:``."""
    code, _, err = _cli(argv, capsys)
    assert code == 2, err
    line = err.strip().splitlines()[-1]
    assert "Traceback" not in err
    return line.split("error: ", 1)[1]


# -- item 3: wrong types at the API's doors ---------------------------------------------------


def test_argument_type_error_is_a_type_error_and_the_librarys():
    assert issubclass(errors.ArgumentTypeError, TypeError)
    assert issubclass(errors.ArgumentTypeError, SparseBTFError)


def test_encode_refuses_options_of_another_type():
    _refusal(lambda: sb.encode(smooth_btf(0), options=5),  # type: ignore[call-overload]
             "encode: options must be an EncodeOptions or None, got 5 (int)")
    _refusal(lambda: sb.encode(smooth_btf(0), execution="4"),  # type: ignore[call-overload]
             "encode: execution must be an Execution or None, got '4' (str)")


def test_load_model_refuses_a_number():
    _refusal(lambda: sb.load_model(42),  # type: ignore[arg-type]
             "load_model: spec must be", "model file's path", "got 42 (int)")


def test_decode_refuses_a_model_of_another_type(tmp_path):
    # refused before the file is read: the argument is wrong whatever the file holds
    _refusal(lambda: sb.decode(tmp_path / "x.coded.h5", 42),  # type: ignore[arg-type]
             "decode: model must be a Model", "got 42 (int)")
    _refusal(lambda: sb.encode(smooth_btf(0), 4.5),  # type: ignore[call-overload]
             "encode: model must be a Model", "got 4.5 (float)")


def test_train_refuses_one_path_or_one_btf():
    text = _refusal(lambda: sb.train("file.h5"),  # type: ignore[arg-type]
                    "train: btfs must be a list", "got 'file.h5' (str)", "['file.h5']")
    assert "/f:" not in text  # not the string's first character opened as a file
    _refusal(lambda: sb.train(smooth_btf(0)),  # type: ignore[arg-type]
             "train: btfs must be a list", "(ArrayBTF)", "[btf]")
    _refusal(lambda: sb.train([smooth_btf(0), 7]), "train: btfs[1] must be", "got 7 (int)")
    _refusal(lambda: sb.train([smooth_btf(0)], options=5),  # type: ignore[arg-type]
             "train: options must be a TrainOptions or None, got 5 (int)")


def test_encode_an_array_says_how_to_wrap_it():
    data = np.full((2, 2, 3, 3, 3), 0.123456, np.float32)
    for given in (data, [data]):
        text = _refusal(lambda g=given: sb.encode(g),  # type: ignore[call-overload]
                        "encode: btf_or_btfs", "numpy.ndarray of shape (2, 2, 3, 3, 3)",
                        "float32", "ArrayBTF")
        assert "0.123" not in text  # the array's type and shape, never its values


def test_open_btf_refuses_an_array_and_a_number():
    text = _refusal(lambda: sb.open_btf(np.zeros((2, 2, 3, 3, 3))),  # type: ignore[arg-type]
                    "open_btf: source must be a path", "numpy.ndarray of shape", "ArrayBTF")
    assert "0." not in text
    _refusal(lambda: sb.open_btf(42), "open_btf: source must be", "got 42 (int)")  # type: ignore


def test_blend_refuses_inputs_that_are_not_coded():
    btf = smooth_btf(0)
    _refusal(lambda: sb.blend([btf, btf], alpha=0.5),  # type: ignore[list-item]
             "blend: coded[0] must be a coded BTF", "(ArrayBTF)")
    _refusal(lambda: sb.blend(3, alpha=0.5),  # type: ignore[arg-type]
             "blend: coded must be a list of two or more coded BTFs", "got 3 (int)")


def test_train_options_refuse_levels_that_do_not_split_k(tmp_path, capsys):
    with pytest.raises(OptionError) as e:
        sb.TrainOptions(tau_train="64,8,8/256,32,32", n_dictionaries=3)
    assert e.value.option == "n_dictionaries" and "multiple of 2" in str(e.value)
    assert sb.TrainOptions(tau_train="64,8,8/256,32,32", n_dictionaries=4).n_dictionaries == 4
    # the command line refuses it by the same rule, naming its flag, before any input is read
    line = _cli_error(["train", tmp_path / "missing.h5", "-o", tmp_path / "m.h5", "--dicts",
                       "3", "--tau-train", "64,8,8/256,32,32"], capsys)  # fmt: skip
    assert line == str(e.value.renamed("--dicts"))


# -- item 4: options that would have no effect ------------------------------------------------


def test_candidates_with_exhaustive_is_refused(tmp_path, capsys):
    # argparse let it through when the value equalled the default (2): --candidates was lost
    for n in ("2", "3"):
        line = _cli_error(["encode", tmp_path / "missing.h5", "-o", tmp_path / "o.coded.h5",
                           "--candidates", n, "--exhaustive"], capsys)  # fmt: skip
        assert "--exhaustive: not allowed with argument --candidates" in line


def test_tau_validation_needs_learned_levels(tmp_path, capsys):
    with pytest.raises(OptionError) as e:
        sb.TrainOptions(tau_validation="64,8,8")
    assert str(e.value).startswith("tau_validation: has no effect unless tau_train is 'learn'")
    assert sb.TrainOptions(tau_train="learn", tau_validation="64,8,8").tau_validation
    line = _cli_error(["train", tmp_path / "missing.h5", "-o", tmp_path / "m.h5",
                       "--tau-validation", "64,8,8"], capsys)  # fmt: skip
    assert line.startswith("--tau-validation: has no effect unless --tau-train is 'learn'")


@pytest.mark.parametrize("tau", ["64,8,8/64,8,8", "learn:64,8,8/256,32,32/64,8,8",
                                 ((64, 8, 8), (64, 8, 8))])  # fmt: skip
def test_a_repeated_tau_level_is_refused(tau):
    with pytest.raises(OptionError) as e:
        sb.TrainOptions(tau_train=tau, n_dictionaries=6)
    assert e.value.option == "tau_train" and "level 64,8,8 is given twice" in str(e.value)


def test_a_repeated_tau_level_on_the_command_line(tmp_path, capsys):
    line = _cli_error(["train", tmp_path / "missing.h5", "-o", tmp_path / "m.h5", "--dicts",
                       "4", "--tau-train", "64,8,8/64,8,8"], capsys)  # fmt: skip
    assert line.startswith("--tau-train: ") and "level 64,8,8 is given twice" in line


def test_patch_sizes_largest_first(tmp_path, capsys):
    for patch in ("5,10", (2, 4)):
        with pytest.raises(OptionError) as e:
            sb.TrainOptions(patch=patch)
        assert "largest first" in str(e.value)
    assert sb.TrainOptions(patch="10,5").patch == "10,5"
    line = _cli_error(["train", tmp_path / "missing.h5", "-o", tmp_path / "m.h5", "--patch",
                       "5,10"], capsys)  # fmt: skip
    assert line.startswith("--patch: ") and "largest first" in line and "10,5" in line


def test_export_release_refuses_an_empty_name(tmp_path, capsys):
    for name in ("", "  "):
        line = _cli_error(["export-release", tmp_path / "missing.coded.h5", tmp_path / "out",
                           "--name", name], capsys)  # fmt: skip
        assert line.startswith("--name must not be empty")
    assert not (tmp_path / "out").exists()


def test_cache_on_a_file_is_an_error(tmp_path, capsys, monkeypatch):
    (tmp_path / "cachefile").write_text("not a folder")
    monkeypatch.setenv("SPARSEBTF_CACHE", str(tmp_path / "cachefile"))
    for action in (["list"], ["size"], ["clear"], []):
        line = _cli_error(["cache", *action], capsys)
        assert str(tmp_path / "cachefile") in line and "not a folder" in line
    from sparsebtf.data.cache import entries  # the library's rule, the command's line

    with pytest.raises(SparseBTFError, match="cachefile is a file, not a folder"):
        entries()
    assert entries(tmp_path / "nowhere") == []  # not made yet: nothing cached


def test_cache_on_a_missing_folder_says_so(tmp_path, capsys, monkeypatch):
    missing = tmp_path / "nowhere"
    monkeypatch.setenv("SPARSEBTF_CACHE", str(missing))
    code, out, _ = _cli(["cache", "list"], capsys)
    assert code == 0 and "0 entries" not in out
    assert out.startswith(f"{missing}: no such folder")
    code, out, _ = _cli(["cache", "size", "--json"], capsys)
    assert code == 0 and '"exists": false' in out
    assert not missing.exists()


# -- item 5: any text prints, whatever stdout's encoding --------------------------------------


def _ascii_run(*argv: str, cwd: Path) -> subprocess.CompletedProcess:
    env = {**os.environ, "PYTHONIOENCODING": "ascii", "PYTHONPATH": SRC,
           "SPARSEBTF_PROGRESS": "0"}  # fmt: skip
    return subprocess.run([sys.executable, "-m", "sparsebtf.cli.main", *argv], cwd=cwd,
                          env=env, capture_output=True, timeout=120)  # fmt: skip


def test_info_prints_a_non_ascii_name_on_an_ascii_stdout(tmp_path):
    sb.save_btf(smooth_btf(0, size=4, name="caf\u00e9"), tmp_path / "m.h5")
    r = _ascii_run("info", "m.h5", cwd=tmp_path)
    assert r.returncode == 0 and b"Traceback" not in r.stderr, r.stderr.decode()
    assert b"caf\\xe9" in r.stdout


@pytest.mark.skipif(sys.platform == "darwin", reason="file names must be valid UTF-8 there")
def test_a_file_name_not_utf8_prints_escaped(tmp_path):
    sb.save_btf(smooth_btf(0, size=4), tmp_path / "m.h5")
    out = os.fsdecode(b"out\xfe.h5")  # undecodable bytes: held as a surrogate
    r = _ascii_run("convert", "m.h5", "-o", out, cwd=tmp_path)
    assert r.returncode == 0 and b"Traceback" not in r.stderr, r.stderr.decode()
    assert b"wrote out\\udcfe.h5" in r.stdout
    assert (tmp_path / out).is_file()
