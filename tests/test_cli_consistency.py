"""The command line speaks one language (issue 20, item 4, and the output defects of item 3):
``--version``, one meaning per option name, τ fractions wherever τ is taken, bounded numbers,
clear errors for values that start with '-', sizes announced before large writes, real
``.btf`` output, ``| head`` exiting 0, the user's umask, stale temporaries removed, notes
instead of raw warnings, readable tables and one PSNR. Tiny shapes: 13 directions, 8x8 texels.
"""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

import sparsebtf
from sparsebtf.cli.main import main

SRC = Path(sparsebtf.__file__).resolve().parents[1]


def run(argv, capsys):
    code = main([str(a) for a in argv])
    out = capsys.readouterr()
    return code, out.out, out.err


def cli(argv, **kw) -> subprocess.CompletedProcess:
    env = {**os.environ, "PYTHONPATH": str(SRC), "SPARSEBTF_PROGRESS": "0"}
    return subprocess.run([sys.executable, "-m", "sparsebtf.cli.main", *map(str, argv)],
                          env=env, capture_output=True, text=True, timeout=120, **kw)  # fmt: skip


# --------------------------------------------------------------------------- the parser


def test_version_prints_the_library_version(capsys):
    with pytest.raises(SystemExit) as e:
        main(["--version"])
    assert e.value.code == 0
    assert capsys.readouterr().out.strip() == f"sparsebtf {sparsebtf.library_version()}"


def test_value_starting_with_dash_gets_a_clear_message(capsys):
    with pytest.raises(SystemExit) as e:
        main(["convert", "synth:stone:8", "-o", "x.h5", "--crop", "-10:10,0:10"])
    assert e.value.code == 2
    err = capsys.readouterr().err.strip().splitlines()[-1]
    assert "--crop: expected one argument" in err
    assert "must be attached: --crop=VALUE" in err


def test_attached_dash_value_reaches_the_range_check(tmp_path, capsys):
    code, _, err = run(["convert", "synth:stone:8:0:tiny13", "-o", tmp_path / "x.h5",
                        "--crop=-10:10,0:10"], capsys)  # fmt: skip
    assert code == 2
    assert err.count("\n") == 1 and "--crop -10:10,0:10: rows R0:R1" in err


# --------------------------------------------------------------------------- pipes, folders


def test_head_closing_the_pipe_exits_0():
    # `info … | head -1`: the reader goes away after one line; the pipeline's status is ours.
    env = {**os.environ, "PYTHONPATH": str(SRC), "SPARSEBTF_PROGRESS": "0"}
    proc = subprocess.run(
        f"{sys.executable} -m sparsebtf.cli.main info synth:stone:8:0:tiny13 --no-scan | head -1"
        "; echo \"status ${PIPESTATUS[0]}\"",
        shell=True, executable="/bin/bash", env=env, capture_output=True, text=True, timeout=120,
    )  # fmt: skip
    lines = proc.stdout.strip().splitlines()
    assert len(lines) == 2 and lines[-1] == "status 0", proc.stdout + proc.stderr
    assert "Error" not in proc.stderr and "Traceback" not in proc.stderr


def test_broken_pipe_in_process_returns_0(monkeypatch, capsys):
    class Gone:
        def write(self, text):
            raise BrokenPipeError

        def flush(self):
            raise BrokenPipeError

        def fileno(self):
            return sys.__stdout__.fileno()

    # main() points the real stdout at /dev/null afterwards; keep ours.
    monkeypatch.setattr(os, "dup2", lambda *a: None)
    monkeypatch.setattr(sys, "stdout", Gone())
    assert main(["info", "synth:stone:8:0:tiny13", "--no-scan"]) == 0


def _dead_pid() -> int:
    proc = subprocess.Popen([sys.executable, "-c", "pass"])
    proc.wait()
    return proc.pid


def test_stale_temporaries_of_any_output_are_removed_by_the_next_run(tmp_path, capsys):
    from sparsebtf._atomic import _host

    dead, host = _dead_pid(), _host()
    stale_file = tmp_path / f".other.h5.{dead}-{host}.abcd1234.part"  # another target's
    stale_dir = tmp_path / f".site.{dead}-{host}.ef_5678.part"  # a killed viewer export
    live = tmp_path / f".busy.h5.{os.getpid()}-{host}.ijkl9012.part"  # a live writer's
    foreign = tmp_path / f".x.h5.{dead}-00000000.mnop3456.part"  # another host's, recent
    mine = tmp_path / "notes.part"  # not our pattern
    stale_dir.mkdir()
    (stale_dir / "data.bin").write_bytes(b"partial")
    for p in (stale_file, live, foreign, mine):
        p.write_bytes(b"partial")
    code, _, err = run(["convert", "synth:stone:8:0:tiny13", "-o", tmp_path / "new.h5"], capsys)
    assert code == 0, err
    assert not stale_file.exists() and not stale_dir.exists()
    assert live.exists() and foreign.exists() and mine.exists()


def test_old_temporaries_from_another_host_are_removed(tmp_path):
    from sparsebtf._atomic import FOREIGN_STALE_SECONDS, remove_stale_parts

    old = tmp_path / ".x.h5.123-00000000.abcd1234.part"
    old.write_bytes(b"partial")
    t = old.stat().st_mtime - FOREIGN_STALE_SECONDS - 60
    os.utime(old, (t, t))
    assert remove_stale_parts(tmp_path / "y.h5") == [old]


def test_view_export_folder_follows_the_umask(tmp_path):
    from sparsebtf.rendering.viewer import export

    class Bundle:
        def files(self):
            return {"index.html": b"<html></html>"}

    previous = os.umask(0o022)
    try:
        out = export(Bundle(), tmp_path / "site")
    finally:
        os.umask(previous)
    assert out.stat().st_mode & 0o777 == 0o755
    assert [p.name for p in tmp_path.iterdir()] == ["site"]


# --------------------------------------------------------------------------- shared files


@pytest.fixture(scope="module")
def coded_files(tmp_path_factory):
    """A dense 8x8 tiny13 BTF with some negative values, a model for it and its codes."""

    from sparsebtf.data.btf import ArrayBTF
    from sparsebtf.data.dense_file import write_dense
    from sparsebtf.storage import save_model

    from .conftest import smooth_btf, tiny_model

    d = tmp_path_factory.mktemp("cli")
    base = smooth_btf(5)
    data = base.to_array().copy()
    data[0, 0, 0, :3, 0] = -0.01  # three negative values, clamped (with a note) when encoding
    write_dense(d / "neg.h5", ArrayBTF(data, base.lights, base.views, name="smooth5"),
                progress=False)  # fmt: skip
    write_dense(d / "ref.h5", base, progress=False)
    save_model(tiny_model(), d / "model.h5")
    assert main(["encode", str(d / "ref.h5"), "-m", str(d / "model.h5"), "-o",
                 str(d / "c.h5"), "--tau", "20,6,6"]) == 0  # fmt: skip
    return d


# --------------------------------------------------------------------------- warnings


def test_encode_clamp_warning_is_one_note_line_naming_the_file(coded_files, tmp_path, capsys):
    d = coded_files
    code, _, err = run(["encode", d / "neg.h5", "-m", d / "model.h5", "-o", tmp_path / "n.h5",
                        "--tau", "20,6,6"], capsys)  # fmt: skip
    assert code == 0, err
    notes = [line for line in err.splitlines() if line.strip()]
    assert notes == [f"sparsebtf: note: {d / 'neg.h5'}: clamped 3 negative values to 0"], err


def test_runtime_warnings_do_not_print_before_a_one_line_error(monkeypatch, capsys):
    import numpy as np

    from sparsebtf.cli import info
    from sparsebtf.errors import FileFormatError

    def describe(*args, **kwargs):
        np.log(np.zeros(2))  # RuntimeWarning: divide by zero
        raise FileFormatError("x.h5: damaged")

    monkeypatch.setattr(info, "describe", describe)
    code, _, err = run(["info", "x.h5"], capsys)
    assert code == 2 and err == "sparsebtf: error: x.h5: damaged\n"


def test_runtime_warnings_after_success_are_one_note_each(monkeypatch, capsys):
    import numpy as np

    from sparsebtf.cli import info

    def describe(*args, **kwargs):
        for _ in range(3):
            np.log(np.zeros(2))
        return {"kind": "test"}

    monkeypatch.setattr(info, "describe", describe)
    code, out, err = run(["info", "x.h5"], capsys)
    assert code == 0 and "test" in out
    assert err == "sparsebtf: note: divide by zero encountered in log\n"


# --------------------------------------------------------------------------- numbers, tau


def test_huge_tau_is_refused_in_one_line(coded_files, tmp_path, capsys):
    d = coded_files
    encode = ["encode", d / "ref.h5", "-m", d / "model.h5", "-o", tmp_path / "x.h5", "--tau"]
    code, _, err = run([*encode, "99999999999999999999"], capsys)
    assert code == 2 and err.count("\n") == 1
    assert "--tau: tau '99999999999999999999': every tau must be <= 4294967295" in err
    code, _, err = run([*encode, "5000,6,6"], capsys)
    assert code == 2 and err.count("\n") == 1
    assert "tau = 5000 is more coefficients than a data point has (4x4x13x13 = 2,704)" in err
    assert not (tmp_path / "x.h5").exists()
    for argv in (["view", d / "c.h5", "--export", tmp_path / "site"],
                 ["render", d / "c.h5", "-o", tmp_path / "r.png"]):
        code, _, err = run([*argv, "--tau", "99999999999999999999"], capsys)
        assert code == 2 and "every tau must be <= 4294967295" in err, argv
    assert list(tmp_path.iterdir()) == []


def test_encode_takes_a_tau_fraction_like_render_and_view(coded_files, tmp_path, capsys):
    import json
    import math

    d = coded_files
    code, out, err = run(["encode", d / "ref.h5", "-m", d / "model.h5", "-o", tmp_path / "f.h5",
                          "--tau", "0.05", "--allow-below-training", "--json"], capsys)  # fmt: skip
    assert code == 0, err
    # A fraction of the release's 885,64,64, rounded up (the default tau of encode).
    want = {ch: math.ceil(0.05 * t) for ch, t in {"Y": 885, "U": 64, "V": 64}.items()}
    assert json.loads(out)["nnz"] == {ch: 4 * t for ch, t in want.items()}


def test_every_numeric_option_is_range_checked():
    import argparse

    from sparsebtf.cli.main import build_parser

    unchecked = []

    def walk(parser, name):
        checks = parser.get_default("checks") or {}
        for a in parser._actions:
            if isinstance(a, argparse._SubParsersAction):
                for sub, sp in a.choices.items():
                    walk(sp, f"{name} {sub}")
            elif a.type in (int, float) and a.dest not in checks and a.choices is None:
                # (an option with choices is bounded by them)
                unchecked.append(f"{name} {a.option_strings}")

    walk(build_parser(), "sparsebtf")
    assert unchecked == []


@pytest.mark.parametrize("weights", ["nan,0.5", "inf,0"])
def test_blend_weights_must_be_finite(coded_files, tmp_path, capsys, weights):
    d = coded_files
    code, _, err = run(["blend", d / "c.h5", d / "c.h5", "--weights", weights, "-o",
                        tmp_path / "b.h5"], capsys)  # fmt: skip
    assert code == 2 and "--weights must be finite numbers" in err


# --------------------------------------------------------------------------- option names


def test_render_image_size_and_its_deprecated_spelling(capsys):
    from sparsebtf.cli.main import build_parser

    p = build_parser()
    new = p.parse_args(["render", "c.h5", "-o", "x.png", "--image-size", "32x24"])
    assert new.image_size == "32x24" and capsys.readouterr().err == ""
    old = p.parse_args(["render", "c.h5", "-o", "x.png", "--size", "32x24"])
    assert old.image_size == "32x24"
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "--size is deprecated" in err and "use --image-size" in err
    assert p.parse_args(["render", "c.h5", "-o", "x.png"]).image_size == "256"
    assert "--image-size" in p._subparsers._group_actions[0].choices["render"].format_help()


def test_blend_direction_options_and_their_deprecated_spelling(coded_files, tmp_path, capsys):
    d = coded_files
    common = ["blend", d / "c.h5", d / "c.h5", "--sweep", "2", "--png", tmp_path / "s"]
    code, _, err = run([*common, "--light-dir", "0,60", "--view-dir", "90,70"], capsys)
    assert code == 0 and "deprecated" not in err, err
    code, _, err = run([*common, "--light", "0,60", "--view", "90,70"], capsys)
    assert code == 0
    assert [line for line in err.splitlines() if "deprecated" in line] == [
        "sparsebtf: note: --light is deprecated (in 'blend' it meant degrees; 'lookup --light' "
        "is an index); use --light-dir",
        "sparsebtf: note: --view is deprecated (in 'blend' it meant degrees; 'lookup --view' "
        "is an index); use --view-dir",
    ]
    code, _, err = run([*common, "--light-dir", "0,100"], capsys)
    assert code == 2 and "--light-dir: elevation must be in (0, 90] degrees" in err


# --------------------------------------------------------------------------- output


def test_eval_without_ssim_images_prints_a_table(coded_files, capsys):
    d = coded_files
    code, out, err = run(["eval", d / "c.h5", "--reference", d / "ref.h5", "--ssim-images", "0"],
                         capsys)  # fmt: skip
    assert code == 0, err
    assert "SSIM  " in out and "not computed (--ssim-images 0)" in out
    assert "Traceback" not in err and "{" not in out


def test_eval_table_prints_fields_it_does_not_know(coded_files, monkeypatch, capsys):
    from sparsebtf import metrics

    compare = metrics.compare

    def more(*args, **kwargs):
        return {**compare(*args, **kwargs), "largest_decoded_value": 1.25,
                "error_share_top_values": 0.125}  # fmt: skip

    monkeypatch.setattr(metrics, "compare", more)
    d = coded_files
    code, out, _ = run(["eval", d / "c.h5", "--reference", d / "ref.h5", "--ssim-images", "2"],
                       capsys)  # fmt: skip
    assert code == 0
    lines = out.splitlines()
    assert any(line.split() == ["largest", "decoded", "value", "1.25"] for line in lines)
    assert any(line.split() == ["error", "share", "top", "values", "0.125"] for line in lines)


def test_psnr_has_one_fixed_peak(coded_files, capsys):
    import json
    import math

    import numpy as np

    from sparsebtf.metrics import PSNR_PEAK, psnr
    from sparsebtf.rendering.render import compare_renders

    d = coded_files
    _, out, _ = run(["eval", d / "c.h5", "--reference", d / "ref.h5", "--ssim-images", "2",
                        "--json"], capsys)  # fmt: skip
    ev = json.loads(out)
    assert PSNR_PEAK == 1.0 and ev["peak"] == 1.0
    assert ev["psnr_rgb"] == pytest.approx(-10 * math.log10(ev["mse_rgb"]))
    _code, out, _ = run(["eval", d / "c.h5", "--reference", d / "ref.h5", "--ssim-images", "2"],
                       capsys)  # fmt: skip
    assert f"{ev['psnr_rgb']:.2f} dB (peak 1)" in out
    # the display-mapped MSE beside the linear and log ones, in the table and the JSON
    assert ev["mse_display"] > 0
    row = next(line for line in out.splitlines() if line.startswith("MSE, display-mapped"))
    assert f"{ev['mse_display']:.4g}" in row
    # Renders: a noisy reference's largest pixel no longer sets the peak, so a lower MSE
    # always reads as a higher PSNR (the 0.0039 -> 31.6 dB, 0.0069 -> 36.8 dB).
    rng = np.random.default_rng(0)
    ref = rng.uniform(0, 1, (16, 16, 3))
    quiet, firefly = ref.copy(), ref.copy()
    firefly[3, 3] = 40.0  # one bright sample in the second reference
    good = compare_renders(ref + 0.0625, quiet)
    worse = compare_renders(ref + 0.0625 * 1.5, firefly)
    assert good["mse"] < worse["mse"] and good["psnr"] > worse["psnr"]
    assert good["peak"] == worse["peak"] == 1.0 and good["psnr"] == pytest.approx(psnr(good["mse"]))


def test_tables_have_no_raw_dicts_or_snake_case_keys(coded_files, capsys):
    d = coded_files
    for argv in (["info", d / "c.h5", "-m", d / "model.h5"], ["info", d / "model.h5"],
                 ["info", d / "ref.h5"],
                 ["lookup", d / "c.h5", "--texel", "1,2", "--light", "3", "--view", "4"],
                 ["lookup", d / "ref.h5", "--texel", "1,2", "--light", "3", "--view", "4"]):
        code, out, err = run(argv, capsys)
        assert code == 0, err
        keys = [line.split("  ")[0] for line in out.splitlines()]
        assert not [k for k in keys if "_" in k], (argv, keys)
        assert "{" not in out and "'Y'" not in out and '"Y"' not in out, out
    code, out, _ = run(["lookup", d / "c.h5", "--texel", "1,2", "--light", "3", "--view", "4"],
                       capsys)  # fmt: skip
    assert "standardised (Eq. 5)" in out and "linear RGB" in out
    code, out, _ = run(["encode", d / "ref.h5", "-m", d / "model.h5", "-o", d / "e.h5", "--tau",
                        "20,6,6"], capsys)  # fmt: skip
    assert "coefficients Y 80, U 24, V 24" in out and "{" not in out


def test_lookup_json_is_still_the_machine_form(coded_files, capsys):
    import json

    d = coded_files
    _code, out, _ = run(["lookup", d / "c.h5", "--texel", "1,2", "--light", "3", "--view", "4",
                        "--json"], capsys)  # fmt: skip
    obj = json.loads(out)
    assert set(obj["standardized"]) == {"Y", "U", "V"} and len(obj["rgb"]) == 3


def test_wrong_model_error_names_the_models(coded_files, tmp_path, capsys):
    from sparsebtf.storage import save_model

    from .conftest import tiny_model

    d = coded_files
    save_model(tiny_model(max_iter=1), tmp_path / "other.h5")
    code, _, err = run(["eval", d / "c.h5", "--reference", d / "ref.h5", "-m",
                        tmp_path / "other.h5"], capsys)  # fmt: skip
    assert code == 2 and err.count("\n") == 1
    assert f"(file {d / 'model.h5'})" in err and f"(file {tmp_path / 'other.h5'})" in err
    assert str(d / "c.h5") in err
    code, _, err = run(["eval", d / "c.h5", "--reference", d / "ref.h5", "-m", "release"],
                       capsys)  # fmt: skip
    assert code == 2 and "(bundled 'release')" in err


def test_errors_about_a_file_name_the_file(coded_files, tmp_path, capsys):
    d = coded_files
    from sparsebtf.data.dense_file import write_dense

    from .conftest import smooth_btf

    write_dense(tmp_path / "dirs7.h5", smooth_btf(1, n_dirs=7), progress=False)
    code, _, err = run(["eval", d / "c.h5", "--reference", tmp_path / "dirs7.h5"], capsys)
    assert code == 2 and err.count("\n") == 1
    assert str(tmp_path / "dirs7.h5") in err and str(d / "c.h5") in err, err


# --------------------------------------------------------------------------- convert, sizes


def test_convert_to_btf_writes_a_real_ubo2014_file(tmp_path, capsys):
    import numpy as np

    from sparsebtf.formats.ubo2014 import UBO2014BTF
    from sparsebtf.open import open_btf

    out = tmp_path / "standin.btf"
    code, stdout, err = run(["convert", "synth:felt:8:0:tiny13", "-o", out], capsys)
    assert code == 0, err
    assert out.read_bytes()[:9] == b"!DFMF08FC"
    btf, ref = open_btf(out), open_btf("synth:felt:8:0:tiny13")
    assert isinstance(btf, UBO2014BTF)
    assert np.array_equal(btf.to_array(), ref.to_array())  # float32 factors: exact
    assert btf.lights.equals(ref.lights) and btf.views.equals(ref.views)
    first = stdout.splitlines()[0]
    from sparsebtf._limits import format_bytes

    assert first.startswith(f"writing {out}: {format_bytes(out.stat().st_size)} (UBO2014")


def test_convert_to_btf_with_more_texels_than_directions(tmp_path, capsys):
    import numpy as np

    from sparsebtf.open import open_btf

    out = tmp_path / "wide.btf"  # 12x12 texels > 7x7 directions: the other factor is the identity
    code, _, err = run(["convert", "synth:stone:12:0:tiny7", "-o", out, "--dtype", "float16"],
                       capsys)  # fmt: skip
    assert code == 0, err
    a, b = open_btf(out).to_array(), open_btf("synth:stone:12:0:tiny7").to_array()
    assert np.array_equal(a, b.astype(np.float16).astype(np.float32))


@pytest.mark.parametrize("name", ["x.xyz", "x", "x.btf.gz"])
def test_convert_refuses_unknown_extensions(tmp_path, capsys, name):
    code, _, err = run(["convert", "synth:felt:8:0:tiny13", "-o", tmp_path / name], capsys)
    assert code == 2 and err.count("\n") == 1
    assert "unknown extension" in err and ".h5 (our dense file) or .btf (a UBO2014 file)" in err
    assert list(tmp_path.iterdir()) == []


def test_large_outputs_are_announced_before_they_are_written(coded_files, tmp_path, capsys):
    from sparsebtf._limits import format_bytes

    code, out, _ = run(["synth", "--class", "felt", "--size", "8", "--directions", "tiny13",
                        "-o", tmp_path / "s.h5"], capsys)  # fmt: skip
    # 8x8 texels x 13 x 13 directions x 3 in chunks of 8x8x8x8x3: 4 chunks of 12,288 values.
    stored = 4 * 8 * 8 * 8 * 8 * 3
    assert code == 0
    assert out.splitlines()[0] == (f"writing {tmp_path / 's.h5'}: {format_bytes(4 * stored)} "
                                   "(8x8 texels, 13 lights x 13 views, float32)")  # fmt: skip
    code, out, _ = run(["convert", tmp_path / "s.h5", "-o", tmp_path / "h.h5", "--dtype",
                        "float16"], capsys)  # fmt: skip
    assert out.splitlines()[0].startswith(f"writing {tmp_path / 'h.h5'}: "
                                          f"{format_bytes(2 * stored)} (")  # fmt: skip
    code, out, _ = run(["decode", coded_files / "c.h5", "-o", tmp_path / "d.h5"], capsys)
    assert out.splitlines()[0].startswith(f"writing {tmp_path / 'd.h5'}: "
                                          f"{format_bytes(4 * stored)} (")  # fmt: skip
    # The announced size is the file's, to the header's few KiB.
    for name, item in (("s.h5", 4), ("h.h5", 2), ("d.h5", 4)):
        assert 0 <= (tmp_path / name).stat().st_size - item * stored < 16 * 1024, name


def test_writing_commands_have_json(coded_files, tmp_path, capsys):
    import json

    code, out, err = run(["convert", "synth:felt:8:0:tiny13", "-o", tmp_path / "a.btf",
                          "--json"], capsys)  # fmt: skip
    assert code == 0
    (entry,) = json.loads(out)["written"]
    assert entry["kind"] == "ubo2014" and entry["file_bytes"] == (tmp_path / "a.btf").stat().st_size
    assert err.startswith(f"writing {tmp_path / 'a.btf'}: ")  # the size line, off stdout
    code, out, _ = run(["synth", "--class", "felt", "--size", "4", "--directions", "tiny7",
                        "-o", tmp_path / "s.h5", "--json"], capsys)  # fmt: skip
    assert [e["kind"] for e in json.loads(out)["written"]] == ["dense"]
    code, out, _ = run(["decode", coded_files / "c.h5", "--images", "0:0", "--png", tmp_path,
                        "--json"], capsys)  # fmt: skip
    assert [e["kind"] for e in json.loads(out)["written"]] == ["png"]


def test_training_tau_is_bounded_and_takes_counts_only(tmp_path, capsys):
    base = ["train", "synth:felt:8:0:tiny13", "-o", tmp_path / "m.h5", "--patch", "4",
            "--dicts", "1", "--iters", "1"]  # fmt: skip
    code, _, err = run([*base, "--tau-train", "999999999999"], capsys)
    assert code == 2 and err.count("\n") == 1 and "every tau must be <= 4294967295" in err
    code, _, err = run([*base, "--tau-train", "5000,4,4"], capsys)
    assert code == 2 and err.count("\n") == 1
    assert "tau_train Y = 5000 is more coefficients than a data point has " \
           "(4x4x13x13 = 2,704)" in err
    code, _, err = run([*base, "--tau-train", "0.5"], capsys)
    assert code == 2 and "a fraction needs a coded tau" in err and "such as 0.25" not in err
    assert not (tmp_path / "m.h5").exists()


def test_target_bytes_above_the_raw_size_is_refused(coded_files, tmp_path, capsys):
    d = coded_files
    code, _, err = run(["encode", d / "ref.h5", "-m", d / "model.h5", "-o", tmp_path / "x.h5",
                        "--target-bytes", "99999999999999999999999"], capsys)  # fmt: skip
    assert code == 2 and err.count("\n") == 1
    assert f"{d / 'ref.h5'}'s raw size (64,896 bytes in fp16)" in err
    assert not (tmp_path / "x.h5").exists()


def test_a_killed_export_replacement_gets_its_previous_folder_back(tmp_path):
    from sparsebtf._atomic import _host, remove_stale_parts

    old = tmp_path / f".site.{_dead_pid()}-{_host()}.ab_12.old"
    (old / "x").mkdir(parents=True)
    (old / "x" / "index.html").write_text("previous export")
    assert remove_stale_parts(tmp_path / "other") == [old]
    assert (tmp_path / "site" / "index.html").read_text() == "previous export"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["site"]


@pytest.mark.parametrize("command", ["synth", "decode"])
def test_every_btf_output_follows_its_extension(coded_files, tmp_path, capsys, command):
    import numpy as np

    from sparsebtf.formats.ubo2014 import UBO2014BTF
    from sparsebtf.open import open_btf

    argv = (["synth", "--class", "felt", "--size", "8", "--directions", "tiny13"]
            if command == "synth" else ["decode", coded_files / "c.h5"])  # fmt: skip
    code, _, err = run([*argv, "-o", tmp_path / "x.btf"], capsys)
    assert code == 0, err
    btf = open_btf(tmp_path / "x.btf")
    assert isinstance(btf, UBO2014BTF)
    code, _, err = run([*argv, "-o", tmp_path / "x.h5"], capsys)
    assert np.array_equal(btf.to_array(), open_btf(tmp_path / "x.h5").to_array())
    code, _, err = run([*argv, "-o", tmp_path / "x.png"], capsys)
    assert code == 2 and "unknown extension '.png'" in err
