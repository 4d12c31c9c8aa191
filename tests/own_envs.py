"""Envs of one's own for the tests: ``BraxFast``, the README's Brax example word for word,
``BraxFastFinish``, whose Brax env terminates, and classes wrong on purpose (the names that lead to no usable env). The README's other example,
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


class BraxFastFinish(BraxFast):
    """``BraxFast`` whose Brax env says done once the body passes position 0.001 (after its
    second step at full push): a Brax env's own termination."""

    def build(self):
        return _DoneAfter(super().build(), mark=0.001)


class _DoneAfter:
    """A Brax env whose ``done`` turns 1 once the observation's first entry passes ``mark``."""

    def __init__(self, env, mark: float):
        self.env, self.mark = env, mark
        self.observation_size, self.action_size = env.observation_size, env.action_size

    def reset(self, rng):
        return self.env.reset(rng)

    def step(self, state, action):
        state = self.env.step(state, action)
        return state.replace(done=(state.obs[0] > self.mark).astype(state.done.dtype))


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


class NoFeatures(Reach):
    """Says it observes nothing: no feature to hide."""

    observation_size = 0
    feature_names = ()


class WideReach(Reach):
    """Takes actions in [-2, 2]."""

    action_bound = 2.0


class NotAnEnv:
    """No reset or step."""
