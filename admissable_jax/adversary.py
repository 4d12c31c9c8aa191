"""The adversary's distribution p_miss over candidate sets (paper §3, eq. for p_miss).

Every ζ env steps all u ∈ U are scored (a_u, see :mod:`admissable_jax.scoring`) and, in
adversarial mode,

    p_miss(u) = (1 / (a_u − l + ε)) / Σ_{u'} 1 / (a_{u'} − l + ε),

with a_u below the lower bound l clipped to l. In uniform mode p_miss stays uniform.
"""

from __future__ import annotations

import chex
import jax
import jax.numpy as jnp

MODES = ("adversarial", "uniform", "none")


def uniform_p_miss(num_sets: int) -> jax.Array:
    return jnp.full((num_sets,), 1.0 / num_sets, jnp.float32)


def inverse_score_p_miss(scores: jax.Array, lower_bound: float, epsilon: float) -> jax.Array:
    """p_miss ∝ 1 / (max(a_u, l) − l + ε): the paper's update, lower scores sampled more.

    Computed as 1 / (max(a_u − l, 0) + ε). The written form ``max(a_u, l) − l + ε`` is not
    safe under jit: XLA may reassociate it to ``max(a_u, l) + (ε − l)``, where ε vanishes in
    float32 for l ≠ 0, so a clipped score gave 1/0 and p_miss turned NaN.
    """
    chex.assert_rank(scores, 1)
    weights = 1.0 / (jnp.maximum(scores - lower_bound, 0.0) + epsilon)
    return weights / jnp.sum(weights)


def update_p_miss(
    p_miss: jax.Array,
    scores: jax.Array,
    adversarial: jax.Array,
    lower_bound: float,
    epsilon: float,
) -> jax.Array:
    """The next p_miss: the inverse-score update if ``adversarial`` (a traced bool, so that
    adversarial and uniform runs share one compiled program), else ``p_miss`` unchanged."""
    chex.assert_equal_shape([p_miss, scores])
    return jnp.where(adversarial, inverse_score_p_miss(scores, lower_bound, epsilon), p_miss)
