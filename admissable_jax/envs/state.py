"""An env's state, :class:`EnvState`, shared by every env (MJX or not), and auto-reset.

No MJX here: code that only carries env states (the training core) imports this, and the
physics is imported when an env is built (:func:`admissable_jax.envs.make_env`).
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

import jax
import jax.numpy as jnp
from flax import struct

if TYPE_CHECKING:
    from mujoco import mjx


@struct.dataclass
class EnvState:
    """One environment's state.

    ``data`` is the physics' (an ``mjx.Data`` for the MuJoCo envs); ``metrics`` holds this
    step's reward terms and positions (Gymnasium's ``info``); ``episode_metrics`` holds the
    running sums of the reward terms and of the reward (``"return"``) since the last reset.
    """

    data: mjx.Data | Any
    obs: jax.Array
    reward: jax.Array
    terminated: jax.Array
    truncated: jax.Array
    step_count: jax.Array
    metrics: dict[str, jax.Array]
    episode_metrics: dict[str, jax.Array]

    @property
    def done(self) -> jax.Array:
        return jnp.logical_or(self.terminated, self.truncated)


def reset_where_done(env: Any, state: EnvState, rng: jax.Array) -> EnvState:
    """Start a new episode of ``env`` in ``state`` if it is done (terminated or truncated),
    else keep it.

    Unbatched; vmap it for a batch. Both branches are computed (as under any ``where``),
    which is what vmapped auto-reset costs anyway.
    """
    fresh = env.reset(rng)
    return jax.tree.map(lambda new, old: jnp.where(state.done, new, old), fresh, state)
