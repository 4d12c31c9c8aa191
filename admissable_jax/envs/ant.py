"""Ant-v5 on MJX (Gymnasium ``ant_v5.py``), default arguments.

Observation (105): qpos[2:] (13), qvel (14), and the external contact forces
``cfrc_ext[1:]`` clipped to [-1, 1] (13 bodies x 6 = 78). Contact forces need
``mj_rnePostConstraint`` after the step, as Gymnasium calls it.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import jax
import jax.numpy as jnp

from admissable_jax.envs.base import MjxEnv, uniform_qpos_normal_qvel_noise
from admissable_jax.envs.catalog import ENV_SPECS

if TYPE_CHECKING:
    from mujoco import mjx

_MAIN_BODY = 1  # torso
_CTRL_COST_WEIGHT = 0.5
_CONTACT_COST_WEIGHT = 5e-4
_CONTACT_FORCE_RANGE = (-1.0, 1.0)
_HEALTHY_Z_RANGE = (0.2, 1.0)
_HEALTHY_REWARD = 1.0


def _clipped_contact_forces(data: mjx.Data) -> jax.Array:
    return jnp.clip(data._impl.cfrc_ext, *_CONTACT_FORCE_RANGE)


class Ant(MjxEnv):
    """Ant-v5: d = 105, 8 actions, frame skip 5."""

    spec = ENV_SPECS["ant"]
    frame_skip = 5
    reset_noise_scale = 0.1
    reads_contact_forces = True
    reward_terms = ("reward_forward", "reward_ctrl", "reward_contact", "reward_survive")
    info_keys = ("x_position", "y_position", "distance_from_origin", "x_velocity", "y_velocity")

    def _observation(self, data: mjx.Data) -> jax.Array:
        contact_forces = _clipped_contact_forces(data)[1:].ravel()
        return jnp.concatenate([data.qpos[2:], data.qvel, contact_forces])

    def _is_healthy(self, qpos: jax.Array, qvel: jax.Array) -> jax.Array:
        finite = jnp.logical_and(jnp.all(jnp.isfinite(qpos)), jnp.all(jnp.isfinite(qvel)))
        low, high = _HEALTHY_Z_RANGE
        return finite & (low <= qpos[2]) & (qpos[2] <= high)

    def _reward_terms(self, before, after, action, healthy):
        # Gymnasium reads the torso's xpos, which mj_step leaves at the kinematics computed
        # before the last substep's integration; MJX's step does the same.
        xy_velocity = (after.xpos[_MAIN_BODY, :2] - before.xpos[_MAIN_BODY, :2]) / self.dt
        terms = {
            "reward_forward": xy_velocity[0],
            "reward_ctrl": -_CTRL_COST_WEIGHT * jnp.sum(jnp.square(action)),
            "reward_contact": -_CONTACT_COST_WEIGHT
            * jnp.sum(jnp.square(_clipped_contact_forces(after))),
            "reward_survive": healthy.astype(jnp.float32) * _HEALTHY_REWARD,
        }
        info = {
            "x_position": after.qpos[0],
            "y_position": after.qpos[1],
            "distance_from_origin": jnp.linalg.norm(after.qpos[:2]),
            "x_velocity": xy_velocity[0],
            "y_velocity": xy_velocity[1],
        }
        return terms, info

    def _reset_noise(self, rng):
        return uniform_qpos_normal_qvel_noise(rng, self.mj_model, self.reset_noise_scale)
