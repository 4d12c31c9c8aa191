"""What each env is, without its physics: name, Gymnasium id, XML, observation size and a
readable name per observation entry.

Reading this needs MuJoCo's C bindings only (for the feature names), never MJX, MuJoCo Warp
or JAX, so what only names or sizes envs (configs, ``plot``, ``--help``, bad input, a
Gymnasium policy's audit, the point mass) starts in a few seconds; the env classes, which
hold the physics, take their entry from here (``spec``) and are imported on first use
(:func:`admissable_jax.envs.make_env`).
"""

from __future__ import annotations

import contextlib
import dataclasses
import importlib
import os
import sys
from typing import Callable, ClassVar

import gymnasium
import mujoco


def gymnasium_asset_path(xml_file: str) -> str:
    """Path of a model XML shipped inside the installed gymnasium package (never copied)."""
    return os.path.join(os.path.dirname(gymnasium.__file__), "envs", "mujoco", "assets", xml_file)


@contextlib.contextmanager
def settotalmass_warning_dropped():
    """Within: MuJoCo's deprecation warning for ``half_cheetah.xml``'s ``settotalmass``
    (Gymnasium's file, nothing a user can act on) is dropped, where MuJoCo would print it and
    append it to ``MUJOCO_LOG.TXT`` in the working directory; other warnings print to stderr."""
    previous = mujoco.get_mju_user_warning()

    def warn(message: str) -> None:
        if "settotalmass" not in message:
            print(f"WARNING: {message}", file=sys.stderr)

    mujoco.set_mju_user_warning(warn)
    try:
        yield
    finally:
        mujoco.set_mju_user_warning(previous)


def load_gymnasium_model(xml_file: str) -> mujoco.MjModel:
    """The compiled model of a Gymnasium XML (:func:`settotalmass_warning_dropped`)."""
    with settotalmass_warning_dropped():
        return mujoco.MjModel.from_xml_path(gymnasium_asset_path(xml_file))


def joint_label(model: mujoco.MjModel, joint: int) -> str:
    """``"thigh left joint"`` for the joint named ``thigh_left_joint``."""
    return model.joint(joint).name.replace("_", " ")


def planar_observation_names(model: mujoco.MjModel) -> list[str]:
    """Names of a planar body's qpos[1:], qvel entries (Hopper, Walker2d, HalfCheetah); joints
    0-2 are the torso's slide x, slide z and hinge (rootx, rootz, rooty), the rest the limbs'."""
    joints = [joint_label(model, j) for j in range(3, model.njnt)]
    positions = ["torso z", "torso angle", *(f"{joint} angle" for joint in joints)]
    velocities = ["torso x velocity", "torso z velocity", "torso angular velocity",
                  *(f"{joint} angular velocity" for joint in joints)]
    return positions + velocities


def ant_observation_names(model: mujoco.MjModel) -> list[str]:
    """Names of Ant-v5's qpos[2:], qvel and clipped ``cfrc_ext[1:]`` entries."""
    joints = [joint_label(model, j) for j in range(1, model.njnt)]  # joint 0: the torso's free joint
    positions = ["torso z", *(f"torso orientation {c}" for c in "wxyz"), *(f"{joint} angle" for joint in joints)]
    velocities = [*(f"torso {c} velocity" for c in "xyz"), *(f"torso angular velocity {c}" for c in "xyz"),
                  *(f"{joint} angular velocity" for joint in joints)]
    forces = []
    for body in range(1, model.nbody):  # cfrc_ext: (torque, force) per body, world left out
        name = model.body(body).name or f"{model.body(model.body_parentid[body]).name} child"
        forces += [f"{name} contact {kind} {c}" for kind in ("torque", "force") for c in "xyz"]
    return positions + velocities + forces


@dataclasses.dataclass(frozen=True)
class EnvSpec:
    """One env's entry. ``home`` names the module of ``admissable_jax.envs`` and the class
    that hold its physics; ``feature_names`` names the observation entries from the XML's
    compiled model (None where the env has no XML)."""

    name: str
    gymnasium_id: str | None
    xml_file: str | None
    observation_size: int
    home: str
    feature_names: Callable[[mujoco.MjModel | None], list[str]]


# In the order figures lay envs out: the paper's three first.
ENV_SPECS: dict[str, EnvSpec] = {spec.name: spec for spec in (
    EnvSpec("hopper", "Hopper-v5", "hopper.xml", 11, "planar_walkers.Hopper", planar_observation_names),
    EnvSpec("walker2d", "Walker2d-v5", "walker2d_v5.xml", 17, "planar_walkers.Walker2d", planar_observation_names),
    EnvSpec("ant", "Ant-v5", "ant.xml", 105, "ant.Ant", ant_observation_names),
    EnvSpec("halfcheetah", "HalfCheetah-v5", "half_cheetah.xml", 17, "half_cheetah.HalfCheetah",
            planar_observation_names),
    EnvSpec("point_mass", None, None, 4, "point_mass.PointMass",
            lambda _: ["x", "y", "x velocity", "y velocity"]),
)}
_ALIASES = {spec.gymnasium_id.lower(): spec.name for spec in ENV_SPECS.values() if spec.gymnasium_id}


class CatalogEntry:
    """Base of the env classes: an env's name, Gymnasium id and observation size are its
    catalog entry's (``spec``), stated once."""

    spec: ClassVar[EnvSpec]

    @property
    def name(self) -> str:
        return self.spec.name

    @property
    def gymnasium_id(self) -> str | None:
        return self.spec.gymnasium_id

    @property
    def display_name(self) -> str:
        """How lines and records name the env: its Gymnasium id, or its own name where it has
        none (the point mass, an env of one's own)."""
        return self.gymnasium_id or self.name

    @property
    def observation_size(self) -> int:
        return self.spec.observation_size


# Envs of your own (:mod:`.external`), by import path, as each was first named in this process.
_EXTERNAL: dict[str, tuple[EnvSpec, type]] = {}


def _external(name: str) -> tuple[EnvSpec, type]:
    """The catalog entry and class of the env ``package.module:Class``, imported now (its
    module may import JAX: only an env of one's own is imported here). ValueError in one
    line where the name does not lead to a usable class."""
    if name in _EXTERNAL:
        return _EXTERNAL[name]
    module_name, _, class_name = name.partition(":")
    try:
        module = importlib.import_module(module_name)
    except Exception as error:  # the user's module: whatever it raises, said in one line
        raise ValueError(f"env {name!r}: cannot import {module_name} ({type(error).__name__}: {error})") from None
    cls = getattr(module, class_name, None)
    if not isinstance(cls, type):
        raise ValueError(f"env {name!r}: {module_name} has no class {class_name}")
    if not all(callable(getattr(cls, method, None)) for method in ("reset", "step")):
        raise ValueError(f"env {name!r}: {class_name} must define reset and step (subclass envs.ExternalEnv)")
    size = getattr(cls, "observation_size", None)
    if not isinstance(size, int) or isinstance(size, bool) or size < 1:
        raise ValueError(f"env {name!r}: {class_name}.observation_size must be an int >= 1, got {size!r}")
    names = [str(feature) for feature in getattr(cls, "feature_names", ())] or [f"obs {i}" for i in range(size)]
    if len(names) != size:
        raise ValueError(f"env {name!r}: {class_name}.feature_names holds {len(names)} names; its "
                         f"observations have {size} entries")
    spec = EnvSpec(name, None, None, size, name, lambda _: list(names))
    cls.spec = spec
    _EXTERNAL[name] = spec, cls
    return spec, cls


def is_external(name: str) -> bool:
    """Whether ``name`` names an env of one's own (``package.module:Class``); a name that is
    no string is not, and :func:`canonical_env_name` says so."""
    return isinstance(name, str) and ":" in name


def external_class(name: str) -> type:
    """The class of the env of one's own called ``name``."""
    return _external(name)[1]


def canonical_env_name(name: str) -> str:
    """``"hopper"`` for ``"hopper"``, ``"Hopper-v5"``, ``"HOPPER"``; ``package.module:Class``
    (an env of one's own, :mod:`.external`) as it is, once its class is found; ValueError
    otherwise."""
    if not isinstance(name, str):
        raise TypeError(f"env name must be a string, got {type(name).__name__}")
    if is_external(name):
        return _external(name)[0].name
    key = _catalog_key(name)
    if "," in name and all(_catalog_key(part.strip()) in ENV_SPECS for part in name.split(",")):
        raise ValueError(f"env={name} names {name.count(',') + 1} envs; a command trains or scores one: run one "
                         f"command per env (env={name.split(',')[0].strip()}, ...), then plot them together")
    if key not in ENV_SPECS:
        valid = ", ".join([*ENV_SPECS, *(spec.gymnasium_id for spec in ENV_SPECS.values() if spec.gymnasium_id)])
        raise ValueError(f"unknown env {name!r}; valid names: {valid}, or package.module:Class for an env of "
                         "your own")
    return key


def _catalog_key(name: str) -> str:
    """The key of ``ENV_SPECS`` that ``name`` would be, in any case or as its Gymnasium id
    (``Hopper-v5`` → ``hopper``); not checked to be there."""
    key = name.lower()
    return _ALIASES.get(key, key)


def gymnasium_env_id(name: str) -> str:
    """The Gymnasium id of one of our envs named as ``env=`` names it (``hopper`` →
    ``Hopper-v5``); any other name as it is, a Gymnasium id for Gymnasium to read."""
    spec = ENV_SPECS.get(_catalog_key(name))
    return spec.gymnasium_id if spec is not None and spec.gymnasium_id else name


def env_spec(name: str) -> EnvSpec:
    """The catalog entry of env ``name`` (any name :func:`canonical_env_name` takes)."""
    return _external(name)[0] if is_external(name) else ENV_SPECS[canonical_env_name(name)]


def short_env_name(name: str) -> str:
    """A name for folders: the env's canonical name, or its class's for one of one's own
    (``cartpole`` for ``my_envs.cartpole:CartPole``)."""
    return name.rpartition(":")[2].lower() if is_external(name) else canonical_env_name(name)


def observation_size(name: str) -> int:
    """d, the observation size of env ``name``, without building it."""
    return env_spec(name).observation_size


def observation_names(name: str) -> list[str]:
    """Readable names of env ``name``'s observation entries ("torso z", "thigh joint angle",
    "aux_1 contact force z", ...), as Gymnasium's docs describe them, without building the env."""
    spec = env_spec(name)
    names = spec.feature_names(load_gymnasium_model(spec.xml_file) if spec.xml_file else None)
    assert len(names) == spec.observation_size, (len(names), spec.observation_size)
    return names
