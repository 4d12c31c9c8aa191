"""Toy envs of our own (``env=toy_envs:DistractedReach``, with ``benchmarks/`` on PYTHONPATH):
the paper's question in miniature, where a 2-core CPU answers it in minutes.

``DistractedReach``: a mass on a line pushed towards a goal drawn at each reset (reward
exp(−(x − g)²) per step, in (0, 1] as l = 0 assumes; the episode ends when |x| > 3), seen
beside 17 features of pure noise (fresh N(0, 1) each step): d = 20, and only the position
and the goal are needed (the velocity helps to stop). Under uniform p_miss an episode hides
one of those two in 2 of 20 episodes; the adversary can hide them far more often. With
d = 4 (the point mass) uniform training meets every set in a quarter of its episodes.
"""

import jax
import jax.numpy as jnp
from flax import struct

from admissable_jax.envs import ExternalEnv

DISTRACTORS = 17


@struct.dataclass
class Mass:
    position: jax.Array
    velocity: jax.Array
    goal: jax.Array
    rng: jax.Array  # draws the distractors


class DistractedReach(ExternalEnv):
    observation_size = 3 + DISTRACTORS
    action_size = 1
    feature_names = ("position", "velocity", "goal", *(f"noise {i}" for i in range(DISTRACTORS)))

    def reset(self, rng):
        rng, draw = jax.random.split(rng)
        start, goal = jax.random.uniform(draw, (2,), minval=-1.0, maxval=1.0)
        mass = Mass(start, jnp.zeros(()), goal, rng)
        return self.first_state(mass, self._observation(mass))

    def step(self, state, action):
        mass = state.data
        velocity = mass.velocity + 0.1 * jnp.clip(action[0], -1.0, 1.0)
        rng, _ = jax.random.split(mass.rng)
        mass = Mass(mass.position + 0.1 * velocity, velocity, mass.goal, rng)
        reward = jnp.exp(-(mass.position - mass.goal) ** 2)
        return self.next_state(state, mass, self._observation(mass), reward, jnp.abs(mass.position) > 3.0)

    def _observation(self, mass):
        noise = jax.random.normal(jax.random.fold_in(mass.rng, 1), (DISTRACTORS,))
        return jnp.concatenate([jnp.stack([mass.position, mass.velocity, mass.goal]), noise])
