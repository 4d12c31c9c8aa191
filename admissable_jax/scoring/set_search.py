"""Searching for the worst sets of k hidden features where C(d, k) is too many to score.

Beam search of width b (greedy at b = 1): level 1 scores every single feature; each later
level extends each of the b sets kept so far by every feature not yet in it, scores all
the extensions in one batch, and keeps the b lowest. After k levels it has scored at most
d + (k − 1) · b · d sets instead of C(d, k). Any scorer ranks the candidates: the paper's
rollout, or a cheaper estimate (``admissable_jax.scoring``), whose finalists a rollout can
then confirm.
"""

from __future__ import annotations

from typing import Callable

import numpy as np

SetScorer = Callable[[np.ndarray], np.ndarray]  # (m, d) 0/1 rows -> (m,) scores; lower hurts more


def beam_search_worst_sets(score_sets: SetScorer, num_features: int, k: int, beam_width: int = 1
                           ) -> list[tuple[tuple[int, ...], float]]:
    """The ``beam_width`` sets of ``k`` features that ``score_sets`` found worst, lowest
    first, each with its score. Raises ValueError unless 1 <= k <= num_features."""
    if not 1 <= k <= num_features or beam_width < 1:
        raise ValueError(f"need 1 <= k <= d = {num_features} and beam_width >= 1, got k={k}, beam_width={beam_width}")
    kept: list[tuple[int, ...]] = [()]
    scores = np.zeros(1)
    for _ in range(k):
        candidates = sorted({tuple(sorted((*kept_set, feature))) for kept_set in kept
                             for feature in range(num_features) if feature not in kept_set})
        rows = np.zeros((len(candidates), num_features), np.float32)
        for row, candidate in zip(rows, candidates):
            row[list(candidate)] = 1.0
        scores = np.asarray(score_sets(rows), np.float64)
        if scores.shape != (len(candidates),):
            raise ValueError(f"score_sets returned shape {scores.shape} for {len(candidates)} sets")
        order = np.argsort(scores, kind="stable")[:beam_width]
        kept, scores = [candidates[i] for i in order], scores[order]
    return [(hidden, float(score)) for hidden, score in zip(kept, scores)]
