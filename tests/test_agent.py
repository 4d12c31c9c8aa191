"""The SAC objectives against hand-computed values, the update's target step, and the replay buffer."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from admissable_jax import replay
from admissable_jax import sac_losses as losses
from admissable_jax.agent import SAC, SACBatch, SACHyperparams


def test_soft_q_target_bootstraps_unless_terminated():
    target = losses.soft_q_target(
        reward=jnp.array([1.0, 2.0]), terminated=jnp.array([False, True]), next_q=jnp.array([10.0, 10.0]),
        next_log_prob=jnp.array([-1.0, -1.0]), alpha=jnp.asarray(0.5), gamma=0.9,
    )
    # 1 + 0.9 * (10 - 0.5 * -1) = 10.45; a termination keeps the reward alone.
    np.testing.assert_allclose(target, [10.45, 2.0], rtol=1e-6)


def test_critic_and_actor_losses():
    q = jnp.array([[1.0, 2.0], [3.0, 4.0]])  # (twins, batch)
    # twin 0: mean(0², 1²) = 0.5; twin 1: mean(2², 3²) = 6.5; half their sum: 3.5.
    np.testing.assert_allclose(losses.critic_loss(q, jnp.array([1.0, 1.0])), 3.5)
    # mean(0.2 * 1 - 3, 0.2 * -1 - 5) = -4.
    np.testing.assert_allclose(losses.actor_loss(jnp.asarray(0.2), jnp.array([1.0, -1.0]), jnp.array([3.0, 5.0])), -4.0, rtol=1e-6)


@pytest.mark.parametrize("log_prob, grows", [(2.0, True), (0.0, False)])
def test_entropy_coefficient_rises_while_entropy_is_below_target(log_prob, grows):
    """Target entropy -1: entropy -log π = -2 is below it (α must grow); 0 is above (α shrinks)."""
    grad_alpha, grad_log_prob = jax.grad(losses.entropy_coefficient_loss, argnums=(0, 1))(
        jnp.asarray(0.0), jnp.full((4,), log_prob), -1.0
    )
    np.testing.assert_allclose(grad_alpha, -(log_prob - 1.0))  # -mean(log π + H̄)
    assert (float(grad_alpha) < 0) == grows  # gradient descent raises log α when negative
    np.testing.assert_array_equal(grad_log_prob, 0.0)  # log π is detached


def test_update_moves_targets_by_tau_and_reports_finite_losses():
    agent = SAC(6, -jnp.ones(2), jnp.ones(2), SACHyperparams(batch_size=8, hidden_sizes=(16, 16), tau=0.25))
    state = agent.init(jax.random.key(0))
    keys = jax.random.split(jax.random.key(1), 4)
    batch = SACBatch(obs=jax.random.normal(keys[0], (8, 6)), action=jax.random.uniform(keys[1], (8, 2), minval=-1),
                     reward=jax.random.normal(keys[2], (8,)), next_obs=jax.random.normal(keys[3], (8, 6)),
                     terminated=jnp.arange(8) % 3 == 0)
    new, metrics = jax.jit(agent.update)(state, batch, jax.random.key(2))
    expected = jax.tree.map(lambda c, t: 0.25 * c + 0.75 * t, new.critic_params, state.target_critic_params)
    for got, want in zip(jax.tree.leaves(new.target_critic_params), jax.tree.leaves(expected)):
        np.testing.assert_allclose(got, want, rtol=1e-5, atol=1e-7)
    assert all(np.isfinite(float(value)) for value in metrics.values())
    np.testing.assert_allclose(metrics["alpha"], 1.0)  # α before its first step


def test_replay_buffer_wraps_around_and_samples_only_filled_rows():
    assert replay.buffer_capacity(1001, 8) == 1000 and replay.buffer_capacity(5, 8) == 8
    buffer = replay.init_buffer(6, obs_size=1, action_size=1)

    def transitions(values):
        values = jnp.asarray(values, jnp.float32)
        return replay.Transitions(obs=values[:, None], set_index=jnp.zeros(2, jnp.int32), action=values[:, None],
                                  reward=values, next_obs=values[:, None], terminated=jnp.zeros(2, bool))

    buffer = replay.insert(buffer, transitions([1, 2]))
    drawn = replay.sample(buffer, jax.random.key(0), 1000).reward
    assert set(np.unique(drawn).tolist()) == {1.0, 2.0}  # never the empty rows
    for values in ([3, 4], [5, 6], [7, 8]):  # the fourth batch overwrites the first
        buffer = replay.insert(buffer, transitions(values))
    assert int(buffer.size) == 6 and int(buffer.position) == 2
    np.testing.assert_array_equal(buffer.data.reward, [7, 8, 3, 4, 5, 6])
    drawn = replay.sample(buffer, jax.random.key(1), 2000).reward
    assert set(np.unique(drawn).tolist()) == {3.0, 4.0, 5.0, 6.0, 7.0, 8.0}
