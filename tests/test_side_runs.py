"""docs/results.md carries the verdicts of the beyond-the-paper runs kept in folders of their
own (evaluation/side_runs.py)."""

from __future__ import annotations

import json

from sparsebtf.evaluation.side_runs import side_runs_section


def _run(folder, source, verdicts, seed=0):
    (folder / "results").mkdir(parents=True)
    run = {"config": {"name": "quick", "source": source}, "created": "2026-01-01T00:00:00Z",
           "seconds": 600.0, "seed": seed,
           "summary": {k: {"claim": f"claim {k}", "figure": f"ratio {v}", "verdict": v}
                       for k, v in verdicts.items()}}  # fmt: skip
    (folder / "results" / "results.json").write_text(json.dumps(run))


def test_side_runs_section_lists_each_runs_verdicts(tmp_path):
    assert side_runs_section(tmp_path) == []  # no side run: nothing added
    _run(tmp_path / "adaptive-patches", "synth", {"adaptive_patches": "supported"})
    _run(tmp_path / "adaptive-patches" / "capture", "capture",
         {"adaptive_patches": "no clear difference"})  # fmt: skip
    _run(tmp_path / "training-variants", "synth", {"training_multitau": "not supported"})
    (tmp_path / "broken" / "results").mkdir(parents=True)
    text = "\n".join(side_runs_section(tmp_path))
    assert "| claim adaptive_patches | ratio supported: **supported** | ratio no clear " \
           "difference: **no clear difference** |" in text
    assert "| claim training_multitau | ratio not supported: **not supported** | not run |" \
        in text
    assert "(adaptive-patches/capture/results.md)" in text
    assert "training_learntau" not in text  # a key no run carries has no row


def test_reruns_at_other_seeds_share_a_cell(tmp_path):
    _run(tmp_path / "training-variants", "synth", {"training_multitau": "supported"})
    _run(tmp_path / "training-variants" / "seed1", "synth",
         {"training_multitau": "not supported"}, seed=1)  # fmt: skip
    _run(tmp_path / "training-variants" / "capture" / "seed2", "capture",
         {"training_multitau": "no clear difference"}, seed=2)  # fmt: skip
    (tmp_path / "training-variants" / "seedling" / "results").mkdir(parents=True)
    text = "\n".join(side_runs_section(tmp_path))
    assert ("| claim training_multitau | seed 0: ratio supported: **supported**<br>seed 1: "
            "ratio not supported: **not supported** | seed 2: ratio no clear difference: **no "
            "clear difference** |") in text
    assert "(training-variants/seed1/results.md)" in text
    assert "(training-variants/capture/seed2/results.md)" in text
    assert "seedling" not in text


def test_an_unreadable_side_run_is_left_out(tmp_path):
    folder = tmp_path / "training-variants" / "results"
    folder.mkdir(parents=True)
    (folder / "results.json").write_text("{not json")
    assert side_runs_section(tmp_path) == []


def test_the_paper_crop_run_carries_table3_alone_at_100x100(tmp_path):
    from sparsebtf.evaluation.benchmark_set import CLASSES, BenchConfig

    cfg = BenchConfig.paper_crop()
    assert cfg.test_size == 100 and cfg.levels == (16, 32, 64, 128)
    assert len(cfg.test_set()) == len(CLASSES) == 7  # one material per class
    assert cfg.train_set() == BenchConfig().train_set()  # the full run's training
    assert not (cfg.table5_materials or cfg.black_materials or cfg.with_raw or cfg.render_spp)
    _run(tmp_path / "paper-crop", "synth", {"table3_rjgw19_lowest": "mostly supported",
                                            "table3_capacity": "holds"})  # fmt: skip
    text = "\n".join(side_runs_section(tmp_path))
    assert "| claim table3_capacity | ratio holds: **holds** | not run |" in text
    assert "(paper-crop/results.md)" in text


def test_bench_quality_paper_crop_flag(tmp_path, monkeypatch, capsys):
    import pytest

    import sparsebtf.evaluation.runner as runner
    from sparsebtf.cli.main import main

    seen = {}
    monkeypatch.setattr(runner, "run_quality",
                        lambda out, cfg, **kw: seen.update(cfg=cfg) or {"summary": {}})  # fmt: skip
    assert main(["bench", "quality", "--paper-crop", "--methods", "neural", "--out",
                 str(tmp_path / "q")]) == 0  # fmt: skip
    assert seen["cfg"].name == "paper-crop" and seen["cfg"].test_size == 100
    with pytest.raises(SystemExit):  # one configuration at a time
        main(["bench", "quality", "--paper-crop", "--quick", "--out", str(tmp_path / "q")])
    assert "not allowed with" in capsys.readouterr().err
