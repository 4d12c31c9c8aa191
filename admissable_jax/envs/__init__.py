"""MJX ports of Gymnasium's Hopper-v5, Walker2d-v5 and Ant-v5, and :func:`make_env`.

``point_mass`` is a pure-JAX toy with the same interface, for tests and smoke runs.
"""

from __future__ import annotations

from admissable_jax.envs import contact_frames
from admissable_jax.envs.ant import Ant
from admissable_jax.envs.base import MAX_EPISODE_STEPS, EnvState, MjxEnv, reset_where_done
from admissable_jax.envs.planar_walkers import Hopper, Walker2d
from admissable_jax.envs.point_mass import PointMass

contact_frames.install()

ENV_CLASSES: dict[str, type] = {cls.name: cls for cls in (Hopper, Walker2d, Ant, PointMass)}
_ALIASES = {cls.gymnasium_id.lower(): cls.name for cls in ENV_CLASSES.values() if cls.gymnasium_id}


def canonical_env_name(name: str) -> str:
    """``"hopper"`` for ``"hopper"``, ``"Hopper-v5"``, ``"HOPPER"``; ValueError otherwise."""
    if not isinstance(name, str):
        raise TypeError(f"env name must be a string, got {type(name).__name__}")
    key = name.lower()
    key = _ALIASES.get(key, key)
    if key not in ENV_CLASSES:
        valid = ", ".join([*ENV_CLASSES, *(cls.gymnasium_id for cls in ENV_CLASSES.values() if cls.gymnasium_id)])
        raise ValueError(f"unknown env {name!r}; valid names: {valid}")
    return key


def make_env(
    name: str, *, solver_iterations: int | None = None, ls_iterations: int | None = None
) -> MjxEnv:
    """The MJX env called ``name`` (``hopper``, ``walker2d``, ``ant`` or a Gymnasium id).

    The defaults reproduce Gymnasium v5 (the XML's solver settings); see
    :class:`~admissable_jax.envs.base.MjxEnv` for the faster, non-parity overrides.
    """
    return ENV_CLASSES[canonical_env_name(name)](
        solver_iterations=solver_iterations, ls_iterations=ls_iterations
    )


__all__ = [
    "MAX_EPISODE_STEPS",
    "Ant",
    "EnvState",
    "Hopper",
    "MjxEnv",
    "PointMass",
    "Walker2d",
    "canonical_env_name",
    "make_env",
    "reset_where_done",
]
