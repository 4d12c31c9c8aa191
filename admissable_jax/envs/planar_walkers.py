"""Hopper-v5 and Walker2d-v5 on MJX (Gymnasium ``hopper_v5.py`` / ``walker2d_v5.py``).

Both are planar walkers with the same observation (qpos[1:], qvel clipped to [-10, 10]),
reward (forward velocity of the root x + healthy bonus - 1e-3 |a|^2), uniform reset noise
of scale 5e-3 and frame skip 4; they differ in the XML and the health rule.
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING, ClassVar

import jax
import jax.numpy as jnp

from admissable_jax.envs.base import MjxEnv
from admissable_jax.envs.catalog import ENV_SPECS

if TYPE_CHECKING:
    from mujoco import mjx

_QVEL_CLIP = 10.0
_CTRL_COST_WEIGHT = 1e-3
_HEALTHY_REWARD = 1.0


def _strictly_inside(x: jax.Array, bounds: tuple[float, float]) -> jax.Array:
    low, high = bounds
    return jnp.logical_and(low < x, x < high)


class PlanarWalker(MjxEnv):
    """Shared v5 logic of Hopper and Walker2d."""

    frame_skip = 4
    reset_noise_scale = 5e-3
    reward_terms = ("reward_forward", "reward_ctrl", "reward_survive")
    info_keys = ("x_position", "z_distance_from_origin", "x_velocity")
    healthy_z_range: ClassVar[tuple[float, float]]
    healthy_angle_range: ClassVar[tuple[float, float]]

    def _observation(self, data: mjx.Data) -> jax.Array:
        return jnp.concatenate([data.qpos[1:], jnp.clip(data.qvel, -_QVEL_CLIP, _QVEL_CLIP)])

    def _is_healthy(self, qpos: jax.Array, qvel: jax.Array) -> jax.Array:
        z, angle = qpos[1], qpos[2]
        return jnp.logical_and(
            _strictly_inside(z, self.healthy_z_range),
            _strictly_inside(angle, self.healthy_angle_range),
        )

    def _reward_terms(self, before, after, action, healthy):
        x_velocity = (after.qpos[0] - before.qpos[0]) / self.dt
        terms = {
            "reward_forward": x_velocity,
            "reward_ctrl": -_CTRL_COST_WEIGHT * jnp.sum(jnp.square(action)),
            "reward_survive": healthy.astype(jnp.float32) * _HEALTHY_REWARD,
        }
        info = {
            "x_position": after.qpos[0],
            "z_distance_from_origin": after.qpos[1] - self.init_qpos[1],
            "x_velocity": x_velocity,
        }
        return terms, info

    def _reset_noise(self, rng):
        qpos_rng, qvel_rng = jax.random.split(rng)
        scale = self.reset_noise_scale
        uniform = lambda key, n: jax.random.uniform(key, (n,), minval=-scale, maxval=scale)
        return uniform(qpos_rng, self.mj_model.nq), uniform(qvel_rng, self.mj_model.nv)


class Hopper(PlanarWalker):
    """Hopper-v5: d = 11, 3 actions. Healthy also needs every qpos[2:], qvel in (-100, 100)."""

    spec = ENV_SPECS["hopper"]
    healthy_z_range = (0.7, math.inf)
    healthy_angle_range = (-0.2, 0.2)
    healthy_state_range = (-100.0, 100.0)

    def _is_healthy(self, qpos, qvel):
        state = jnp.concatenate([qpos, qvel])[2:]
        healthy_state = jnp.all(_strictly_inside(state, self.healthy_state_range))
        return jnp.logical_and(super()._is_healthy(qpos, qvel), healthy_state)


class Walker2d(PlanarWalker):
    """Walker2d-v5 (``walker2d_v5.xml``): d = 17, 6 actions."""

    spec = ENV_SPECS["walker2d"]
    healthy_z_range = (0.8, 2.0)
    healthy_angle_range = (-1.0, 1.0)
