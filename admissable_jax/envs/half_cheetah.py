"""HalfCheetah-v5 on MJX (Gymnasium ``half_cheetah_v5.py``), default arguments.

Beyond the paper's three envs: the one of Gymnasium's standard MuJoCo locomotion tasks that
never terminates, so every episode (and every scoring episode) runs its 1,000 steps.
Observation (17): qpos[1:] (8) and qvel (9), unclipped. Reward: forward velocity of the
root x − 0.1 |a|²; no health rule, no survive bonus. Frame skip 5; reset noise
qpos + U(−0.1, 0.1), qvel + 0.1 · N(0, 1).
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import jax
import jax.numpy as jnp

from admissable_jax.envs.base import MjxEnv, uniform_qpos_normal_qvel_noise
from admissable_jax.envs.catalog import ENV_SPECS

if TYPE_CHECKING:
    from mujoco import mjx

_CTRL_COST_WEIGHT = 0.1


class HalfCheetah(MjxEnv):
    """HalfCheetah-v5: d = 17, 6 actions, frame skip 5, never terminates."""

    spec = ENV_SPECS["halfcheetah"]
    frame_skip = 5
    reset_noise_scale = 0.1
    reward_terms = ("reward_forward", "reward_ctrl")
    info_keys = ("x_position", "x_velocity")

    def _observation(self, data: mjx.Data) -> jax.Array:
        return jnp.concatenate([data.qpos[1:], data.qvel])

    def _is_healthy(self, qpos: jax.Array, qvel: jax.Array) -> jax.Array:
        return jnp.ones((), bool)  # HalfCheetah-v5 has no termination

    def _reward_terms(self, before, after, action, healthy):
        x_velocity = (after.qpos[0] - before.qpos[0]) / self.dt
        terms = {
            "reward_forward": x_velocity,
            "reward_ctrl": -_CTRL_COST_WEIGHT * jnp.sum(jnp.square(action)),
        }
        return terms, {"x_position": after.qpos[0], "x_velocity": x_velocity}

    def _reset_noise(self, rng):
        return uniform_qpos_normal_qvel_noise(rng, self.mj_model, self.reset_noise_scale)
