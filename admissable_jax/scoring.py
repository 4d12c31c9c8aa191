"""Adversarial scores a_u for every candidate set, in one batched rollout (paper §3).

a_u = v̂_u^π(s_0): the mean undiscounted return of N episodes of the deterministic policy
with the features in u hidden, run to termination or the env's step limit. All
(|U| + 1) · N episodes (the +1 is the clean case, nothing hidden) run as one vmapped,
jitted rollout: a ``lax.while_loop`` over time that stops once every episode is done;
finished episodes stop accumulating reward. Episode i starts from the same initial state
for every u (common random numbers), so differences between sets are not reset noise.
"""

from __future__ import annotations

from typing import Any, Callable

import chex
import jax
import jax.numpy as jnp
from flax import struct

from admissable_jax.missingness import mask_observation

PolicyFn = Callable[[Any, jax.Array], jax.Array]  # (params, masked_obs (2·d,)) -> action


@struct.dataclass
class MissingnessScores:
    """Scores of all candidate sets (rows of ``hidden_sets``) and of the clean case."""

    scores: jax.Array  # (|U|,) a_u, mean return with u hidden
    clean_score: jax.Array  # () mean return with nothing hidden
    returns: jax.Array  # (|U| + 1, N) per-episode returns; last row is the clean case
    lengths: jax.Array  # (|U| + 1, N) episode lengths

    @property
    def min_score(self) -> jax.Array:
        return jnp.min(self.scores)

    @property
    def argmin(self) -> jax.Array:
        return jnp.argmin(self.scores)


def score_missingness(
    env,
    policy_fn: PolicyFn,
    params: Any,
    rng: jax.Array,
    hidden_sets: jax.Array,
    n_episodes: int = 10,
    max_steps: int | None = None,
) -> MissingnessScores:
    """Score every u in ``hidden_sets`` ((|U|, d) 0/1 rows) and the clean case.

    ``policy_fn(params, masked_obs) -> action`` may be any JAX function of the 2·d masked
    observation (our SAC actor's mean action, or a hand-written controller). ``max_steps``
    defaults to the env's limit (1000). Jit-able with ``env``, ``policy_fn``, ``n_episodes``
    and ``max_steps`` static.
    """
    hidden_sets = jnp.asarray(hidden_sets, jnp.float32)
    num_sets, num_features = hidden_sets.shape
    chex.assert_equal(num_features, env.observation_size)
    max_steps = env.max_episode_steps if max_steps is None else max_steps
    all_sets = jnp.concatenate([hidden_sets, jnp.zeros((1, num_features))])  # + clean case
    num_rows = num_sets + 1

    initial = jax.vmap(env.reset)(jax.random.split(rng, n_episodes))
    states = jax.tree.map(lambda x: jnp.broadcast_to(x, (num_rows, *x.shape)), initial)
    states = jax.tree.map(lambda x: x.reshape(num_rows * n_episodes, *x.shape[2:]), states)
    hidden = jnp.repeat(all_sets, n_episodes, axis=0)  # row r * N + i: set r, episode i
    batch = num_rows * n_episodes
    policy = jax.vmap(policy_fn, in_axes=(None, 0))

    def cond(carry):
        t, _, alive, _, _ = carry
        return jnp.logical_and(t < max_steps, jnp.any(alive))

    def body(carry):
        t, states, alive, returns, lengths = carry
        actions = policy(params, mask_observation(states.obs, hidden))
        states = jax.vmap(env.step)(states, actions)
        returns = returns + jnp.where(alive, states.reward, 0.0)
        lengths = lengths + alive.astype(jnp.int32)
        alive = alive & ~states.terminated & (states.step_count < max_steps)
        return t + 1, states, alive, returns, lengths

    carry = (jnp.zeros((), jnp.int32), states, jnp.ones(batch, bool), jnp.zeros(batch), jnp.zeros(batch, jnp.int32))
    _, _, _, returns, lengths = jax.lax.while_loop(cond, body, carry)
    returns = returns.reshape(num_rows, n_episodes)
    lengths = lengths.reshape(num_rows, n_episodes)
    means = returns.mean(axis=1)
    return MissingnessScores(scores=means[:-1], clean_score=means[-1], returns=returns, lengths=lengths)
