"""Soft Actor-Critic (Haarnoja et al. 2018), written by hand with Stable-Baselines3's defaults.

Tanh-squashed Gaussian actor (log-std clipped to [-20, 2]), twin Q critics with Polyak
target copies, automatic entropy coefficient (target entropy -|A|), Adam for all three,
every layer initialised as PyTorch's ``nn.Linear`` (SB3's networks). The update follows
SB3's order: entropy coefficient, critics, actor, target networks, with the entropy
coefficient from before its own step used in the critic and actor losses. The objectives
themselves are in :mod:`admissable_jax.sac_losses`, beside their equations. Inputs are the
2·d masked observations; the agent never sees which env it runs in.

``tests/test_agent.py`` checks one gradient step number for number against SB3's own
(``tests/sb3_reference.py`` records it): log-probabilities, deterministic action, critic
target, the three losses and every parameter after the step.
"""

from __future__ import annotations

import dataclasses
import math
from typing import Sequence

import chex
import flax.linen as nn
import jax
import jax.numpy as jnp
import optax
from flax import struct

from admissable_jax import sac_losses as losses

LOG_STD_MIN, LOG_STD_MAX = -20.0, 2.0


@dataclasses.dataclass(frozen=True)
class SACHyperparams:
    """SB3's SAC defaults; the values the paper's experiments used."""

    learning_rate: float = 3e-4
    gamma: float = 0.99
    tau: float = 0.005
    batch_size: int = 256
    hidden_sizes: tuple[int, ...] = (256, 256)
    initial_alpha: float = 1.0


def linear(features: int, fan_in: int) -> nn.Dense:
    """A dense layer initialised as PyTorch's ``nn.Linear``, which SB3's SAC keeps: weights
    and biases ~ U(±1/√fan_in). (Flax's default, LeCun normal, spreads weights about √3
    times wider and starts biases at 0.)"""
    bound = 1.0 / math.sqrt(fan_in)

    def uniform(key: jax.Array, shape: Sequence[int], dtype=jnp.float32) -> jax.Array:
        return jax.random.uniform(key, shape, dtype, -bound, bound)

    return nn.Dense(features, kernel_init=uniform, bias_init=uniform)


class MLP(nn.Module):
    """ReLU hidden layers, then a linear output (SB3's initialisation, :func:`linear`)."""

    hidden_sizes: Sequence[int]
    out_size: int

    @nn.compact
    def __call__(self, x: jax.Array) -> jax.Array:
        for size in self.hidden_sizes:
            x = nn.relu(linear(size, x.shape[-1])(x))
        return linear(self.out_size, x.shape[-1])(x)


class Actor(nn.Module):
    """Mean and log-std of the pre-tanh Gaussian."""

    hidden_sizes: Sequence[int]
    action_size: int

    @nn.compact
    def __call__(self, obs: jax.Array) -> tuple[jax.Array, jax.Array]:
        x = obs
        for size in self.hidden_sizes:
            x = nn.relu(linear(size, x.shape[-1])(x))
        mean = linear(self.action_size, x.shape[-1])(x)
        log_std = jnp.clip(linear(self.action_size, x.shape[-1])(x), LOG_STD_MIN, LOG_STD_MAX)
        return mean, log_std


class TwinCritic(nn.Module):
    """Two independent Q(s, a) networks; returns shape (2, ...)."""

    hidden_sizes: Sequence[int]

    @nn.compact
    def __call__(self, obs: jax.Array, action: jax.Array) -> jax.Array:
        x = jnp.concatenate([obs, action], axis=-1)
        q1 = MLP(self.hidden_sizes, 1)(x)[..., 0]
        q2 = MLP(self.hidden_sizes, 1)(x)[..., 0]
        return jnp.stack([q1, q2])


@struct.dataclass
class SACState:
    """SAC's learned state: the actor, twin critics and their Polyak targets, the entropy
    temperature log α, and an Adam state for each."""

    actor_params: dict
    critic_params: dict
    target_critic_params: dict
    log_alpha: jax.Array
    actor_opt_state: optax.OptState
    critic_opt_state: optax.OptState
    alpha_opt_state: optax.OptState


@struct.dataclass
class SACBatch:
    """A minibatch as the losses see it: observations already masked with their episode's u."""

    obs: jax.Array  # (B, 2·d) masked
    action: jax.Array  # (B, A)
    reward: jax.Array  # (B,)
    next_obs: jax.Array  # (B, 2·d) masked with the same set
    terminated: jax.Array  # (B,)


class SAC:
    """Networks, optimizers and the pure functions that act and learn."""

    def __init__(self, input_size: int, action_low: jax.Array, action_high: jax.Array, hp: SACHyperparams):
        self.input_size = input_size
        self.action_size = int(action_low.shape[0])
        self.action_low = jnp.asarray(action_low, jnp.float32)
        self.action_high = jnp.asarray(action_high, jnp.float32)
        self.hp = hp
        self.actor = Actor(hp.hidden_sizes, self.action_size)
        self.critic = TwinCritic(hp.hidden_sizes)
        self.optimizer = optax.adam(hp.learning_rate)
        self.target_entropy = -float(self.action_size)

    # --- acting -------------------------------------------------------------------------
    def _scale(self, squashed: jax.Array) -> jax.Array:
        return self.action_low + (squashed + 1.0) * 0.5 * (self.action_high - self.action_low)

    def sample_action(self, actor_params, obs: jax.Array, rng: jax.Array) -> tuple[jax.Array, jax.Array]:
        """(action in the env's bounds, log π(action | obs)) for a batch of masked obs."""
        return self.action_from_noise(actor_params, obs, self._noise(rng, obs))

    def _noise(self, rng: jax.Array, obs: jax.Array) -> jax.Array:
        return jax.random.normal(rng, (*obs.shape[:-1], self.action_size))

    def action_from_noise(self, actor_params, obs: jax.Array, noise: jax.Array) -> tuple[jax.Array, jax.Array]:
        """:meth:`sample_action` with its standard-normal ``noise`` given: the
        reparameterised sample a = scale(tanh(μ + σ·noise)) and its log-probability."""
        mean, log_std = self.actor.apply(actor_params, obs)
        chex.assert_equal_shape([mean, noise])
        std = jnp.exp(log_std)
        pre_tanh = mean + std * noise
        squashed = jnp.tanh(pre_tanh)
        gaussian_log_prob = -0.5 * (((pre_tanh - mean) / std) ** 2 + 2 * log_std + jnp.log(2 * jnp.pi))
        # Change of variables through tanh (SB3's 1e-6 guard) and the affine scale.
        log_det = jnp.log(1.0 - squashed**2 + 1e-6) + jnp.log(0.5 * (self.action_high - self.action_low))
        return self._scale(squashed), jnp.sum(gaussian_log_prob - log_det, axis=-1)

    def deterministic_action(self, actor_params, obs: jax.Array) -> jax.Array:
        """The policy's mean action, squashed and scaled: what scoring evaluates."""
        mean, _ = self.actor.apply(actor_params, obs)
        return self._scale(jnp.tanh(mean))

    # --- learning -----------------------------------------------------------------------
    def init(self, rng: jax.Array) -> SACState:
        """Fresh networks (targets equal to the critics), α = ``initial_alpha``, fresh Adam states."""
        actor_rng, critic_rng = jax.random.split(rng)
        dummy_obs = jnp.zeros((1, self.input_size))
        actor_params = self.actor.init(actor_rng, dummy_obs)
        critic_params = self.critic.init(critic_rng, dummy_obs, jnp.zeros((1, self.action_size)))
        log_alpha = jnp.log(jnp.asarray(self.hp.initial_alpha, jnp.float32))
        return SACState(
            actor_params=actor_params,
            critic_params=critic_params,
            target_critic_params=jax.tree.map(jnp.copy, critic_params),
            log_alpha=log_alpha,
            actor_opt_state=self.optimizer.init(actor_params),
            critic_opt_state=self.optimizer.init(critic_params),
            alpha_opt_state=self.optimizer.init(log_alpha),
        )

    def update(self, state: SACState, batch: SACBatch, rng: jax.Array) -> tuple[SACState, dict[str, jax.Array]]:
        """One gradient step on all three losses, then the Polyak target update."""
        actor_rng, next_rng = jax.random.split(rng)
        return self.update_from_noise(state, batch, self._noise(actor_rng, batch.obs), self._noise(next_rng, batch.next_obs))

    def critic_target(self, state: SACState, batch: SACBatch, next_noise: jax.Array, alpha: jax.Array) -> jax.Array:
        """The soft Bellman target y of every transition, from the target twins at a' ~ π(· | s')."""
        next_action, next_log_prob = self.action_from_noise(state.actor_params, batch.next_obs, next_noise)
        next_q = jnp.min(self.critic.apply(state.target_critic_params, batch.next_obs, next_action), axis=0)
        return losses.soft_q_target(batch.reward, batch.terminated, next_q, next_log_prob, alpha, self.hp.gamma)

    def update_from_noise(self, state: SACState, batch: SACBatch, actor_noise: jax.Array,
                          next_noise: jax.Array) -> tuple[SACState, dict[str, jax.Array]]:
        """:meth:`update` with the policy's sampling noise given: ``actor_noise`` for a ~ π(· | s)
        (entropy coefficient and actor losses), ``next_noise`` for a' ~ π(· | s') (the target)."""
        chex.assert_rank(batch.obs, 2)
        chex.assert_equal(batch.obs.shape[-1], self.input_size)
        hp = self.hp

        # Entropy coefficient (eq. 18), then α from before its own step, as SB3.
        _, log_prob = self.action_from_noise(state.actor_params, batch.obs, actor_noise)
        alpha_loss, alpha_grad = jax.value_and_grad(losses.entropy_coefficient_loss)(
            state.log_alpha, log_prob, self.target_entropy
        )
        alpha_updates, alpha_opt_state = self.optimizer.update(alpha_grad, state.alpha_opt_state)
        log_alpha = optax.apply_updates(state.log_alpha, alpha_updates)
        alpha = jnp.exp(state.log_alpha)

        # Critics (eqs. 2-5) toward the soft Bellman target from the target twins.
        target = self.critic_target(state, batch, next_noise, alpha)

        def critic_loss_fn(params):
            q = self.critic.apply(params, batch.obs, batch.action)
            return losses.critic_loss(q, target), q

        (critic_loss, q), critic_grad = jax.value_and_grad(critic_loss_fn, has_aux=True)(state.critic_params)
        critic_updates, critic_opt_state = self.optimizer.update(critic_grad, state.critic_opt_state)
        critic_params = optax.apply_updates(state.critic_params, critic_updates)

        # Actor (eq. 7) against the freshly updated critics (SB3's order).
        def actor_loss_fn(params):
            action, log_prob = self.action_from_noise(params, batch.obs, actor_noise)
            q_pi = jnp.min(self.critic.apply(critic_params, batch.obs, action), axis=0)
            return losses.actor_loss(alpha, log_prob, q_pi), -jnp.mean(log_prob)

        (actor_loss, entropy), actor_grad = jax.value_and_grad(actor_loss_fn, has_aux=True)(state.actor_params)
        actor_updates, actor_opt_state = self.optimizer.update(actor_grad, state.actor_opt_state)
        actor_params = optax.apply_updates(state.actor_params, actor_updates)

        target_critic_params = optax.incremental_update(critic_params, state.target_critic_params, hp.tau)
        new_state = SACState(
            actor_params=actor_params,
            critic_params=critic_params,
            target_critic_params=target_critic_params,
            log_alpha=log_alpha,
            actor_opt_state=actor_opt_state,
            critic_opt_state=critic_opt_state,
            alpha_opt_state=alpha_opt_state,
        )
        metrics = {
            "critic_loss": critic_loss,
            "actor_loss": actor_loss,
            "alpha_loss": alpha_loss,
            "alpha": alpha,
            "entropy": entropy,
            "q_mean": jnp.mean(q),
        }
        return new_state, metrics
