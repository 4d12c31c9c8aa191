"""Make MJX's plane–capsule contact frame match C MuJoCo's, on both physics backends.

Why: the v5 XMLs use pyramidal friction cones, whose edges point along the contact
frame's tangents, so the tangent direction changes the physics, not only the bookkeeping.
C MuJoCo (``mjc_PlaneCapsule`` followed by ``mju_makeFrame``) uses the capsule axis
projected onto the plane as the first tangent whenever that projection is non-zero.
MJX 3.17 (JAX implementation) and its vendored MuJoCo Warp
(``third_party/mujoco_warp/_src/collision_primitive_core.py``) do the same only when the
projection's norm is >= 0.5 and otherwise fall back to a fixed axis. Ant's lower legs are
steep capsules, so on Ant-v5 both backends' contact forces differ from Gymnasium's (one
step from Gymnasium-visited states: qvel errors up to 0.9 on JAX, observation errors up to
1.8 on Warp; every other entry agrees to float round-off). The replacements below remove this.

JAX: our collider replaces MJX's in its collision table (:func:`install`). Warp: our
``wp.func`` replaces the name ``plane_capsule`` that MuJoCo Warp's plane–capsule collider
calls (:func:`install_warp`); Warp generates kernel code from those names when it first
builds the collision module, so this must run before the first Warp step (:mod:`.physics`
does both when imported, before any env is built). :data:`PATCHED_SOURCES` records the sha256 of the upstream code each patch
replaces; a test fails when a MuJoCo upgrade changes it, so the patch is re-checked
(and dropped, once upstream matches C MuJoCo) rather than silently going stale.
"""

from __future__ import annotations

import hashlib
import inspect

import jax.numpy as jnp

from admissable_jax.envs import warp_package

warp_package.use_package()  # before MJX is imported: MJX's Warp bridge then runs the mujoco-warp package
from mujoco.mjx._src import collision_driver, collision_primitive  # noqa: E402
from mujoco.mjx._src.types import GeomType  # noqa: E402

# mju_normalize3 treats shorter vectors as zero (mjMINVAL).
_MIN_NORM = 1e-15

# sha256 (first 16 hex digits) of the upstream functions the patches replace, MuJoCo 3.17.0.
PATCHED_SOURCES = {"jax": "5c698e166c246651", "warp": "097dd38698804d98"}


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


_UPSTREAM_JAX = collision_driver._COLLISION_FUNC[(GeomType.PLANE, GeomType.CAPSULE)]


def install() -> None:
    """Route MJX's (plane, capsule) collisions through :func:`plane_capsule` (idempotent)."""
    collision_driver._COLLISION_FUNC[(GeomType.PLANE, GeomType.CAPSULE)] = plane_capsule


def is_installed() -> bool:
    return collision_driver._COLLISION_FUNC[(GeomType.PLANE, GeomType.CAPSULE)] is plane_capsule


def _build_warp_plane_capsule():
    """Our ``wp.func`` with the signature of MuJoCo Warp's ``plane_capsule``."""
    import warp as wp
    from mujoco.mjx.third_party.mujoco_warp._src.collision_primitive_core import plane_sphere
    from mujoco.mjx.third_party.mujoco_warp._src.types import mat23f

    @wp.func
    def plane_capsule_c_frame(
        plane_normal: wp.vec3,
        plane_pos: wp.vec3,
        capsule_pos: wp.vec3,
        capsule_axis: wp.vec3,
        capsule_radius: float,
        capsule_half_length: float,
    ):
        n = plane_normal
        tangent = capsule_axis - n * wp.dot(n, capsule_axis)
        norm = wp.length(tangent)
        if norm < 1.0e-15:  # mju_normalize3's fallback
            tangent = wp.vec3(1.0, 0.0, 0.0)
        else:
            tangent = tangent / norm
        c = wp.cross(n, tangent)
        frame = wp.mat33(n[0], n[1], n[2], tangent[0], tangent[1], tangent[2], c[0], c[1], c[2])
        segment = capsule_axis * capsule_half_length
        dist1, pos1 = plane_sphere(n, plane_pos, capsule_pos + segment, capsule_radius)
        dist2, pos2 = plane_sphere(n, plane_pos, capsule_pos - segment, capsule_radius)
        dist = wp.vec2(dist1, dist2)
        pos = mat23f(pos1[0], pos1[1], pos1[2], pos2[0], pos2[1], pos2[2])
        return dist, pos, frame

    return plane_capsule_c_frame


_warp_plane_capsule = None


def install_warp() -> None:
    """Make MuJoCo Warp's plane–capsule collider frame contacts as C MuJoCo (idempotent)."""
    global _warp_plane_capsule
    from mujoco.mjx.third_party.mujoco_warp._src import collision_primitive as warp_primitive

    if _warp_plane_capsule is None:
        _warp_plane_capsule = _build_warp_plane_capsule()
    warp_primitive.plane_capsule = _warp_plane_capsule


def is_installed_warp() -> bool:
    from mujoco.mjx.third_party.mujoco_warp._src import collision_primitive as warp_primitive

    return _warp_plane_capsule is not None and warp_primitive.plane_capsule is _warp_plane_capsule


def upstream_source_hashes() -> dict[str, str]:
    """sha256 prefixes of the upstream code our patches replace, as installed now."""
    jax_inner = next(cell.cell_contents for cell in _UPSTREAM_JAX.__closure__ if callable(cell.cell_contents))
    hashes = {"jax": _digest(inspect.getsource(jax_inner))}
    try:
        from mujoco.mjx.third_party.mujoco_warp._src import collision_primitive_core
    except ImportError:  # warp-lang not installed
        return hashes
    hashes["warp"] = _digest(inspect.getsource(collision_primitive_core.plane_capsule.func))
    return hashes


def _digest(source: str) -> str:
    return hashlib.sha256(source.encode()).hexdigest()[:16]


__all__ = ["PATCHED_SOURCES", "install", "install_warp", "is_installed", "is_installed_warp",
           "plane_capsule", "upstream_source_hashes"]
