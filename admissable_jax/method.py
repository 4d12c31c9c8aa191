"""The paper's method in array-library-neutral form: candidate sets, the masked observation
and the adversary's p_miss, for NumPy and JAX arrays alike.

JAX-free on purpose: the Gymnasium wrappers (:mod:`admissable_jax.wrappers`) run the method
with NumPy alone, and the trainer (:mod:`.missingness`, :mod:`.adversary`) runs the same
functions on JAX arrays under jit. A missing set u ⊆ {0..d-1} is a 0/1 row of length d
(1 = hidden); the candidate sets U are a (|U|, d) matrix, or where too many to list, an
index :class:`SetNumbering` turns into a row and back.
"""

from __future__ import annotations

import dataclasses
import functools
import math
import numbers

import numpy as np

MODES = ("adversarial", "uniform", "none", "worst")
DRAWING_MODES = ("adversarial", "uniform", "worst")  # the modes that hide a drawn u in training (not "none")
MAX_CANDIDATE_SETS = 100_000  # more sets than this cannot be scored in one batched rollout, nor kept as one matrix
MAX_SET_INDEX = 2**31 - 1  # a set's index into U is an int32


def set_sizes(k: int, up_to_k: bool = False) -> range:
    """The sizes of the sets in U: k alone, or 1 .. k with ``up_to_k`` (the paper's
    U = {u : |u| <= k}, §2, less the empty set, which ``include_empty`` adds)."""
    return range(1 if up_to_k else k, k + 1)


def _sizes_text(num_features: int, k: int, up_to_k: bool) -> str:
    return f"C({num_features}, {k})" if not up_to_k else f"C({num_features}, 1) + ... + C({num_features}, {k})"


def num_candidate_sets(num_features: int, k: int = 1, include_empty: bool = False, up_to_k: bool = False) -> int:
    """|U| = C(d, k), or the sum of C(d, j) for j = 1 .. k with ``up_to_k`` (+ 1 with the
    empty set); TypeError/ValueError for a bad ``k`` or a U too big for int32 indices."""
    if not isinstance(num_features, numbers.Integral) or isinstance(num_features, bool):
        raise TypeError(f"num_features (d) must be an int, got {type(num_features).__name__}")
    if not isinstance(k, int) or isinstance(k, bool):
        raise TypeError(f"k must be an int, got {type(k).__name__}")
    if not 1 <= k < num_features:
        raise ValueError(f"k must satisfy 1 <= k < d = {num_features}, got k = {k}")
    count = sum(math.comb(num_features, size) for size in set_sizes(k, up_to_k)) + int(include_empty)
    if count > MAX_SET_INDEX:
        raise ValueError(f"{_sizes_text(num_features, k, up_to_k)} = {count:,} candidate sets exceed the "
                         f"{MAX_SET_INDEX:,} that an int32 set index numbers: use a smaller k")
    return count


def check_exact_size(num_features: int, k: int = 1, include_empty: bool = False, up_to_k: bool = False,
                     remedy: str = "use a smaller k") -> int:
    """|U| where one batched rollout can score every set and one (|U|, d) matrix hold them,
    at most :data:`MAX_CANDIDATE_SETS`; ValueError in one line, ending in ``remedy``, beyond."""
    count = num_candidate_sets(num_features, k, include_empty, up_to_k)
    if count > MAX_CANDIDATE_SETS:
        raise ValueError(f"{_sizes_text(num_features, k, up_to_k)} = {count:,} candidate sets exceed the "
                         f"{MAX_CANDIDATE_SETS:,} that one batched rollout scores and one (|U|, d) matrix holds: "
                         f"{remedy}")
    return count


@dataclasses.dataclass(frozen=True)
class SetNumbering:
    """U's order as arithmetic: the 0/1 row of the set with a given index into U, and the
    index of a given set, for NumPy and JAX arrays (under jit too), so that a U of any size
    is numbered without listing it (a pool over Ant's C(105, 3) = 187,460 triples).

    The order: the empty set first (``include_empty``), then the sets of each size of
    :func:`set_sizes`, smaller first, each size in lexicographic order of the sorted
    features (k = 1: index i = {i}). Within a size r, the set e_0 < ... < e_{r-1} of d
    features has the rank C(d, r) − 1 − Σ_j C(d − 1 − e_j, r − j) (the combinatorial
    number system), which :meth:`rows` inverts greedily. Up to
    :data:`MAX_CANDIDATE_SETS` sets, :meth:`rows` gathers from the listed matrix instead (one
    gather per lookup, where the arithmetic costs a few small ops per feature of u).
    """

    num_features: int
    k: int = 1
    include_empty: bool = False
    up_to_k: bool = False
    count: int = dataclasses.field(init=False)  # |U|, counted (and k checked) at construction

    def __post_init__(self):
        object.__setattr__(self, "count", num_candidate_sets(self.num_features, self.k, self.include_empty,
                                                             self.up_to_k))

    @property
    def listed(self) -> bool:
        """Whether U is small enough to list: at most :data:`MAX_CANDIDATE_SETS` sets."""
        return self.count <= MAX_CANDIDATE_SETS

    @functools.cached_property
    def _blocks(self) -> tuple[np.ndarray, np.ndarray]:
        """(size of each block of U, its first index): the empty set's block, then each size's."""
        sizes = ([0] if self.include_empty else []) + list(set_sizes(self.k, self.up_to_k))
        counts = [math.comb(self.num_features, size) for size in sizes]
        return np.array(sizes, np.int32), np.cumsum([0] + counts[:-1]).astype(np.int32)

    @functools.cached_property
    def _binomials(self) -> np.ndarray:
        """(k + 1, d + 1) int32 table of C(n, m) at [m, n], capped at int32's largest (a
        capped entry exceeds every rank of U, so no lookup reads one)."""
        d = self.num_features
        return np.array([[min(math.comb(n, m), MAX_SET_INDEX) for n in range(d + 1)] for m in range(self.k + 1)],
                        np.int32)

    @functools.cached_property
    def matrix(self) -> np.ndarray:
        """U as a (|U|, d) 0/1 float32 matrix, in U's order; ValueError beyond
        :data:`MAX_CANDIDATE_SETS` sets."""
        check_exact_size(self.num_features, self.k, self.include_empty, self.up_to_k)
        return self._computed_rows(np.arange(self.count, dtype=np.int32))

    def rows(self, indices):
        """The 0/1 float32 rows (..., d) of the sets at ``indices`` (ints in [0, |U|)), in
        ``indices``' array library."""
        xp = indices.__array_namespace__()
        if self.listed:
            return xp.asarray(self.matrix)[indices]
        return self._computed_rows(indices)

    def _computed_rows(self, indices):
        """:meth:`rows` by the greedy inverse of the rank (class docstring), feature by feature
        of u from the lowest: the co-rank's largest C(n, m) ≤ it names feature d − 1 − n."""
        xp = indices.__array_namespace__()
        d = self.num_features
        sizes, starts = (xp.asarray(table) for table in self._blocks)
        binomials = xp.asarray(self._binomials)
        indices = xp.astype(indices, xp.int32)
        block = xp.sum(xp.astype(indices[..., None] >= starts, xp.int32), axis=-1) - 1
        size = xp.take(sizes, block)
        co_rank = xp.take(binomials[:, d], size) - 1 - (indices - xp.take(starts, block))
        n = xp.arange(d, dtype=xp.int32)
        rows = xp.zeros(indices.shape + (d,), dtype=xp.float32)
        for position in range(self.k):
            still = size - position  # features of u left to find, this one included
            table = xp.take(binomials[:, :d], xp.clip(still, 1, self.k), axis=0)  # (..., d): C(n, still)
            largest = xp.sum(xp.astype(table <= co_rank[..., None], xp.int32), axis=-1) - 1
            found = n == largest[..., None]
            active = still >= 1
            co_rank = co_rank - xp.where(active, xp.sum(xp.where(found, table, 0), axis=-1), 0)
            rows = rows + xp.astype(active[..., None] & (n == d - 1 - largest[..., None]), xp.float32)
        return rows

    def indices(self, rows):
        """The int32 indices into U of the sets with 0/1 ``rows`` (..., d), each one a set of U,
        in ``rows``' array library: the rank of the class docstring plus its size's first index."""
        xp = rows.__array_namespace__()
        d = self.num_features
        sizes, starts = self._blocks
        first_of_size = np.zeros(self.k + 1, np.int32)
        first_of_size[sizes] = starts
        hidden = xp.astype(rows > 0.5, xp.int32)
        size = xp.sum(hidden, axis=-1)
        before = xp.cumulative_sum(hidden, axis=-1) - hidden  # hidden features before each one (no integer matmul)
        still = xp.clip(size[..., None] - before, 0, self.k)
        flat = xp.reshape(xp.asarray(self._binomials), (-1,))
        terms = xp.take(flat, still * (d + 1) + xp.asarray(np.arange(d - 1, -1, -1, dtype=np.int32)))
        rank = xp.take(xp.asarray(self._binomials[:, d]), size) - 1 - xp.sum(hidden * terms, axis=-1)
        return xp.take(xp.asarray(first_of_size), size) + rank


def candidate_sets(num_features: int, k: int = 1, include_empty: bool = False, up_to_k: bool = False) -> np.ndarray:
    """U as a (|U|, d) 0/1 float32 matrix: every subset of exactly ``k`` features (of 1 to
    ``k`` with ``up_to_k``, smaller sets first), each size in lexicographic order (k = 1
    gives row i = {i}), optionally preceded by the empty set (:class:`SetNumbering`'s order);
    ValueError beyond :data:`MAX_CANDIDATE_SETS` sets."""
    return SetNumbering(num_features, k, include_empty, up_to_k).matrix


def describe_set(hidden) -> str:
    """``"{3}"``, ``"{1,4}"`` or ``"{}"`` for a 0/1 row."""
    return "{" + ",".join(str(i) for i in np.flatnonzero(np.asarray(hidden))) + "}"


def parse_set(text: str) -> list[int]:
    """The feature indices of a set written by :func:`describe_set` (``"{1,4}"`` -> [1, 4])."""
    return [int(index) for index in text.strip("{}").split(",") if index]


def hidden_row(hidden, num_features: int) -> np.ndarray:
    """u's 0/1 float32 row of length d from its feature indices (ints; one int is one
    feature), or from a 0/1 row given as floats or bools; ValueError for an index outside
    [0, d), not whole or given twice (a 0/1 row of the wrong length reads so, and is no set
    of indices), or for a bool row not of length d; TypeError for a string (its characters
    are no indices)."""
    if isinstance(hidden, str):
        raise TypeError(f"hidden must be feature indices or a 0/1 row, got the string {hidden!r}")
    if isinstance(hidden, (int, np.integer)):
        hidden = [hidden]
    hidden = np.asarray(list(hidden) if not isinstance(hidden, np.ndarray) else hidden)
    if hidden.dtype.kind in "fb" and hidden.shape == (num_features,) and np.isin(hidden, (0, 1)).all():
        return hidden.astype(np.float32)
    if hidden.dtype.kind == "b":
        raise ValueError(f"a 0/1 row of hidden features needs d = {num_features} entries, got shape {hidden.shape}")
    indices = hidden.astype(np.int64)
    if not np.array_equal(indices, hidden):
        raise ValueError(f"hidden features must be whole indices, got {hidden.tolist()}")
    if indices.size and (indices.min() < 0 or indices.max() >= num_features):
        raise ValueError(f"hidden features must be in [0, {num_features}), got {indices.tolist()}")
    if len(np.unique(indices)) < indices.size:
        raise ValueError(f"hidden features are given twice in {indices.tolist()}: give each index once, "
                         f"or a 0/1 row of d = {num_features} entries")
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


def check_fail_at(fail_at, max_steps: int | None = None, name: str = "fail_at") -> int:
    """``fail_at`` as an int: the env step of each episode at which the sensors of u fail
    (:func:`hidden_from_step`); ValueError in one line (naming the setting ``name``) for one
    below 0, not whole, or at or past ``max_steps`` (the episodes' step limit, where known),
    where nothing would fail."""
    if not isinstance(fail_at, numbers.Integral) or isinstance(fail_at, bool) or fail_at < 0:
        raise ValueError(f"{name} must be an env step >= 0 (0: hidden from the start), got {fail_at!r}")
    if max_steps is not None and fail_at >= max_steps:
        raise ValueError(f"{name}={fail_at} is not below the episodes' {max_steps} steps: nothing would fail")
    return int(fail_at)


def fail_steps(fail_at, max_steps: int | None = None, name: str = "fail_at") -> tuple[int, ...]:
    """The env steps ``fail_at`` names, smallest first and each once: one step (an int), a
    comma list (``"0,50,100"``) or a sequence of ints; ValueError in one line for an empty
    list or a step :func:`check_fail_at` refuses."""
    if isinstance(fail_at, str):
        try:
            steps = [int(part) for part in fail_at.split(",") if part.strip()]
        except ValueError:
            steps = []
        if not steps:
            raise ValueError(f"{name} must be an env step or a comma list of them, e.g. 0,50,100; got {fail_at!r}")
    else:
        steps = list(fail_at) if isinstance(fail_at, (list, tuple, np.ndarray)) else [fail_at]
    if not steps:
        raise ValueError(f"{name} must name at least one env step")
    return tuple(sorted({check_fail_at(step, max_steps, name) for step in steps}))


def spread_fail_steps(fail_at, n_episodes: int, max_steps: int | None = None,
                      names: tuple[str, str] = ("fail_at", "n_episodes")) -> tuple[int, ...]:
    """The failure step of each of a set's ``n_episodes`` scoring episodes when its sensors
    fail at the m env steps ``fail_at`` names (:func:`fail_steps`): episode i at the (i mod
    m)-th, so each step scores N/m episodes from the same start states for every set, and
    a_u is the mean over the steps of each step's a_u. ValueError in one line (naming the
    settings ``names``) where m does not divide N: the steps would weigh unevenly."""
    steps = fail_steps(fail_at, max_steps, names[0])
    if n_episodes % len(steps):
        raise ValueError(f"{names[0]}={','.join(map(str, steps))} splits each set's {names[1]}={n_episodes} episodes "
                         f"unevenly: give {names[1]} a multiple of {len(steps)}")
    return tuple(steps[i % len(steps)] for i in range(n_episodes))


def hidden_from_step(hidden, steps_taken, fail_at):
    """u's 0/1 rows as each episode sees them after ``steps_taken`` env steps, when the sensors
    of u fail at env step ``fail_at``: nothing hidden before it, u from it on (the observation
    after ``fail_at`` steps is the first without them). ``fail_at`` = 0 is the paper's u, hidden
    for the whole episode (§3). ``hidden`` (n, d), ``steps_taken`` (n,), ``fail_at`` one step
    or each episode's (n,); NumPy or JAX."""
    xp = hidden.__array_namespace__()
    return hidden * xp.astype(steps_taken >= fail_at, hidden.dtype)[..., None]


def check_masked_batch(masked_obs: np.ndarray, num_features: int) -> None:
    """ValueError in one line unless ``masked_obs`` is a batch of masked observations (n, 2·d),
    as a policy's ``masked`` takes them (an unmasked batch would fail deep in the network)."""
    if np.ndim(masked_obs) != 2 or np.shape(masked_obs)[1] != 2 * num_features:
        raise ValueError(f"expected a batch of masked observations (n, 2·d = {2 * num_features}), "
                         f"got shape {np.shape(masked_obs)}")


def act_with_hidden(masked_policy, obs, hidden, num_features: int) -> np.ndarray:
    """``masked_policy`` (a batch (n, 2·d) of masked observations -> actions (n, A)) on
    Gymnasium observations, (d,) or (n, d), with u (feature indices or a 0/1 row) hidden:
    the action(s) in ``obs``'s leading shape. ValueError for observations of another d."""
    obs = np.asarray(obs, np.float32)
    if obs.shape[-1:] != (num_features,):
        masked = (f"; a masked observation ({2 * num_features}: features, then the indicator) goes to the policy's "
                  ".masked(batch)" if obs.shape[-1:] == (2 * num_features,) else "")
        raise ValueError(f"expected observations of {num_features} features, got shape {obs.shape}{masked}")
    batch = obs.reshape(-1, num_features)
    actions = np.asarray(masked_policy(mask_observation(batch, hidden_row(hidden, num_features))))
    return actions.reshape(*obs.shape[:-1], -1)


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


def worst_set_p_miss(scores):
    """p_miss of mode ``worst``: every episode hides argmin_u a_u, the deterministic
    adversary that the paper decides against "to avoid training instabilities and
    forgetting" (§3), so that the claim can be tested. Sets tied for the lowest score share
    p_miss evenly; l and ε play no part."""
    xp = scores.__array_namespace__()
    worst = xp.astype(scores == xp.min(scores), scores.dtype)
    return worst / xp.sum(worst)
