"""MJX ports of Gymnasium's Hopper-v5, Walker2d-v5 and Ant-v5 (the paper's envs) and
HalfCheetah-v5, and :func:`make_env`.

``point_mass`` is a pure-JAX toy with the same interface, for tests and smoke runs; an env of
one's own, written in JAX on :class:`ExternalEnv` (or a Brax env on :class:`BraxEnv`), is
named by its import path (``package.module:Class``, :mod:`.external`). Which physics backend
steps an env (MJX's JAX implementation or MuJoCo Warp) is decided here, from
:class:`EnvOptions`; nothing outside this package needs to know.

Importing this package imports no MJX: names, sizes and feature names come from
:mod:`.catalog`, and an env's class, with its physics, is imported when first asked for
(:func:`make_env`, or an attribute such as ``envs.Hopper`` or ``envs.MjxEnv``), so that what
never steps an MJX env (``plot``, ``--help``, bad input, the point mass) starts seconds
sooner.
"""

from __future__ import annotations

import dataclasses
import importlib
from typing import TYPE_CHECKING, Any

from admissable_jax.envs.catalog import (
    ENV_SPECS,
    EnvSpec,
    canonical_env_name,
    env_spec,
    external_class,
    is_external,
    observation_names,
    observation_size,
    settotalmass_warning_dropped,
    short_env_name,
)
from admissable_jax.envs.options import MAX_EPISODE_STEPS, PHYSICS_CHOICES, EnvOptions, resolve_physics
from admissable_jax.envs.state import EnvState, reset_where_done

if TYPE_CHECKING:
    from admissable_jax.envs.base import MjxEnv

# The attributes imported on first use, and their modules.
_LAZY = {"MjxEnv": "base", "ExternalEnv": "external", "BraxEnv": "external",
         **{spec.home.split(".")[1]: spec.home.split(".")[0] for spec in ENV_SPECS.values()}}


def __getattr__(attribute: str) -> Any:
    if attribute not in _LAZY:
        raise AttributeError(f"module {__name__!r} has no attribute {attribute!r}")
    return getattr(importlib.import_module(f"{__name__}.{_LAZY[attribute]}"), attribute)


def env_class(name: str) -> type:
    """The class of env ``name`` (its module, and MJX for the MuJoCo envs, imported now)."""
    if is_external(name):
        return external_class(name)
    return __getattr__(env_spec(name).home.split(".")[1])


def env_physics(name: str, physics: str) -> str:
    """The backend env ``name`` steps on for a ``physics`` choice (auto, jax, warp): as
    :func:`resolve_physics` says for a MuJoCo env; ``"jax"`` for an env without a MuJoCo
    model (the point mass, an env of one's own), which steps in JAX whatever is asked, so
    that a run's ``config.yaml`` records what ran."""
    if env_spec(name).xml_file:
        return resolve_physics(physics)
    if physics not in PHYSICS_CHOICES:
        resolve_physics(physics)  # its ValueError names the choices
    return "jax"


def make_env(name: str, options: EnvOptions | None = None, **option_overrides) -> MjxEnv:
    """The env called ``name`` (``hopper``, ``walker2d``, ``ant``, ``halfcheetah``, a Gymnasium id,
    ``point_mass``, or ``package.module:Class`` for an env of your own: :mod:`.external`), built
    with ``options`` (an :class:`EnvOptions`; keyword arguments override its fields), e.g.
    ``make_env("ant", physics="warp", max_batch=4096)``.

    The defaults reproduce Gymnasium v5 (the XML's solver settings, 1000-step episodes) on
    the best backend for this machine (``physics="auto"``).
    """
    if options is not None and not isinstance(options, EnvOptions):
        raise TypeError(f"options must be an EnvOptions, got {type(options).__name__} (a dict's keys go as keywords: "
                        "make_env(name, **options))")
    fields = [field.name for field in dataclasses.fields(EnvOptions)]
    unknown = sorted(set(option_overrides) - set(fields))
    if unknown:
        raise TypeError(f"make_env got an unknown option {unknown[0]!r}; the options are {', '.join(fields)}")
    if options is None:
        options = EnvOptions(**option_overrides)
    elif option_overrides:
        options = dataclasses.replace(options, **option_overrides)
    return env_class(name)(options)


__all__ = [
    "ENV_SPECS",
    "MAX_EPISODE_STEPS",
    "PHYSICS_CHOICES",
    "Ant",
    "BraxEnv",
    "EnvOptions",
    "EnvSpec",
    "EnvState",
    "ExternalEnv",
    "HalfCheetah",
    "Hopper",
    "MjxEnv",
    "PointMass",
    "Walker2d",
    "canonical_env_name",
    "env_class",
    "env_physics",
    "env_spec",
    "make_env",
    "observation_names",
    "observation_size",
    "reset_where_done",
    "resolve_physics",
    "settotalmass_warning_dropped",
    "short_env_name",
]
