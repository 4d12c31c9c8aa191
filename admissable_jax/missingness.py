"""Missing feature sets and the masked observation (paper §2, eq. for m_u, and §3).

A missing set u ⊆ {0..d-1} is stored as a 0/1 row of length d (1 = hidden), so the
candidate sets U are a (|U|, d) matrix and an environment's current set is an index into
it. The masked observation replaces hidden features by 0 and appends the indicator v with
v_i = 1[i ∈ u] (paper §3, following Skand et al. 2024): 2·d inputs.
"""

from __future__ import annotations

import itertools
import math

import chex
import jax
import jax.numpy as jnp
import numpy as np

MAX_CANDIDATE_SETS = 100_000  # more subsets than this cannot be scored in one batched rollout


def num_candidate_sets(num_features: int, k: int = 1, include_empty: bool = False) -> int:
    """|U| = C(d, k) (+ 1 with the empty set); TypeError/ValueError for a bad ``k``."""
    if not isinstance(k, int) or isinstance(k, bool):
        raise TypeError(f"k must be an int, got {type(k).__name__}")
    if not 1 <= k < num_features:
        raise ValueError(f"k must satisfy 1 <= k < d = {num_features}, got k = {k}")
    count = math.comb(num_features, k)
    if count > MAX_CANDIDATE_SETS:
        raise ValueError(
            f"C({num_features}, {k}) = {count} candidate sets exceed {MAX_CANDIDATE_SETS}"
        )
    return count + int(include_empty)


def candidate_sets(num_features: int, k: int = 1, include_empty: bool = False) -> np.ndarray:
    """U as a (|U|, d) 0/1 float32 matrix: every subset of exactly ``k`` features, in
    lexicographic order (k = 1 gives row i = {i}), optionally preceded by the empty set."""
    num_candidate_sets(num_features, k, include_empty)
    rows = [np.zeros(num_features, np.float32)] if include_empty else []
    for subset in itertools.combinations(range(num_features), k):
        row = np.zeros(num_features, np.float32)
        row[list(subset)] = 1.0
        rows.append(row)
    return np.stack(rows)


def describe_set(hidden: np.ndarray) -> str:
    """``"{3}"``, ``"{1,4}"`` or ``"{}"`` for a 0/1 row."""
    return "{" + ",".join(str(i) for i in np.flatnonzero(np.asarray(hidden))) + "}"


def mask_observation(obs: jax.Array, hidden: jax.Array) -> jax.Array:
    """m_u(s) with hidden features set to 0, concatenated with the indicator: (..., 2·d).

    ``hidden`` is the 0/1 row of u (broadcast against ``obs``); used by training, replay
    sampling, scoring and any policy wrapper.
    """
    chex.assert_equal_shape([obs, jnp.broadcast_to(hidden, obs.shape)])
    hidden = jnp.broadcast_to(hidden, obs.shape).astype(obs.dtype)
    return jnp.concatenate([obs * (1.0 - hidden), hidden], axis=-1)


def sample_set_indices(rng: jax.Array, p_miss: jax.Array, shape: tuple[int, ...]) -> jax.Array:
    """Draw set indices u ~ p_miss (one per episode start)."""
    return jax.random.choice(rng, p_miss.shape[0], shape=shape, p=p_miss).astype(jnp.int32)
