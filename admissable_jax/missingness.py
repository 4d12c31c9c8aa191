"""Missing feature sets and the masked observation on JAX (paper §2, eq. for m_u, and §3).

A missing set u ⊆ {0..d-1} is stored as a 0/1 row of length d (1 = hidden), so the
candidate sets U are a (|U|, d) matrix and an environment's current set is an index into
it (where U is too big to list, :class:`~admissable_jax.method.SetNumbering` computes the
row of an index). The masked observation replaces hidden features by 0 and appends the
indicator v with v_i = 1[i ∈ u] (paper §3, following Skand et al. 2024): 2·d inputs. The
formulas live in :mod:`admissable_jax.method` (JAX-free, shared with the Gymnasium
wrappers); this module adds what the trainer needs on the device: shape checks and u's
sampling.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

from admissable_jax import method
from admissable_jax.method import SetNumbering, candidate_sets, describe_set, num_candidate_sets

__all__ = ["SetNumbering", "candidate_sets", "describe_set", "mask_observation", "num_candidate_sets",
           "sample_distinct_sets", "sample_set_indices"]


def mask_observation(obs: jax.Array, hidden: jax.Array) -> jax.Array:
    """m_u(s) with hidden features set to 0, concatenated with the indicator: (..., 2·d)
    (:func:`admissable_jax.method.mask_observation`, shape-checked for JAX callers).

    ``hidden`` is the 0/1 row of u (broadcast against ``obs``); used by training, replay
    sampling and scoring. ValueError in one line for a ``hidden`` that does not broadcast to
    ``obs``'s shape, or holds other values than 0 and 1 (feature indices given for the row,
    which would broadcast to nonsense).
    """
    obs = jnp.asarray(obs)
    try:
        broadcast = np.broadcast_shapes(np.shape(hidden), obs.shape) == obs.shape
    except ValueError:
        broadcast = False
    if not broadcast:
        raise ValueError(f"hidden of shape {np.shape(hidden)} does not broadcast to the observations' shape {obs.shape}: "
                         f"give u's 0/1 row(s) of d = {obs.shape[-1] if obs.ndim else 0}")
    check_zero_one(hidden, "hidden")
    return method.mask_observation(obs, hidden)


def check_zero_one(rows, name: str) -> None:
    """ValueError in one line where ``rows``, sets as 0/1 rows, hold another value (feature
    indices given for a row). Checked where the values are concrete; under jit they are not
    known when this runs, and it passes."""
    try:
        values = np.asarray(rows)
    except jax.errors.TracerArrayConversionError:
        return
    if not np.isin(values, (0, 1)).all():
        raise ValueError(f"{name} must hold only 0 (seen) and 1 (hidden), got {np.unique(values)[:5].tolist()}; "
                         "admissable_jax.method.hidden_row(indices, d) makes the row of feature indices")


def sample_set_indices(rng: jax.Array, p_miss: jax.Array, shape: tuple[int, ...]) -> jax.Array:
    """Draw set indices u ~ p_miss (one per episode start)."""
    return jax.random.choice(rng, p_miss.shape[0], shape=shape, p=p_miss).astype(jnp.int32)


def sample_distinct_sets(rng: jax.Array, num_sets: int, count: int) -> jax.Array:
    """``count`` distinct set indices, a uniformly random subset of [0, ``num_sets``) in random
    order, by Floyd's algorithm: ``count`` draws, where ``jax.random.choice`` without
    replacement permutes all of U (Ant at k = 5: 96,560,646 sets, 127 s and 1.8 GiB on a
    2-core CPU). Draw i takes t uniform in [0, j], j = num_sets − count + i, or j itself where
    t is taken already."""
    draw_rng, order_rng = jax.random.split(rng)
    keys = jax.random.split(draw_rng, count)

    def draw(i, chosen):
        last = num_sets - count + i
        candidate = jax.random.randint(keys[i], (), 0, last + 1, jnp.int32)
        return chosen.at[i].set(jnp.where(jnp.any(chosen == candidate), last, candidate))

    chosen = jax.lax.fori_loop(0, count, draw, jnp.full((count,), -1, jnp.int32))
    return jax.random.permutation(order_rng, chosen)
