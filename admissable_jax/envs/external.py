"""Envs of your own: any env written in JAX trains, is scored and is audited as ours are.

Name it by its import path, ``package.module:Class``, wherever an env name goes
(``env=my_envs.cartpole:CartPole`` on the command line, ``TrainConfig(env=...)``,
``make_env``); the run's ``config.yaml`` keeps that name, so ``resume``, ``plot``, ``audit``
and ``load_policy`` find the class again (its module must be importable there too). The class
subclasses :class:`ExternalEnv`, states its sizes as class attributes, and writes ``reset``
and ``step`` as pure functions of arrays, with :meth:`ExternalEnv.first_state` and
:meth:`ExternalEnv.next_state` filling in what every env's state carries (the step count,
truncation at ``episode_length``, the running return). Nothing above ``envs/`` changes: the
trainer, scoring and audit see the same interface as for Hopper.

An env with Brax's interface (any ``brax.envs`` env; MuJoCo Playground's have the same
``reset``/``step``/``State``) takes part through :class:`BraxEnv`, which only needs its name
and sizes.

The candidate sets U are built from ``observation_size``; ``feature_names`` (optional) name
the observation entries in figures and audit reports, as "torso z" names Hopper's first.
The paper's l = 0 assumes returns above 0: an env whose returns can be negative wants a
negative ``lower_bound``.
"""

from __future__ import annotations

import abc
from typing import Any, ClassVar

import jax
import jax.numpy as jnp

from admissable_jax.envs.catalog import CatalogEntry, canonical_env_name
from admissable_jax.envs.options import EnvOptions
from admissable_jax.envs.state import EnvState


class ExternalEnv(CatalogEntry, abc.ABC):
    """Base of an env of your own (see the module's docstring). Of :class:`EnvOptions` it
    takes ``episode_length`` and ``terminate_when_unhealthy``; the physics settings are the
    MuJoCo envs', and it steps in its own JAX code."""

    observation_size: ClassVar[int]  # d: the length of ``obs``
    action_size: ClassVar[int]
    action_bound: ClassVar[float] = 1.0  # actions lie in [-bound, bound]^action_size
    feature_names: ClassVar[tuple[str, ...]] = ()  # one per observation entry; () = their indices

    def __init__(self, options: EnvOptions | None = None):
        if "spec" not in vars(type(self)):  # built directly, not by name: its entry, by its own path
            canonical_env_name(f"{type(self).__module__}:{type(self).__qualname__}")
        self.options = options or EnvOptions()
        self.action_low = jnp.full((self.action_size,), -self.action_bound, jnp.float32)
        self.action_high = jnp.full((self.action_size,), self.action_bound, jnp.float32)

    @property
    def max_episode_steps(self) -> int:
        return self.options.episode_length

    @property
    def physics_name(self) -> str:
        return "jax"

    @property
    def steps_cost_each_world(self) -> bool:
        """As :attr:`MjxEnv.steps_cost_each_world`: on a CPU, where its JAX step runs."""
        return jax.default_backend() == "cpu"

    def __repr__(self) -> str:
        return f"{type(self).__name__}(obs {self.observation_size}, actions {self.action_size})"

    def capacity_exceeded(self, state: EnvState) -> jax.Array:
        """Never: the env has no fixed-size physics buffers."""
        return jnp.zeros((), bool)

    def capacity_message(self) -> str:
        return f"{self.name} has no physics buffers"

    @abc.abstractmethod
    def reset(self, rng: jax.Array) -> EnvState:
        """A new episode: ``return self.first_state(data, obs)``."""

    @abc.abstractmethod
    def step(self, state: EnvState, action: jax.Array) -> EnvState:
        """One transition from ``state.data``: ``return self.next_state(state, data, obs,
        reward, terminated)``. Does not reset: the trainer does, when ``state.done``."""

    def first_state(self, data: Any, obs: jax.Array) -> EnvState:
        """The state at an episode's start: ``data`` is whatever the env carries (a pytree of
        arrays), ``obs`` its observation."""
        zero = jnp.zeros((), jnp.float32)
        return EnvState(data=data, obs=self._checked("observations", obs, (self.observation_size,)), reward=zero,
                        terminated=jnp.zeros((), bool), truncated=jnp.zeros((), bool),
                        step_count=jnp.zeros((), jnp.int32), metrics={}, episode_metrics={"return": zero})

    def _checked(self, what: str, value: jax.Array, shape: tuple[int, ...]) -> jax.Array:
        """``value`` as float32, or ValueError in one line (at trace time, so before any run
        starts) where its shape is not ``shape``: a user's env meets our batches here."""
        value = jnp.asarray(value, jnp.float32)
        if value.shape != shape:
            raise ValueError(f"{type(self).__name__} gives {what} of shape {value.shape}, not {shape}"
                             + (" (its observation_size)" if what == "observations" else ""))
        return value

    def next_state(self, state: EnvState, data: Any, obs: jax.Array, reward: jax.Array,
                   terminated: jax.Array) -> EnvState:
        """The state after one step of ``state``: the step counted, truncated at
        ``episode_length`` (Gymnasium's TimeLimit), ``terminated`` only if the options allow
        it, the reward added to the episode's return."""
        reward = self._checked("rewards", reward, ())
        step_count = state.step_count + 1
        return EnvState(data=data, obs=self._checked("observations", obs, (self.observation_size,)), reward=reward,
                        terminated=jnp.asarray(terminated, bool) & self.options.terminate_when_unhealthy,
                        truncated=step_count >= self.max_episode_steps, step_count=step_count, metrics={},
                        episode_metrics={"return": state.episode_metrics["return"] + reward})


class BraxEnv(ExternalEnv):
    """An env with Brax's interface, taking part as an env of one's own: a subclass names a
    Brax env (``brax_name`` and ``brax_kwargs`` for ``brax.envs.get_environment``) or
    overrides :meth:`build` to return any object with Brax's ``reset(rng) -> State`` and
    ``step(state, action) -> State``, and states ``observation_size`` and ``action_size``
    (checked against the env's own). The Brax state is the env's ``data``; Brax's ``done``
    is the termination, and truncation at ``episode_length`` is ours, as for every env."""

    brax_name: ClassVar[str] = ""
    brax_kwargs: ClassVar[dict[str, Any]] = {}

    def __init__(self, options: EnvOptions | None = None):
        super().__init__(options)
        self.brax_env = self.build()
        sizes = (self.brax_env.observation_size, self.brax_env.action_size)
        if sizes != (self.observation_size, self.action_size):
            raise ValueError(f"{type(self).__name__} states observation_size {self.observation_size} and action_size "
                             f"{self.action_size}; the env it builds has {sizes[0]} and {sizes[1]}")

    def build(self) -> Any:
        """The Brax env stepped (by default ``brax.envs.get_environment(brax_name, **brax_kwargs)``)."""
        from brax import envs  # imported only when a Brax env is built: seconds

        return envs.get_environment(self.brax_name, **self.brax_kwargs)

    def reset(self, rng: jax.Array) -> EnvState:
        brax_state = self.brax_env.reset(rng)
        return self.first_state(brax_state, brax_state.obs)

    def step(self, state: EnvState, action: jax.Array) -> EnvState:
        brax_state = self.brax_env.step(state.data, action)
        return self.next_state(state, brax_state, brax_state.obs, brax_state.reward, brax_state.done > 0)
