"""MJX ports of Gymnasium's Hopper-v5, Walker2d-v5 and Ant-v5 (the paper's envs) and
HalfCheetah-v5, and :func:`make_env`.

``point_mass`` is a pure-JAX toy with the same interface, for tests and smoke runs. Which
physics backend steps an env (MJX's JAX implementation or MuJoCo Warp) is decided here,
from :class:`EnvOptions`; nothing outside this package needs to know.
"""

from __future__ import annotations

import contextlib
import dataclasses
import io

# MJX prints an import failure when warp-lang is absent; physics=jax needs no Warp (and
# physics=warp says clearly when it is missing), so keep that line out of users' output.
with contextlib.redirect_stdout(io.StringIO()):
    from mujoco import mjx  # noqa: F401

from admissable_jax.envs import contact_frames  # noqa: E402
from admissable_jax.envs.ant import Ant  # noqa: E402
from admissable_jax.envs.base import EnvState, MjxEnv, reset_where_done, settotalmass_warning_dropped  # noqa: E402
from admissable_jax.envs.half_cheetah import HalfCheetah  # noqa: E402
from admissable_jax.envs.options import MAX_EPISODE_STEPS, PHYSICS_CHOICES, EnvOptions, resolve_physics, warp_installed  # noqa: E402
from admissable_jax.envs.planar_walkers import Hopper, Walker2d  # noqa: E402
from admissable_jax.envs.point_mass import PointMass  # noqa: E402

contact_frames.install()
if warp_installed():
    import warp

    warp.config.quiet = True  # no banner in users' output
    warp.config.log_level = max(warp.config.log_level, warp.LOG_WARNING)  # nor a line per kernel module
    contact_frames.install_warp()  # before the first Warp collision kernel is built

ENV_CLASSES: dict[str, type] = {cls.name: cls for cls in (Hopper, Walker2d, Ant, HalfCheetah, PointMass)}
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


def observation_size(name: str) -> int:
    """d, the observation size of env ``name``, without building it."""
    return ENV_CLASSES[canonical_env_name(name)].observation_size


def observation_names(name: str) -> list[str]:
    """Readable names of env ``name``'s observation entries ("torso z", "thigh joint angle",
    "aux_1 contact force z", ...), without building the env."""
    return ENV_CLASSES[canonical_env_name(name)].observation_names()


def make_env(name: str, options: EnvOptions | None = None, **option_overrides) -> MjxEnv:
    """The env called ``name`` (``hopper``, ``walker2d``, ``ant``, ``halfcheetah``, a Gymnasium id, or
    ``point_mass``), built with ``options`` (an :class:`EnvOptions`; keyword arguments
    override its fields), e.g. ``make_env("ant", physics="warp", max_batch=4096)``.

    The defaults reproduce Gymnasium v5 (the XML's solver settings, 1000-step episodes) on
    the best backend for this machine (``physics="auto"``).
    """
    if options is None:
        options = EnvOptions(**option_overrides)
    elif option_overrides:
        options = dataclasses.replace(options, **option_overrides)
    return ENV_CLASSES[canonical_env_name(name)](options)


__all__ = [
    "MAX_EPISODE_STEPS",
    "PHYSICS_CHOICES",
    "Ant",
    "EnvOptions",
    "EnvState",
    "HalfCheetah",
    "Hopper",
    "MjxEnv",
    "PointMass",
    "Walker2d",
    "canonical_env_name",
    "make_env",
    "observation_names",
    "observation_size",
    "reset_where_done",
    "resolve_physics",
    "settotalmass_warning_dropped",
]
