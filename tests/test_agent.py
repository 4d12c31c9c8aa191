"""The SAC objectives against hand-computed values, one gradient step against
Stable-Baselines3's, the initialisation, and the replay buffer."""

from __future__ import annotations

import functools
import os

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


SB3_STEP = os.path.join(os.path.dirname(__file__), "data", "sb3_sac_step.npz")


def _flax_params(recorded, stage: str) -> tuple[dict, dict, dict]:
    """(actor, critic, target critic) parameters in our layout from SB3's state dicts recorded
    ``before`` or ``after`` the step (torch weights are (out, in), Flax kernels (in, out))."""
    def dense(name: str) -> dict:
        return {"kernel": jnp.asarray(recorded[f"{stage}/{name}.weight"].T), "bias": jnp.asarray(recorded[f"{stage}/{name}.bias"])}

    def twins(network: str) -> dict:
        return {"params": {f"MLP_{twin}": {f"Dense_{i}": dense(f"{network}/qf{twin}.{layer}") for i, layer in enumerate((0, 2, 4))}
                           for twin in (0, 1)}}

    actor = {f"Dense_{i}": dense(f"actor/{name}") for i, name in enumerate(("latent_pi.0", "latent_pi.2", "mu", "log_std"))}
    return {"params": actor}, twins("critic"), twins("critic_target")


def test_one_gradient_step_matches_stable_baselines3():
    """Our SAC against SB3's recorded ``train()`` step (``tests/sb3_reference.py``): the same
    weights, batch and sampling noise give the same log-probabilities, deterministic action,
    critic target, losses, and parameters after the step (order of updates, α per loss, Adam,
    Polyak), within float32 rounding."""
    recorded = np.load(SB3_STEP)
    obs_size, action_size = recorded["batch/obs"].shape[1], recorded["batch/action"].shape[1]
    hidden = recorded["before/actor/latent_pi.0.weight"].shape[0]
    agent = SAC(obs_size, -jnp.ones(action_size), jnp.ones(action_size),
                SACHyperparams(batch_size=recorded["batch/obs"].shape[0], hidden_sizes=(hidden, hidden)))
    actor, critic, target_critic = _flax_params(recorded, "before")
    state = agent.init(jax.random.key(0)).replace(actor_params=actor, critic_params=critic,
                                                   target_critic_params=target_critic)
    batch = SACBatch(**{name: jnp.asarray(recorded[f"batch/{name}"])
                        for name in ("obs", "action", "reward", "next_obs", "terminated")})
    actor_noise, next_noise = jnp.asarray(recorded["noise/actor_noise"]), jnp.asarray(recorded["noise/next_noise"])
    close = functools.partial(np.testing.assert_allclose, rtol=2e-5, atol=2e-6)

    close(agent.deterministic_action(actor, batch.obs), recorded["sb3/deterministic_action"])
    action, log_prob = agent.action_from_noise(actor, batch.obs, actor_noise)
    close(action, recorded["sb3/sampled_action"])
    close(log_prob, recorded["sb3/log_prob"])
    close(agent.critic_target(state, batch, next_noise, jnp.exp(state.log_alpha)), recorded["sb3/critic_target"])

    new, metrics = jax.jit(agent.update_from_noise)(state, batch, actor_noise, next_noise)
    for ours, theirs in (("critic_loss", "critic_loss"), ("actor_loss", "actor_loss"), ("alpha_loss", "ent_coef_loss"),
                         ("alpha", "ent_coef")):
        close(metrics[ours], recorded[f"sb3/{theirs}"])
    after = _flax_params(recorded, "after")
    for ours, theirs in zip((new.actor_params, new.critic_params, new.target_critic_params), after):
        jax.tree.map(close, ours, theirs)
    close(new.log_alpha, recorded["after/log_ent_coef"][0])

    # Polyak: the target twins move τ = 0.005 of the way to the updated critics. SB3 starts
    # them equal to the critics, so that move (at most 1.5e-6 here) hides inside the
    # tolerance above: compare the move itself, to a few float32 roundings (1e-7).
    moved = lambda target: jax.tree.map(lambda a, b: np.asarray(a) - np.asarray(b), target, target_critic)
    jax.tree.map(functools.partial(np.testing.assert_allclose, rtol=0, atol=1e-7),
                 moved(new.target_critic_params), moved(after[2]))

    # Hand-computed: Adam's first step moves log α by the learning rate against the sign of
    # its gradient −mean(log π + H̄), H̄ = −|A|: up while the entropy −log π is below H̄.
    gradient = -np.mean(recorded["sb3/log_prob"] - action_size)
    np.testing.assert_allclose(float(new.log_alpha - state.log_alpha), -3e-4 * np.sign(gradient), rtol=1e-3)
    # The target H̄ = −|A| itself: at SB3's start log α = 0 the α loss is 0 whatever H̄, and
    # Adam's first step sees only its gradient's sign, so value the loss at log α = 0.5.
    _, shifted = jax.jit(agent.update_from_noise)(state.replace(log_alpha=jnp.asarray(0.5)), batch, actor_noise,
                                                  next_noise)
    close(shifted["alpha_loss"], -0.5 * np.mean(recorded["sb3/log_prob"] - action_size))


def test_layers_start_as_pytorch_linear():
    """Weights and biases ~ U(±1/√fan_in), as PyTorch's nn.Linear (SB3's initialisation)."""
    agent = SAC(40, -jnp.ones(3), jnp.ones(3), SACHyperparams(hidden_sizes=(256, 256)))
    layers = agent.init(jax.random.key(0)).critic_params["params"]["MLP_0"]
    for name, fan_in in (("Dense_0", 43), ("Dense_1", 256)):
        for array in (layers[name]["kernel"], layers[name]["bias"]):
            bound = 1 / np.sqrt(fan_in)
            assert np.abs(array).max() <= bound
            # a uniform's standard deviation is bound/√3 (Flax's LeCun normal: about √3 times that)
            np.testing.assert_allclose(np.std(array), bound / np.sqrt(3), rtol=0.15 if array.ndim == 1 else 0.02)


def test_actor_log_std_is_clamped_as_sb3_clamps_it():
    """log σ within [-20, 2] (SB3's LOG_STD_MIN, LOG_STD_MAX), however far the layer pushes it."""
    agent = SAC(6, -jnp.ones(2), jnp.ones(2), SACHyperparams(hidden_sizes=(8, 8)))
    params = agent.init(jax.random.key(0)).actor_params
    for push, clamped in ((100.0, 2.0), (-100.0, -20.0)):
        pushed = jax.tree.map(lambda x: x, params)
        pushed["params"]["Dense_3"]["bias"] = jnp.full(2, push)  # the log-σ head, after the mean's
        _, log_std = agent.actor.apply(pushed, jnp.ones((3, 6)))
        np.testing.assert_array_equal(log_std, clamped)


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
    # The rows written last, oldest first, across the wrap (what a state's fingerprint hashes of the buffer).
    np.testing.assert_array_equal(replay.latest(buffer, 4).reward, [5, 6, 7, 8])
    np.testing.assert_array_equal(replay.latest(buffer, 10).reward, [3, 4, 5, 6, 7, 8])
    drawn = replay.sample(buffer, jax.random.key(1), 2000).reward
    assert set(np.unique(drawn).tolist()) == {3.0, 4.0, 5.0, 6.0, 7.0, 8.0}
