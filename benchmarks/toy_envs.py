"""Toy envs of our own (``env=toy_envs:Reach``, ``env=toy_envs:DistractedReach``, with
``benchmarks/`` on PYTHONPATH): the README's example of an env of one's own, and the paper's
question in miniature, where a 2-core CPU answers it in minutes (benchmarks/README.md).

``Reach``: a mass on a line pushed towards a goal drawn at each reset; it must see its
position and the goal to get there (its velocity helps it stop). Reward exp(−(x − g)²) per
step, in (0, 1] as the paper's l = 0 assumes; the episode terminates when |x| > 3.
``DistractedReach``: the same, seen beside 17 features of pure noise (fresh N(0, 1) each
step): d = 20, of which two are needed. Under uniform p_miss an episode hides one of those two
in 2 of 20 episodes; the adversary can hide them far more often. With d = 4 (the point mass)
uniform training meets every set in a quarter of its episodes.
"""

import jax
import jax.numpy as jnp
from flax import struct

from admissable_jax.envs import ExternalEnv


@struct.dataclass
class Mass:
    position: jax.Array
    velocity: jax.Array
    goal: jax.Array
    rng: jax.Array  # draws the noise features


class Reach(ExternalEnv):
    observation_size = 3
    action_size = 1
    feature_names = ("position", "velocity", "goal")
    noise_features = 0  # features of pure noise after these three

    def reset(self, rng):
        rng, draw = jax.random.split(rng)
        start, goal = jax.random.uniform(draw, (2,), minval=-1.0, maxval=1.0)
        mass = Mass(start, jnp.zeros(()), goal, rng)
        return self.first_state(mass, self._observation(mass))

    def step(self, state, action):
        mass = state.data
        velocity = mass.velocity + 0.1 * jnp.clip(action[0], -1.0, 1.0)
        mass = Mass(mass.position + 0.1 * velocity, velocity, mass.goal, jax.random.split(mass.rng)[0])
        reward = jnp.exp(-(mass.position - mass.goal) ** 2)
        return self.next_state(state, mass, self._observation(mass), reward, jnp.abs(mass.position) > 3.0)

    def _observation(self, mass):
        noise = jax.random.normal(jax.random.fold_in(mass.rng, 1), (self.noise_features,))
        return jnp.concatenate([jnp.stack([mass.position, mass.velocity, mass.goal]), noise])


class DistractedReach(Reach):
    noise_features = 17
    observation_size = 3 + noise_features
    feature_names = (*Reach.feature_names, *(f"noise {i}" for i in range(noise_features)))
