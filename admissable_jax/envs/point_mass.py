"""A 2-D point mass in pure JAX: a seconds-to-compile task for tests and smoke runs.

Not a paper environment. Observation (d = 4): position (x, y) and velocity; actions: a
force in [-1, 1]^2; reward exp(-|p|^2) per step (in (0, 1], so returns are positive as the
paper's l = 0 assumes); the episode terminates when |p| > 3. A policy must see both
positions to steer home, so hiding one of them is what an adversary should learn to do.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
from flax import struct

from admissable_jax.envs.catalog import ENV_SPECS
from admissable_jax.envs.external import ExternalEnv
from admissable_jax.envs.state import EnvState

_DT = 0.1
_ESCAPE_RADIUS = 3.0


@struct.dataclass
class PointMassData:
    position: jax.Array  # (2,)
    velocity: jax.Array  # (2,)


class PointMass(ExternalEnv):
    """Written on :class:`~admissable_jax.envs.external.ExternalEnv`, as an env of one's own
    would be; of :class:`EnvOptions` only ``episode_length`` and ``terminate_when_unhealthy``
    apply: there is no MuJoCo model or solver."""

    spec = ENV_SPECS["point_mass"]
    reward_terms = ("reward_distance",)
    action_size = 2

    def _state(self, data: PointMassData, reward, terminated, step_count, episode_metrics) -> EnvState:
        return EnvState(
            data=data,
            obs=jnp.concatenate([data.position, data.velocity]),
            reward=reward,
            terminated=terminated,
            truncated=step_count >= self.max_episode_steps,
            step_count=step_count,
            metrics={"reward_distance": reward},
            episode_metrics=episode_metrics,
        )

    def reset(self, rng: jax.Array) -> EnvState:
        data = PointMassData(jax.random.uniform(rng, (2,), minval=-1.0, maxval=1.0), jnp.zeros(2))
        zero = jnp.zeros((), jnp.float32)
        return self._state(data, zero, jnp.zeros((), bool), jnp.zeros((), jnp.int32),
                           {"reward_distance": zero, "return": zero})

    def step(self, state: EnvState, action: jax.Array) -> EnvState:
        action = jnp.clip(action, self.action_low, self.action_high)
        velocity = state.data.velocity + _DT * action
        position = state.data.position + _DT * velocity
        reward = jnp.exp(-jnp.sum(position**2))
        episode_return = state.episode_metrics["return"] + reward
        return self._state(
            PointMassData(position, velocity),
            reward,
            (jnp.linalg.norm(position) > _ESCAPE_RADIUS) & self.options.terminate_when_unhealthy,
            state.step_count + 1,
            {"reward_distance": episode_return, "return": episode_return},
        )
