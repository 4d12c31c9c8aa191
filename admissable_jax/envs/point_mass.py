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
    would be (its ``first_state``/``next_state`` count steps, truncate and sum the return);
    of :class:`EnvOptions` only ``episode_length`` and ``terminate_when_unhealthy`` apply:
    there is no MuJoCo model or solver."""

    spec = ENV_SPECS["point_mass"]
    action_size = 2

    def reset(self, rng: jax.Array) -> EnvState:
        data = PointMassData(jax.random.uniform(rng, (2,), minval=-1.0, maxval=1.0), jnp.zeros(2))
        return self.first_state(data, _observation(data))

    def step(self, state: EnvState, action: jax.Array) -> EnvState:
        action = jnp.clip(action, self.action_low, self.action_high)
        velocity = state.data.velocity + _DT * action
        position = state.data.position + _DT * velocity
        data = PointMassData(position, velocity)
        return self.next_state(state, data, _observation(data), jnp.exp(-jnp.sum(position**2)),
                               jnp.linalg.norm(position) > _ESCAPE_RADIUS)


def _observation(data: PointMassData) -> jax.Array:
    return jnp.concatenate([data.position, data.velocity])
