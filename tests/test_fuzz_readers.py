"""Every reader command over a seeded fuzz corpus (tests/fuzz_corpus.py): no traceback, no hang,
and exit status 2 with one error line for every input that is invalid.

The default suite runs the small corpus (a sample of the run-file mutations through
inspect/analyze/monitor, every CSV/.npy/config case); ``-m slow`` runs the large one
(every mutation through every reader, more truncations and bit flips, ROS bags).
The time limit per run only tells a hang from a slow run: it is far above any normal run.
"""

from __future__ import annotations

import pytest
from fuzz_corpus import build_corpus, run_cases

LIMIT_S = 300.0


def _check(tmp_path_factory, seed: int, size: str) -> None:
    cases = build_corpus(tmp_path_factory.mktemp(f"fuzz-{size}-{seed}"), seed, size)
    failures = run_cases(cases, LIMIT_S)
    assert not failures, "\n".join(f"{c.name}: {why}" for c, why in failures)


def test_small_corpus(tmp_path_factory):
    _check(tmp_path_factory, 1, "small")


@pytest.mark.slow
@pytest.mark.parametrize("seed", [1, 2])
def test_large_corpus(tmp_path_factory, seed):
    _check(tmp_path_factory, seed, "large")
