"""Envs of one's own for the tests (``env=reach_env:Reach``, ``env=reach_env:BraxFast``), the
README's example word for word, and two classes wrong on purpose.

A mass on a line is pushed towards a goal drawn at each reset; it must see both its
position and the goal to get there (its velocity helps it stop). Reward exp(−(x − g)²) per
step, in (0, 1] as the paper's l = 0 assumes; the episode terminates when |x| > 3.
"""

import jax
import jax.numpy as jnp
from flax import struct

from admissable_jax.envs import BraxEnv, ExternalEnv


@struct.dataclass
class Mass:
    position: jax.Array
    velocity: jax.Array
    goal: jax.Array


class Reach(ExternalEnv):
    observation_size = 3
    action_size = 1
    feature_names = ("position", "velocity", "goal")

    def reset(self, rng):
        start, goal = jax.random.uniform(rng, (2,), minval=-1.0, maxval=1.0)
        mass = Mass(start, jnp.zeros(()), goal)
        return self.first_state(mass, self._observation(mass))

    def step(self, state, action):
        mass = state.data
        velocity = mass.velocity + 0.1 * jnp.clip(action[0], -1.0, 1.0)
        mass = Mass(mass.position + 0.1 * velocity, velocity, mass.goal)
        reward = jnp.exp(-(mass.position - mass.goal) ** 2)
        return self.next_state(state, mass, self._observation(mass), reward, jnp.abs(mass.position) > 3.0)

    def _observation(self, mass):
        return jnp.stack([mass.position, mass.velocity, mass.goal])


class BraxFast(BraxEnv):
    """Brax's own test env ("fast"): position and velocity of a body pushed forward while
    the action is positive; reward = position."""

    brax_name = "fast"
    observation_size = 2
    action_size = 1
    feature_names = ("position", "velocity")


# Wrong on purpose: the tests' names that lead to no usable env.


class WrongSize(BraxFast):
    """States a size the Brax env does not have."""

    observation_size = 3
    feature_names = ()


class WrongObservation(Reach):
    """States one observation entry more than it gives."""

    observation_size = 4
    feature_names = ()


class OneName(Reach):
    """Names one of its three observation entries."""

    feature_names = ("position",)


class NoSize(Reach):
    """Forgot to say its observation size."""

    observation_size = None
