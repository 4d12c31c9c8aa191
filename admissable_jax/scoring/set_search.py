"""Searching for the worst sets of k hidden features where C(d, k) is too many to score.

Beam search of width b (greedy at b = 1): level 1 ranks every single feature; each later
level extends each of the b sets kept so far by every feature not yet in it, ranks all the
distinct extensions in one batch, and keeps the b lowest. After k levels it has ranked at
most d + (k − 1) · b · d sets instead of C(d, k). With ``up_to_k`` (U holds the sets of
1 .. k features, the paper's |u| <= k) the finalists are the b lowest of all levels, so a
single feature can beat every pair; the beam each level extends is the same. Any scorer
ranks the candidates: the paper's rollout, or a cheaper estimate
(``admissable_jax.scoring``), whose finalists a rollout can then confirm.

Every level hands the scorer the same number of rows, b · d (each kept set with each
feature added; rows that repeat a set, or extend a set by a feature it holds, or extend an
empty beam slot, are scored too but never kept), so the search is one fixed-shape program:
it runs under ``jit`` (the trainer's candidate pool, :mod:`admissable_jax.training`) and
eagerly with one compiled scorer (the audit).
"""

from __future__ import annotations

from typing import Callable

import jax
import jax.numpy as jnp
from flax import struct

SetScorer = Callable[[jax.Array], jax.Array]  # (m, d) 0/1 rows -> (m,) scores; lower hurts more


@struct.dataclass
class SearchResult:
    """The sets a beam search kept, lowest score first."""

    rows: jax.Array  # (b, d) 0/1 rows of the sets kept: of k features (of 1 .. k with up_to_k)
    scores: jax.Array  # (b,) the scorer's scores; inf where not ``found``
    found: jax.Array  # (b,) bool: False only where fewer than b distinct sets exist
    num_ranked: jax.Array  # () distinct sets the scorer ranked over all levels


@jax.jit
def first_copies(rows: jax.Array, among: jax.Array) -> jax.Array:
    """``among`` (m,) where no earlier row of ``among`` is the same set as this (m, d) 0/1 row:
    the rows sorted by their features packed 32 to a word (the ``among`` rows first, equal
    sets in row order), each compared with the one before it. O(m log m) in time and O(m)
    in memory, where comparing every pair of rows held (m, m) matrices (Ant at b = d: 11,025
    rows; a pool's scoring program held 0.75 GiB of temporaries with them, 0.54 without)."""
    m, d = rows.shape
    words = -(-d // 32)
    bits = jnp.pad(rows > 0.5, ((0, 0), (0, 32 * words - d))).reshape(m, words, 32).astype(jnp.uint32)
    packed = jnp.sum(bits << jnp.arange(32, dtype=jnp.uint32), axis=-1, dtype=jnp.uint32)  # distinct bits: an OR
    *keys, row_of = jax.lax.sort((jnp.where(among, 0, 1).astype(jnp.uint32), *packed.T, jnp.arange(m)),
                                 num_keys=words + 2)
    keys = jnp.stack(keys, axis=1)
    first = jnp.concatenate([jnp.ones(1, bool), jnp.any(keys[1:] != keys[:-1], axis=1)])
    return among & jnp.zeros(m, bool).at[row_of].set(first)


def beam_search_worst_sets(score_sets: SetScorer, num_features: int, k: int, beam_width: int = 1,
                           up_to_k: bool = False) -> SearchResult:
    """The ``beam_width`` sets of ``k`` features (of 1 .. k with ``up_to_k``) that
    ``score_sets`` finds worst (module docstring). ``score_sets`` maps (b · d, d) rows to
    (b · d,) scores and may be traced; the other arguments are static. Raises ValueError unless
    1 <= k <= num_features and beam_width >= 1."""
    if not 1 <= k <= num_features or beam_width < 1:
        raise ValueError(f"need 1 <= k <= d = {num_features} and beam_width >= 1, got k={k}, beam_width={beam_width}")
    d, b = num_features, beam_width
    kept = jnp.zeros((b, d), jnp.float32)  # the beam that the next level extends
    kept_found = jnp.arange(b) == 0  # level 0 keeps one set: the empty one
    final_rows, final_scores, final_found = jnp.zeros((0, d), jnp.float32), jnp.zeros((0,)), jnp.zeros((0,), bool)
    num_ranked = jnp.zeros((), jnp.int32)
    for size in range(1, k + 1):
        candidates = jnp.maximum(kept[:, None, :], jnp.eye(d)[None]).reshape(b * d, d)  # kept set i plus feature f
        new = (kept_found[:, None] & (kept == 0)).reshape(b * d)  # a set of ``size`` features
        new = first_copies(candidates, new)
        scores = jnp.where(new, score_sets(candidates), jnp.inf)
        num_ranked = num_ranked + new.sum()
        order = jnp.argsort(scores, stable=True)[:b]
        kept, kept_found = candidates[order], new[order]
        if up_to_k or size == k:  # the answer: the b lowest of this level's sets (and the smaller sets' finalists)
            final_rows, final_scores, final_found = (jnp.concatenate(pair) for pair in (
                (final_rows, candidates), (final_scores, scores), (final_found, new)))
            lowest = jnp.argsort(final_scores, stable=True)[:b]
            final_rows, final_scores, final_found = final_rows[lowest], final_scores[lowest], final_found[lowest]
    return SearchResult(rows=final_rows, scores=final_scores, found=final_found, num_ranked=num_ranked)
