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
    def observation_size(self) -> int:
        return self.spec.observation_size


def canonical_env_name(name: str) -> str:
    """``"hopper"`` for ``"hopper"``, ``"Hopper-v5"``, ``"HOPPER"``; ValueError otherwise."""
    if not isinstance(name, str):
        raise TypeError(f"env name must be a string, got {type(name).__name__}")
    key = name.lower()
    key = _ALIASES.get(key, key)
    if key not in ENV_SPECS:
        valid = ", ".join([*ENV_SPECS, *(spec.gymnasium_id for spec in ENV_SPECS.values() if spec.gymnasium_id)])
        raise ValueError(f"unknown env {name!r}; valid names: {valid}")
    return key


def env_spec(name: str) -> EnvSpec:
    """The catalog entry of env ``name`` (any name :func:`canonical_env_name` takes)."""
    return ENV_SPECS[canonical_env_name(name)]


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
