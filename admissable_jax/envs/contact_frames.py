"""Make MJX's plane–capsule contact frame match C MuJoCo's.

Why: the v5 XMLs use pyramidal friction cones, whose edges point along the contact
frame's tangents, so the tangent direction changes the physics, not only the bookkeeping.
C MuJoCo (``mjc_PlaneCapsule`` followed by ``mju_makeFrame``) uses the capsule axis
projected onto the plane as the first tangent whenever that projection is non-zero.
MJX 3.17 does the same only when the projection's norm is >= 0.5 and otherwise falls back
to a fixed world axis. Ant's lower legs are steep capsules, so on Ant-v5 MJX's contact
forces differ from Gymnasium's (we measured qvel errors up to 0.9 after one step in
float64, where every other step agrees to 1e-14). Replacing the collider removes this.

The replacement is installed into MJX's collision table, process-wide, by
:func:`install`; it is called when :mod:`admissable_jax.envs` is imported.
"""

import jax.numpy as jnp
from mujoco.mjx._src import collision_driver, collision_primitive
from mujoco.mjx._src.types import GeomType

# mju_normalize3 treats shorter vectors as zero (mjMINVAL).
_MIN_NORM = 1e-15


@collision_primitive.collider(ncon=2)
def plane_capsule(plane, capsule):
    """Two plane–sphere contacts at the capsule's end caps, framed as C MuJoCo frames them."""
    normal, axis = plane.mat[:, 2], capsule.mat[:, 2]
    tangent = axis - normal * jnp.dot(normal, axis)
    norm = jnp.linalg.norm(tangent)
    tangent = jnp.where(
        norm < _MIN_NORM,
        jnp.array([1.0, 0.0, 0.0], dtype=tangent.dtype),
        tangent / jnp.maximum(norm, _MIN_NORM),
    )
    frame = jnp.stack([normal, tangent, jnp.cross(normal, tangent)])[None]
    segment = axis * capsule.size[1]
    dists, positions = [], []
    for cap_end in (capsule.pos + segment, capsule.pos - segment):
        dist = jnp.dot(cap_end - plane.pos, normal) - capsule.size[0]
        dists.append(dist[None])
        positions.append((cap_end - normal * (capsule.size[0] + 0.5 * dist))[None])
    return jnp.concatenate(dists), jnp.concatenate(positions), jnp.concatenate([frame, frame])


def install() -> None:
    """Route MJX's (plane, capsule) collisions through :func:`plane_capsule` (idempotent)."""
    collision_driver._COLLISION_FUNC[(GeomType.PLANE, GeomType.CAPSULE)] = plane_capsule


def is_installed() -> bool:
    return collision_driver._COLLISION_FUNC[(GeomType.PLANE, GeomType.CAPSULE)] is plane_capsule


__all__ = ["install", "is_installed", "plane_capsule"]
