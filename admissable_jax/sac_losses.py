"""The Soft Actor-Critic objectives, one function each, beside the equations they implement.

Equation numbers are those of Haarnoja et al. 2018, "Soft Actor-Critic Algorithms and
Applications" (arXiv:1812.05905), in the form Stable-Baselines3 computes them (twin
critics, the minimum of the target twins, a learned entropy coefficient α).
"""

from __future__ import annotations

import jax
import jax.numpy as jnp


def soft_q_target(
    reward: jax.Array, terminated: jax.Array, next_q: jax.Array, next_log_prob: jax.Array,
    alpha: jax.Array, gamma: float,
) -> jax.Array:
    """y = r + γ (1 − terminated) (min_j Q̄_j(s', a') − α log π(a' | s')), a' ~ π(· | s')
    (eqs. 2–3: the soft Bellman backup). ``next_q`` is already the minimum over the target
    twins. Only true terminations cut the bootstrap; a truncated episode bootstraps."""
    not_terminal = 1.0 - terminated.astype(jnp.float32)
    return jax.lax.stop_gradient(reward + not_terminal * gamma * (next_q - alpha * next_log_prob))


def critic_loss(q: jax.Array, target: jax.Array) -> jax.Array:
    """J_Q = Σ_j E[½ (Q_j(s, a) − y)²] over the twins (eq. 5); ``q`` is (twins, batch)."""
    return 0.5 * jnp.sum(jnp.mean((q - target) ** 2, axis=-1))


def actor_loss(alpha: jax.Array, log_prob: jax.Array, q: jax.Array) -> jax.Array:
    """J_π = E[α log π(a | s) − min_j Q_j(s, a)], a ~ π(· | s) reparameterised (eq. 7)."""
    return jnp.mean(alpha * log_prob - q)


def entropy_coefficient_loss(log_alpha: jax.Array, log_prob: jax.Array, target_entropy: float) -> jax.Array:
    """J(α) = E[−log α · (log π(a | s) + H̄)] with log π detached (eq. 18, in SB3's
    log-α form): α grows while the policy's entropy −log π is below the target H̄."""
    return -jnp.mean(log_alpha * jax.lax.stop_gradient(log_prob + target_entropy))
