"""Envs of one's own for the tests: ``BraxFast``, the README's Brax example word for word, and
classes wrong on purpose (the names that lead to no usable env). The README's other example,
``Reach``, is ``benchmarks/toy_envs.py``'s."""

from admissable_jax.envs import BraxEnv
from toy_envs import Reach  # benchmarks/ is on the tests' path


class BraxFast(BraxEnv):
    """Brax's own test env ("fast"): position and velocity of a body pushed forward while
    the action is positive; reward = position."""

    brax_name = "fast"
    observation_size = 2
    action_size = 1
    feature_names = ("position", "velocity")


# Wrong on purpose.


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


class NotAnEnv:
    """No reset or step."""
