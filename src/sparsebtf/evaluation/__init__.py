"""Evaluation against the paper's claims: benchmark set, baselines, runner and report.

``sparsebtf bench quality`` runs :func:`runner.run_quality` on a
:class:`benchmark_set.BenchConfig`; :mod:`baselines` holds the per-material PCA baseline and
its byte accounting; :mod:`report` writes the tables, plots and ``results.md``.
"""
