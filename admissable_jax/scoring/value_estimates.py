"""Cheaper estimates of the scores a_u from the trained critic (``critic``, ``horizon``).

The paper's a_u (``rollout``, :mod:`.rollout_scores`) costs N whole episodes per set: up to
1,000 sequential physics steps a round. These two estimate instead the *discounted* value
of the deterministic policy π with u hidden, from the same N start states s_0^i that
``rollout`` uses (the same reset keys: common random numbers):

- ``critic``:  â_u = 1/N Σ_i min(Q1, Q2)(m_u(s_0^i), π(m_u(s_0^i))). One batched forward
  pass of the twin critic, no physics.
- ``horizon`` with H = ``score_horizon`` steps: run every episode H steps, then let the
  critic value the rest:

      â_u = 1/N Σ_i [ Σ_{t<H} γ^t r_t^i + γ^H · alive_H^i · min(Q1, Q2)(m_u(s_H^i), π(m_u(s_H^i))) ]

  where alive_H^i says episode i neither terminated nor reached the env's step limit within
  its first H steps (a finished episode adds nothing after its end). H = 0 is ``critic``;
  H ≥ the step limit is the discounted Monte Carlo return. A round costs H batched steps.

Both are on the discounted scale (γ = 0.99: about 100 steps' worth of reward), not the
undiscounted return a_u of the paper. The records say which estimator made a row
(``score_estimator``), and p_miss ∝ 1/(â_u − l + ε) is computed from the estimates as they
are: with l = 0 a common positive scale factor cancels in p_miss, so what differs from
``rollout``'s p_miss is how the estimates rank and space the sets, which
``benchmarks/score_estimators.py`` measures; l is read on the estimate's scale.
"""

from __future__ import annotations

from typing import Any, Callable

import chex
import jax
import jax.numpy as jnp

from admissable_jax.missingness import mask_observation
from admissable_jax.scoring.rollout_scores import MissingnessScores, PolicyFn

CriticFn = Callable[[Any, jax.Array, jax.Array], jax.Array]  # (params, masked obs (2·d,), action) -> (2,) twin Q


def estimate_scores(
    env,
    policy_fn: PolicyFn,
    policy_params: Any,
    critic_fn: CriticFn,
    critic_params: Any,
    rng: jax.Array,
    hidden_sets: jax.Array,
    n_episodes: int = 10,
    horizon: int = 0,
    gamma: float = 0.99,
) -> MissingnessScores:
    """â_u for every row of ``hidden_sets`` and the clean case (module docstring): ``critic``
    with ``horizon=0``, ``horizon`` otherwise. All (|U| + 1) · N episodes step at once.
    ``returns`` holds each episode's estimate, ``lengths`` the steps it ran (at most H).
    Jit-able with ``env``, the two functions, ``n_episodes`` and ``horizon`` static."""
    hidden_sets = jnp.asarray(hidden_sets, jnp.float32)
    num_sets, num_features = hidden_sets.shape
    chex.assert_equal(num_features, env.observation_size)
    if horizon < 0:
        raise ValueError(f"horizon must be >= 0, got {horizon}")
    num_rows = num_sets + 1
    episode_hidden = jnp.repeat(jnp.concatenate([hidden_sets, jnp.zeros((1, num_features))]), n_episodes, axis=0)
    starts = jax.vmap(env.reset)(jax.random.split(rng, n_episodes))  # as score_missingness draws them
    states = jax.tree.map(lambda x: jnp.tile(x, (num_rows,) + (1,) * (x.ndim - 1)), starts)
    policy = jax.vmap(policy_fn, in_axes=(None, 0))

    def step(carry, t):
        states, discounted, alive, length, overflow = carry
        actions = policy(policy_params, mask_observation(states.obs, episode_hidden))
        states = jax.vmap(env.step)(states, actions)
        discounted = discounted + jnp.where(alive, gamma**t * states.reward, 0.0)  # where: a dead episode may hold NaN
        length = length + alive
        alive = alive & ~states.terminated & (states.step_count < env.max_episode_steps)
        return (states, discounted, alive, length, overflow | env.capacity_exceeded(states)), None

    num_episodes = num_rows * n_episodes
    carry = (states, jnp.zeros(num_episodes), jnp.ones(num_episodes, bool), jnp.zeros(num_episodes, jnp.int32),
             jnp.zeros((), bool))
    (states, discounted, alive, length, overflow), _ = jax.lax.scan(step, carry, jnp.arange(horizon))
    masked = mask_observation(states.obs, episode_hidden)
    q = jax.vmap(critic_fn, in_axes=(None, 0, 0))(critic_params, masked, policy(policy_params, masked))
    chex.assert_shape(q, (num_episodes, 2))
    estimates = discounted + jnp.where(alive, gamma**horizon * jnp.min(q, axis=-1), 0.0)
    estimates = estimates.reshape(num_rows, n_episodes)
    means = estimates.mean(axis=1)
    return MissingnessScores(
        scores=means[:-1], clean_score=means[-1], returns=estimates, lengths=length.reshape(num_rows, n_episodes),
        loop_steps=jnp.asarray(horizon, jnp.int32), capacity_exceeded=overflow,
    )
