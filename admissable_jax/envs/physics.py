"""The physics behind an MJX env: MJX's JAX implementation or MuJoCo Warp, one interface.

:class:`Physics` holds the device model and a template ``mjx.Data`` and steps it exactly as
Gymnasium's ``do_simulation`` does (``frame_skip`` × ``mj_step``, then
``mj_rnePostConstraint`` where the env reads contact forces). Everything backend-specific
lives here:

- Warp keeps every world's contacts in one buffer shared by the whole vmapped batch, so
  its capacity is ``naconmax`` = (the model's largest possible contact count per world) ×
  ``max_batch``; constraint rows per world (``njmax``) are the model's largest possible
  count. Both counts come from MJX's own static contact and constraint tables, so neither
  can overflow while the batch stays within ``max_batch``; if one does anyway, the world's
  overflow flags say so and :meth:`Physics.capacity_exceeded` reports it.
- C MuJoCo's plane–capsule contact frames are installed on both backends when
  :mod:`admissable_jax.envs` is imported (:mod:`.contact_frames`), before any step.
- Warp computes ``cfrc_ext`` inside its step when the model asks for it
  (``run_rne_postconstraint``); the JAX implementation calls ``mjx.rne_postconstraint``.
- Warp data has scratch fields shared by every world of a batch (the contact buffer and
  its counters), which JAX transformations must never batch: a ``lax.cond``/``while_loop``
  under ``vmap`` or a leaf-wise ``jnp.where`` would. So the data an env state carries
  leaves them out (``None``), and :meth:`Physics.step` lends them back from the template
  for the step. They are rewritten by every step's collision pass, so nothing is lost; and
  env states stay plain pytrees, every leaf per world, on both backends.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import mujoco
from mujoco import mjx
from mujoco.mjx._src import collision_driver, constraint

# Warp's overflow flags that mean a buffer was too small (not: solver iteration limits).
_CAPACITY_FLAGS = {
    "NEFC": "constraint rows per world (njmax)",
    "NJMAX_NNZ": "constraint Jacobian non-zeros (njmax_nnz)",
    "BROADPHASE": "collision candidates (naconmax)",
    "NARROWPHASE": "contacts (naconmax)",
    "CCD": "convex contacts (naccdmax)",
    "NVMAX": "active dofs (nvmax)",
    "EPA_HORIZON": "EPA horizon",
    "HFIELD": "height-field contacts",
}


def _capacity_mask() -> int:
    from mujoco.mjx.third_party.mujoco_warp._src.types import OverflowType

    mask = 0
    for name in _CAPACITY_FLAGS:
        mask |= int(getattr(OverflowType, name))
    return mask


class Physics:
    """A MuJoCo model on one backend (``impl``: ``"jax"`` or ``"warp"``)."""

    def __init__(self, mj_model: mujoco.MjModel, impl: str, frame_skip: int, max_batch: int,
                 contact_forces: bool, graph_mode: str | None = None):
        self.impl, self.frame_skip, self.max_batch = impl, frame_skip, max_batch
        self.contact_forces = contact_forces
        condim = collision_driver.make_condim(mj_model)
        self.contacts_per_world = int(condim.size)
        self.constraints_per_world = len(constraint.make_efc_type(mj_model, condim))
        if impl == "jax":
            self.model = mjx.put_model(mj_model, impl="jax")
            self.data_template = mjx.make_data(self.model, impl="jax")
            self._shared = {}  # JAX data has no fields shared across a batch
        elif impl == "warp":
            model = mjx.put_model(mj_model, impl="warp", graph_mode=_warp_graph_mode(graph_mode))
            if contact_forces:
                warp_options = model.opt._impl.replace(run_rne_postconstraint=True)
                model = model.replace(opt=model.opt.replace(_impl=warp_options))
            self.model = model
            self.data_template = mjx.make_data(
                mj_model, impl="warp",
                naconmax=max(1, self.contacts_per_world) * max_batch,
                njmax=max(1, self.constraints_per_world),
            )
            self._shared = _shared_fields(self.data_template)
            self._capacity_mask = _capacity_mask()
        else:
            raise ValueError(f"unknown physics implementation {impl!r}")

    def __repr__(self) -> str:
        sizes = ""
        if self.impl == "warp":
            sizes = f", naconmax {self.data_template._impl.naconmax}, njmax {self.data_template._impl.njmax}"
        return f"Physics({self.impl}, max_batch {self.max_batch}{sizes})"

    def data(self, qpos: jax.Array, qvel: jax.Array) -> mjx.Data:
        """Fresh data at (qpos, qvel) after ``mj_forward``, as Gymnasium's ``set_state``.

        MJX's kinematics writes normalized free-joint quaternions back into qpos; C MuJoCo
        normalizes a copy, so the raw qpos is kept (Gymnasium's reset obs holds it). C's
        ``mj_forward`` leaves contact forces at zero; Warp's, asked for them, fills them in,
        so they are zeroed here.
        """
        data = self.data_template.replace(qpos=qpos, qvel=qvel)
        data = mjx.forward(self.model, data).replace(qpos=qpos)
        if self.impl == "warp" and self.contact_forces:
            data = data.replace(_impl=data._impl.replace(cfrc_ext=jnp.zeros_like(data._impl.cfrc_ext)))
        return self._without_shared(data)

    def _without_shared(self, data: mjx.Data) -> mjx.Data:
        return data.replace(_impl=data._impl.replace(**dict.fromkeys(self._shared)))

    def _with_shared(self, data: mjx.Data) -> mjx.Data:
        return data.replace(_impl=data._impl.replace(**self._shared))

    def step(self, data: mjx.Data, ctrl: jax.Array) -> mjx.Data:
        """``frame_skip`` × ``mj_step`` with ``ctrl``, then contact forces if the env reads them."""
        data = self._with_shared(data).replace(ctrl=ctrl)
        data = jax.lax.fori_loop(0, self.frame_skip, lambda _, d: mjx.step(self.model, d), data)
        if self.contact_forces and self.impl == "jax":
            data = mjx.rne_postconstraint(self.model, data)
        return self._without_shared(data)

    def capacity_exceeded(self, data: mjx.Data) -> jax.Array:
        """Whether a buffer overflowed in this world since its data was made (always False on jax)."""
        if self.impl == "jax":
            return jnp.zeros((), bool)
        return (data._impl.overflow & self._capacity_mask) != 0

    def capacity_message(self) -> str:
        """One line for a run that exceeded Warp's buffers: what, and the setting to raise."""
        return (
            f"the Warp physics buffers overflowed ({', '.join(_CAPACITY_FLAGS.values())}: sized for "
            f"max_batch={self.max_batch} worlds, {self.contacts_per_world} contacts and "
            f"{self.constraints_per_world} constraint rows per world); more worlds were stepped at once "
            f"than the env's max_batch allows: raise max_batch, or use physics=jax"
        )


def _warp_graph_mode(name: str | None):
    """MuJoCo Warp's ``GraphMode`` member called ``name`` (``None``: MJX's default)."""
    if name is None:
        return None
    from mujoco.mjx.warp import types as warp_types

    return getattr(warp_types.GraphMode, name)


def _shared_fields(template: mjx.Data) -> dict[str, jax.Array]:
    """Warp's per-batch scratch arrays (``DATA_NON_VMAP``) in ``template``, by field name."""
    from mujoco.mjx.warp import types as warp_types

    return {
        name: getattr(template._impl, name)
        for name in sorted(warp_types.DATA_NON_VMAP)
        if isinstance(getattr(template._impl, name, None), jax.Array)
    }
