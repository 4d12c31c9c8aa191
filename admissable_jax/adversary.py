"""The adversary's distribution p_miss over candidate sets (paper §3, eq. for p_miss).

Every ζ env steps all u ∈ U are scored (a_u, see :mod:`admissable_jax.scoring`) and, in
adversarial mode,

    p_miss(u) = (1 / (a_u − l + ε)) / Σ_{u'} 1 / (a_{u'} − l + ε),

with a_u below the lower bound l clipped to l. In uniform mode p_miss stays uniform. Mode
``worst``, the deterministic adversary the paper decides against (§3), puts p_miss on
argmin_u a_u.
"""

from __future__ import annotations

import chex
import jax
import jax.numpy as jnp

from admissable_jax.method import MODES, inverse_score_p_miss, worst_set_p_miss

__all__ = ["MODES", "inverse_score_p_miss", "uniform_p_miss", "update_p_miss"]


def uniform_p_miss(num_sets: int) -> jax.Array:
    return jnp.full((num_sets,), 1.0 / num_sets, jnp.float32)


def update_p_miss(
    p_miss: jax.Array,
    scores: jax.Array,
    adversarial: jax.Array,
    greedy: jax.Array,
    lower_bound: float,
    epsilon: float,
) -> jax.Array:
    """The next p_miss: if ``adversarial``, the inverse-score update, or with ``greedy`` too
    (mode ``worst``) all of it on the worst-scored set; else ``p_miss`` unchanged. Both flags
    are traced bools, so that runs of every mode share one compiled program."""
    chex.assert_rank(scores, 1)
    chex.assert_equal_shape([p_miss, scores])
    adversary = jnp.where(greedy, worst_set_p_miss(scores), inverse_score_p_miss(scores, lower_bound, epsilon))
    return jnp.where(adversarial, adversary, p_miss)
