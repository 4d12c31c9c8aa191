"""The paper's method in array-library-neutral form: candidate sets, the masked observation
and the adversary's p_miss, for NumPy and JAX arrays alike.

JAX-free on purpose: the Gymnasium wrappers (:mod:`admissable_jax.wrappers`) run the method
with NumPy alone, and the trainer (:mod:`.missingness`, :mod:`.adversary`) runs the same
functions on JAX arrays under jit. A missing set u ⊆ {0..d-1} is a 0/1 row of length d
(1 = hidden); the candidate sets U are a (|U|, d) matrix.
"""

from __future__ import annotations

import itertools
import math

import numpy as np

MODES = ("adversarial", "uniform", "none")
MAX_CANDIDATE_SETS = 100_000  # more subsets than this cannot be scored in one batched rollout


def set_sizes(k: int, up_to_k: bool = False) -> range:
    """The sizes of the sets in U: k alone, or 1 .. k with ``up_to_k`` (the paper's
    U = {u : |u| <= k}, §2, less the empty set, which ``include_empty`` adds)."""
    return range(1 if up_to_k else k, k + 1)


def num_candidate_sets(num_features: int, k: int = 1, include_empty: bool = False, up_to_k: bool = False) -> int:
    """|U| = C(d, k), or the sum of C(d, j) for j = 1 .. k with ``up_to_k`` (+ 1 with the
    empty set); TypeError/ValueError for a bad ``k``."""
    if not isinstance(k, int) or isinstance(k, bool):
        raise TypeError(f"k must be an int, got {type(k).__name__}")
    if not 1 <= k < num_features:
        raise ValueError(f"k must satisfy 1 <= k < d = {num_features}, got k = {k}")
    count = sum(math.comb(num_features, size) for size in set_sizes(k, up_to_k))
    if count > MAX_CANDIDATE_SETS:
        sizes = f"C({num_features}, {k})" if not up_to_k else f"C({num_features}, 1) + ... + C({num_features}, {k})"
        raise ValueError(f"{sizes} = {count:,} candidate sets exceed the {MAX_CANDIDATE_SETS:,} that U may hold "
                         f"(it is kept as one (|U|, d) matrix, with pool_size too): use a smaller k")
    return count + int(include_empty)


def candidate_sets(num_features: int, k: int = 1, include_empty: bool = False, up_to_k: bool = False) -> np.ndarray:
    """U as a (|U|, d) 0/1 float32 matrix: every subset of exactly ``k`` features (of 1 to
    ``k`` with ``up_to_k``, smaller sets first), each size in lexicographic order (k = 1
    gives row i = {i}), optionally preceded by the empty set."""
    num_candidate_sets(num_features, k, include_empty, up_to_k)
    rows = [np.zeros(num_features, np.float32)] if include_empty else []
    for size in set_sizes(k, up_to_k):
        for subset in itertools.combinations(range(num_features), size):
            row = np.zeros(num_features, np.float32)
            row[list(subset)] = 1.0
            rows.append(row)
    return np.stack(rows)


def describe_set(hidden) -> str:
    """``"{3}"``, ``"{1,4}"`` or ``"{}"`` for a 0/1 row."""
    return "{" + ",".join(str(i) for i in np.flatnonzero(np.asarray(hidden))) + "}"


def parse_set(text: str) -> list[int]:
    """The feature indices of a set written by :func:`describe_set` (``"{1,4}"`` -> [1, 4])."""
    return [int(index) for index in text.strip("{}").split(",") if index]


def hidden_row(hidden, num_features: int) -> np.ndarray:
    """u's 0/1 float32 row of length d from its feature indices (ints), or from a 0/1 row
    given as floats or bools; ValueError for an index outside [0, d)."""
    hidden = np.asarray(list(hidden) if not isinstance(hidden, np.ndarray) else hidden)
    if hidden.dtype.kind in "fb" and hidden.shape == (num_features,) and np.isin(hidden, (0, 1)).all():
        return hidden.astype(np.float32)
    indices = hidden.astype(np.int64)
    if indices.size and (indices.min() < 0 or indices.max() >= num_features):
        raise ValueError(f"hidden features must be in [0, {num_features}), got {indices.tolist()}")
    row = np.zeros(num_features, np.float32)
    row[indices] = 1.0
    return row


def mask_observation(obs, hidden):
    """m_u(s): hidden features set to 0, followed by the 0/1 indicator v, v_i = 1[i ∈ u]
    (paper §3, after Skand et al. 2024): shape (..., 2·d), in ``obs``'s array library and dtype.

    ``hidden`` is u's 0/1 row, broadcast against ``obs``.
    """
    xp = obs.__array_namespace__()  # numpy or jax.numpy
    hidden = xp.broadcast_to(xp.asarray(hidden, dtype=obs.dtype), obs.shape)
    return xp.concat([obs * (1 - hidden), hidden], axis=-1)


def inverse_score_p_miss(scores, lower_bound: float, epsilon: float):
    """p_miss(u) ∝ 1 / (max(a_u, l) − l + ε) (paper §3): the sets the agent handles worst
    are drawn most.

    Computed as 1 / (max(a_u − l, 0) + ε). The written form ``max(a_u, l) − l + ε`` is not
    safe under jit: XLA may reassociate it to ``max(a_u, l) + (ε − l)``, where ε vanishes in
    float32 for l ≠ 0, so a clipped score gave 1/0 and p_miss turned NaN.
    """
    xp = scores.__array_namespace__()
    weights = 1.0 / (xp.maximum(scores - lower_bound, 0.0) + epsilon)
    return weights / xp.sum(weights)
