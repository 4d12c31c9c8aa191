"""Reference transitions from Gymnasium's C-MuJoCo envs, and our step from the same states.

Used by the parity tests and by ``benchmarks/physics_deviation.py``, which measures how far
a faster solver setting moves our envs from Gymnasium's.
"""

from __future__ import annotations

import functools

import gymnasium
import jax
import numpy as np

from admissable_jax.envs.base import MjxEnv
from admissable_jax.envs.catalog import settotalmass_warning_dropped
from admissable_jax.envs.state import EnvState


def gymnasium_transitions(env_id: str, n: int, seed: int = 0) -> dict[str, np.ndarray]:
    """``n`` transitions of Gymnasium's env under uniform random actions.

    Each starts with ``set_state`` at the visited (qpos, qvel), as our
    ``state_from_qpos_qvel`` does, so both sides start from identical data. Every fourth
    start gets extra joint velocity (sigma 8) so that velocity clipping is exercised.
    Keys: qpos, qvel, action, obs, reward, terminated, and ``info_<key>`` per info entry.
    """
    rng = np.random.default_rng(seed)
    with settotalmass_warning_dropped():
        env = gymnasium.make(env_id)
    env.reset(seed=seed)
    env.action_space.seed(seed)
    sim = env.unwrapped
    out = {key: [] for key in ("qpos", "qvel", "action", "obs", "reward", "terminated", "info")}
    for i in range(n):
        qpos, qvel = sim.data.qpos.copy(), sim.data.qvel.copy()
        if i % 4 == 3:
            qvel += rng.normal(0.0, 8.0, size=qvel.shape)
        action = env.action_space.sample()
        sim.set_state(qpos, qvel)
        obs, reward, terminated, _, info = env.step(action)
        for key, value in zip(out, (qpos, qvel, action, obs, reward, terminated, info)):
            out[key].append(value)
        if terminated:
            env.reset()
    env.close()
    info = out.pop("info")
    arrays = {key: np.asarray(value) for key, value in out.items()}
    arrays.update({f"info_{key}": np.asarray([i[key] for i in info]) for key in info[0]})
    return arrays


def step_from_state(env: MjxEnv, qpos, qvel, action, step_count) -> EnvState:
    """Our step from one (qpos, qvel, step_count) with ``action`` (pure; jit/vmap it)."""
    return env.step(env.state_from_qpos_qvel(qpos, qvel).replace(step_count=step_count), action)


def step_from_states(env: MjxEnv, qpos, qvel, action, step_count) -> EnvState:
    """:func:`step_from_state` for each row, batched and jitted."""
    return jax.jit(jax.vmap(functools.partial(step_from_state, env)))(qpos, qvel, action, step_count)
