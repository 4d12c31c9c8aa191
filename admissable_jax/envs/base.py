"""The MJX environment base shared by our Gymnasium v5 ports.

An environment is a plain Python object built from a frozen :class:`EnvOptions` bundle and
holding the compiled MuJoCo model; its ``reset`` and ``step`` are pure functions of arrays
and an :class:`EnvState` pytree, so they can be jitted and vmapped. Physics is MJX with the
XML's own solver settings on the backend the options name (:mod:`.physics`), stepped exactly
as Gymnasium's ``MujocoEnv.do_simulation`` does.
"""

from __future__ import annotations

import abc
from typing import TYPE_CHECKING, ClassVar

import chex
import jax
import jax.numpy as jnp
import mujoco

from admissable_jax.envs.catalog import CatalogEntry, load_gymnasium_model
from admissable_jax.envs.options import EnvOptions
from admissable_jax.envs.physics import Physics
from admissable_jax.envs.state import EnvState

if TYPE_CHECKING:
    from mujoco import mjx


class MjxEnv(CatalogEntry, abc.ABC):
    """A Gymnasium MuJoCo v5 task on MJX. Subclasses name their catalog entry (``spec``:
    name, Gymnasium id, XML, observation size) and fill in the task-specific hooks."""

    frame_skip: ClassVar[int]
    reset_noise_scale: ClassVar[float]
    reward_terms: ClassVar[tuple[str, ...]]
    info_keys: ClassVar[tuple[str, ...]]
    reads_contact_forces: ClassVar[bool] = False

    def __init__(self, options: EnvOptions | None = None):
        """Load the XML from gymnasium and put it on the backend ``options.physics`` resolves
        to. Solver settings default to the XML's (Gymnasium parity)."""
        self.options = options or EnvOptions()
        self.mj_model = load_gymnasium_model(self.spec.xml_file)
        if self.options.solver_iterations is not None:
            self.mj_model.opt.iterations = self.options.solver_iterations
        if self.options.ls_iterations is not None:
            self.mj_model.opt.ls_iterations = self.options.ls_iterations
        self.physics = Physics(self.mj_model, self.options.resolved_physics, self.frame_skip,
                               self.options.max_batch, contact_forces=self.reads_contact_forces,
                               graph_mode=self.options.graph_mode, deterministic=self.options.deterministic,
                               worlds_per_call=self.options.worlds_per_call)
        self.dt = float(self.mj_model.opt.timestep) * self.frame_skip
        self.init_qpos = jnp.asarray(self.mj_model.qpos0, dtype=jnp.float32)
        self.init_qvel = jnp.zeros(self.mj_model.nv, dtype=jnp.float32)
        ctrl_range = self.mj_model.actuator_ctrlrange
        self.action_low = jnp.asarray(ctrl_range[:, 0], dtype=jnp.float32)
        self.action_high = jnp.asarray(ctrl_range[:, 1], dtype=jnp.float32)
        self.action_size = int(self.mj_model.nu)
        observed = int(self._observation(self.physics.data_template).shape[-1])
        assert observed == self.observation_size, (observed, self.observation_size)

    @property
    def max_episode_steps(self) -> int:
        return self.options.episode_length

    @property
    def physics_name(self) -> str:
        """``"jax"`` or ``"warp"``: the backend this env steps on."""
        return self.physics.impl

    @property
    def steps_cost_each_world(self) -> bool:
        """Whether a batched step costs about the sum of its worlds' work: MJX's JAX physics
        on a CPU. Not MuJoCo Warp (its step is kernel launches, about the same for any batch
        that fits) nor any accelerator. Where it holds, worlds with nothing left to do are
        better not stepped at all (an experiment scores its pairs one after another)."""
        return self.physics.steps_cost_each_world

    def __repr__(self) -> str:
        return (
            f"{type(self).__name__}({self.gymnasium_id}: obs {self.observation_size}, "
            f"actions {self.action_size}, frame_skip {self.frame_skip}, dt {self.dt}, "
            f"physics {self.physics_name})"
        )

    # --- task hooks -------------------------------------------------------------------
    @abc.abstractmethod
    def _observation(self, data: mjx.Data) -> jax.Array:
        """The v5 observation vector of ``data``."""

    @abc.abstractmethod
    def _is_healthy(self, qpos: jax.Array, qvel: jax.Array) -> jax.Array:
        """Gymnasium's ``is_healthy`` for this (qpos, qvel)."""

    @abc.abstractmethod
    def _reward_terms(
        self, before: mjx.Data, after: mjx.Data, action: jax.Array, healthy: jax.Array
    ) -> tuple[dict[str, jax.Array], dict[str, jax.Array]]:
        """(reward terms, summing to the reward; ``info_keys`` entries such as positions)."""

    @abc.abstractmethod
    def _reset_noise(self, rng: jax.Array) -> tuple[jax.Array, jax.Array]:
        """Noise added to (init_qpos, init_qvel) at reset, as the env's ``reset_model``."""

    # --- public API -------------------------------------------------------------------
    def is_healthy(self, qpos: jax.Array, qvel: jax.Array) -> jax.Array:
        """Whether (qpos, qvel) is healthy; the episode terminates when it is not."""
        return self._is_healthy(qpos, qvel)

    def reset(self, rng: jax.Array) -> EnvState:
        """A new episode from the v5 reset distribution."""
        qpos_noise, qvel_noise = self._reset_noise(rng)
        return self.state_from_qpos_qvel(self.init_qpos + qpos_noise, self.init_qvel + qvel_noise)

    def state_from_qpos_qvel(self, qpos: jax.Array, qvel: jax.Array) -> EnvState:
        """Put a given (qpos, qvel) into a fresh state, as Gymnasium's ``set_state`` does.

        Runs ``mj_forward`` (not ``mj_rnePostConstraint``), so, as in Gymnasium after a
        reset, contact forces read as zero until the first step. The step counter is 0.
        Use this to compare one of our steps with Gymnasium's from the same state:
        ``env.unwrapped.set_state(qpos, qvel)`` there, this here, then step both.
        """
        chex.assert_shape(qpos, (self.mj_model.nq,))
        chex.assert_shape(qvel, (self.mj_model.nv,))
        data = self.physics.data(jnp.asarray(qpos, jnp.float32), jnp.asarray(qvel, jnp.float32))
        zero = jnp.zeros((), jnp.float32)
        return EnvState(
            data=data,
            obs=self._observation(data),
            reward=zero,
            terminated=jnp.zeros((), bool),
            truncated=jnp.zeros((), bool),
            step_count=jnp.zeros((), jnp.int32),
            metrics={key: zero for key in (*self.reward_terms, *self.info_keys)},
            episode_metrics={key: zero for key in (*self.reward_terms, "return")},
        )

    def step(self, state: EnvState, action: jax.Array) -> EnvState:
        """One v5 transition. Does not reset: callers decide what to do when ``done``.

        ``truncated`` is set at ``max_episode_steps`` (Gymnasium's TimeLimit); it may be set
        together with ``terminated``.
        """
        chex.assert_shape(action, (self.action_size,))
        action = jnp.asarray(action, jnp.float32)
        data = self.physics.step(state.data, action)
        healthy = self._is_healthy(data.qpos, data.qvel)
        terms, info = self._reward_terms(state.data, data, action, healthy)
        reward = sum(terms.values())
        step_count = state.step_count + 1
        episode_metrics = {key: state.episode_metrics[key] + terms[key] for key in self.reward_terms}
        episode_metrics["return"] = state.episode_metrics["return"] + reward
        return EnvState(
            data=data,
            obs=self._observation(data),
            reward=reward,
            terminated=jnp.logical_not(healthy) & self.options.terminate_when_unhealthy,
            truncated=step_count >= self.max_episode_steps,
            step_count=step_count,
            metrics={**terms, **info},
            episode_metrics=episode_metrics,
        )

    def capacity_exceeded(self, state: EnvState) -> jax.Array:
        """Whether the physics ran out of a fixed buffer in any of ``state``'s worlds (batched
        or not); :meth:`capacity_message` says which setting to raise."""
        return jnp.any(self.physics.capacity_exceeded(state.data))

    def capacity_message(self) -> str:
        return self.physics.capacity_message()


def uniform_qpos_normal_qvel_noise(rng: jax.Array, model: mujoco.MjModel, scale: float) -> tuple[jax.Array, jax.Array]:
    """Reset noise of Ant-v5 and HalfCheetah-v5: qpos + U(-s, s), qvel + s · N(0, 1)."""
    qpos_rng, qvel_rng = jax.random.split(rng)
    qpos_noise = jax.random.uniform(qpos_rng, (model.nq,), minval=-scale, maxval=scale)
    qvel_noise = scale * jax.random.normal(qvel_rng, (model.nv,))
    return qpos_noise, qvel_noise
