"""The fuzz harness's names where tests and ``benchmarks/fuzz.py`` import them; the harness
itself is :mod:`sparsebtf.testing` (corpus, byte-level mutations, semantic fuzzing, the
exhaustive field fuzz)."""

from __future__ import annotations

from .testing.corpus import _btf, _coded, _directions, _legacy_copy, _model, build_corpus
from .testing.field_fuzz import (
    FIELD_KINDS,
    FIELD_MUTATIONS,
    FIELD_OUTCOMES,
    build_field_corpus,
    run_field_case,
    run_field_fuzz,
)
from .testing.mutation import READERS, exercise, mutate, run_case, sizes, write_case
from .testing.semantic import (
    SEMANTIC_KINDS,
    SEMANTIC_OUTCOMES,
    build_semantic_corpus,
    run_semantic_case,
    semantic_exercise,
    write_semantic_case,
)

__all__ = [
    "FIELD_KINDS",
    "FIELD_MUTATIONS",
    "FIELD_OUTCOMES",
    "READERS",
    "SEMANTIC_KINDS",
    "SEMANTIC_OUTCOMES",
    "_btf",
    "_coded",
    "_directions",
    "_legacy_copy",
    "_model",
    "build_corpus",
    "build_field_corpus",
    "build_semantic_corpus",
    "exercise",
    "mutate",
    "run_case",
    "run_field_case",
    "run_field_fuzz",
    "run_semantic_case",
    "semantic_exercise",
    "sizes",
    "write_case",
    "write_semantic_case",
]  # fmt: skip
