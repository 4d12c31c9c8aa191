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
- C MuJoCo's plane–capsule contact frames are installed on both backends when this module
  is imported (:mod:`.contact_frames`), before any env is built, so before any step.
- Warp is the ``mujoco-warp`` package, in its deterministic mode unless the env's options
  say otherwise (:mod:`.warp_package`): so a GPU can repeat a run bit for bit.
- Warp computes ``cfrc_ext`` inside its step when the model asks for it
  (``run_rne_postconstraint``); the JAX implementation calls ``mjx.rne_postconstraint``.
- Warp data has scratch fields shared by every world of a batch (the contact buffer and
  its counters), which JAX transformations must never batch: a ``lax.cond``/``while_loop``
  under ``vmap`` or a leaf-wise ``jnp.where`` would. So the data an env state carries
  leaves them out (``None``), and :meth:`Physics.step` lends them back from the template
  for the step. They are rewritten by every step's collision pass, so nothing is lost; and
  env states stay plain pytrees, every leaf per world, on both backends.
- A Warp step is an FFI call that updates its data in place, over one flat batch of worlds:
  under nested ``vmap`` (an experiment's pairs × envs) MJX flattens the batch inside every
  ``mj_step``, and XLA then copies each of the data's fields into and out of the call, every
  frame. So a Warp :meth:`Physics.step` flattens the batch once per env step instead
  (:func:`in_one_flat_batch`).
- On a CPU, a JAX physics call costs 2.5-3× as much per world once its worlds' data pass
  about 256 KiB (measured on 2 cores: Hopper between 32 and 48 worlds, Walker2d between 16
  and 24, Ant between 12 and 16; ``benchmarks/NOTES.md``), so a larger batch (an
  experiment's pairs × envs, a scoring round's slots) is flattened the same way and stepped
  in pieces below that size, one after another (``EnvOptions.worlds_per_call``).
"""

from __future__ import annotations

import contextlib
import io
import math
from typing import Any, Callable

import jax
import jax.numpy as jnp
import mujoco
from jax.custom_batching import custom_vmap

from admissable_jax.envs import warp_package

warp_package.use_package()  # before MJX is imported: MJX's Warp bridge then runs the mujoco-warp package
# MJX prints an import failure when warp-lang is absent; physics=jax needs no Warp (and
# physics=warp says clearly when it is missing), so keep that line out of users' output.
with contextlib.redirect_stdout(io.StringIO()):
    from mujoco import mjx  # noqa: E402
from mujoco.mjx._src import collision_driver, constraint  # noqa: E402
from mujoco.mjx._src import forward as mjx_forward  # noqa: E402
from mujoco.mjx._src import scan as mjx_scan  # noqa: E402
from mujoco.mjx._src.types import IntegratorType  # noqa: E402

from admissable_jax.branching import broadcast_unbatched  # noqa: E402
from admissable_jax.envs import contact_frames  # noqa: E402
from admissable_jax.envs.options import CUDA_GRAPH_MODES, warp_installed  # noqa: E402

contact_frames.install()
if warp_installed():
    import warp

    warp.config.quiet = True  # no banner in users' output
    warp.config.log_level = max(warp.config.log_level, warp.LOG_WARNING)  # nor a line per kernel module
    contact_frames.install_warp()  # before the first Warp collision kernel is built

# The most data a JAX physics call steps at once on a CPU (module docstring).
CPU_CALL_BYTES = 256 * 1024

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
                 contact_forces: bool, graph_mode: str | None = None, *, deterministic: bool,
                 worlds_per_call: int = 0):
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
            if graph_mode in CUDA_GRAPH_MODES and jax.default_backend() == "cpu":
                raise ValueError(f"graph_mode={graph_mode!r} captures CUDA graphs, which MuJoCo Warp on the CPU has not: "
                                 "use graph_mode None (MJX's default) or 'NONE' there")
            warp_package.set_deterministic(deterministic)
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
        # A batched step costs about the sum of its worlds' work only for the JAX physics on a
        # CPU; Warp's step is kernel launches, an accelerator's about the same for any batch.
        self.steps_cost_each_world = impl == "jax" and jax.default_backend() == "cpu"
        self.worlds_per_call = _worlds_per_call(impl, worlds_per_call, self.data_template, self.steps_cost_each_world)
        # Jitted, so that one world's data and step are traced once per env and argument
        # shape: each program that resets or steps an env, and each vmap rule below, reuses them
        # (a Hopper run's two programs on the JAX physics traced in 11 CPU-s instead of 17-19 here:
        # benchmarks/program_build.py).
        self._data, self._step = jax.jit(self._world_data), jax.jit(self._world_step)
        # Warp's FFI calls, and JAX's in pieces: one flat batch whatever the vmaps (module docstring).
        if impl == "warp" or self.worlds_per_call:
            self._data, self._step = (in_one_flat_batch(world_fn, self.worlds_per_call)
                                      for world_fn in (self._data, self._step))

    def __repr__(self) -> str:
        sizes = ""
        if self.impl == "warp":
            sizes = f", naconmax {self.data_template._impl.naconmax}, njmax {self.data_template._impl.njmax}"
        if self.worlds_per_call:
            sizes = f", {self.worlds_per_call} worlds per call"
        return f"Physics({self.impl}, max_batch {self.max_batch}{sizes})"

    def data(self, qpos: jax.Array, qvel: jax.Array) -> mjx.Data:
        """Fresh data at (qpos, qvel), ready to step and to observe, as after Gymnasium's
        ``set_state`` (``mj_forward``).

        Only the kinematics runs (body positions: Ant's reward reads the torso's before a
        step), not the whole ``mj_forward``: every other quantity it would compute (contacts,
        constraint forces, accelerations) is recomputed from (qpos, qvel) by the next
        ``mj_step``'s own ``forward`` and read by nothing before it, and contact forces read
        as zero, as in Gymnasium after a reset. This keeps a second copy of ``forward`` (and its
        compile time) out of every program that resets envs. MJX's kinematics writes
        normalized free-joint quaternions back into qpos; C MuJoCo normalizes a copy, so the
        raw qpos is kept (Gymnasium's reset obs holds it).
        """
        return self._data(qpos, qvel)

    def _world_data(self, qpos: jax.Array, qvel: jax.Array) -> mjx.Data:
        data = self.data_template.replace(qpos=qpos, qvel=qvel)
        data = mjx.kinematics(self.model, data).replace(qpos=qpos)
        return self._without_shared(data)

    def _without_shared(self, data: mjx.Data) -> mjx.Data:
        return data.replace(_impl=data._impl.replace(**dict.fromkeys(self._shared)))

    def _with_shared(self, data: mjx.Data) -> mjx.Data:
        return data.replace(_impl=data._impl.replace(**self._shared))

    def step(self, data: mjx.Data, ctrl: jax.Array) -> mjx.Data:
        """``frame_skip`` × ``mj_step`` with ``ctrl``, then contact forces if the env reads them."""
        return self._step(data, ctrl)

    def _world_step(self, data: mjx.Data, ctrl: jax.Array) -> mjx.Data:
        data = self._with_shared(data).replace(ctrl=ctrl)
        data = jax.lax.fori_loop(0, self.frame_skip, lambda _, d: self._mj_step(d), data)
        if self.contact_forces and self.impl == "jax":
            data = mjx.rne_postconstraint(self.model, data)
        return self._without_shared(data)

    def _mj_step(self, data: mjx.Data) -> mjx.Data:
        """One ``mj_step``: ``mjx.step``, except RK4 on the JAX backend (all three envs)."""
        if self.impl == "jax" and self.model.opt.integrator == IntegratorType.RK4:
            return _rungekutta4_step(self.model, data)
        return mjx.step(self.model, data)

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


def _rungekutta4_step(model: mjx.Model, data: mjx.Data) -> mjx.Data:
    """``mjx.step`` for an RK4 model (all three envs), compiled with one copy of ``forward``.

    ``mjx.step`` runs ``mjx.forward``, then ``mjx.rungekutta4`` (C MuJoCo's
    ``mj_RungeKutta``): three more ``forward`` stages in a scan that MJX unrolls, so a
    compiled step holds four copies of ``forward`` (kinematics, collision, constraints,
    solver), and XLA:CPU spends most of a program's compile time on them
    (``benchmarks/step_compile.py``: Hopper 33 s → 18 s, record ``step_compile.jsonl``).
    Here all four stages are one scan of four ``forward`` calls: stage 0 is the plain
    ``forward`` of ``data``, stages 1-3 are MJX's, with the same
    arithmetic in the same order. XLA fuses the two programs differently, so they agree to
    float32 rounding, not bitwise (after 21 steps: |Δqpos| ≤ 3e-7, |Δqvel| ≤ 2e-5).
    """
    a, b = mjx_forward._RK4_A, mjx_forward._RK4_B  # pylint: disable=protected-access
    dt = model.opt.timestep
    stage_times = data.time + jnp.tril(a).sum(axis=0) * dt
    integrate = lambda *args: mjx_forward._integrate_pos(*args, dt=dt)  # pylint: disable=protected-access

    def stage(carry, row):
        sums, previous_qvel, previous, start = carry
        first, a_ii, b_i, time = row
        # stage i > 0 starts from stage 0's state, moved along the previous stage's derivatives
        qpos = mjx_scan.flat(model, integrate, "jqv", "q", model.jnt_type, start.qpos, a_ii * previous_qvel)
        qvel = start.qvel + a_ii * previous.qacc * dt
        act = start.act + a_ii * previous.act_dot * dt
        pick = lambda original, moved: jnp.where(first, original, moved)
        stage_data = mjx.forward(model, previous.replace(
            qpos=pick(previous.qpos, qpos), qvel=pick(previous.qvel, qvel), act=pick(previous.act, act),
            time=pick(previous.time, time),
        ))
        start = jax.tree.map(pick, stage_data, start)
        terms = (stage_data.qvel, stage_data.qacc, stage_data.act_dot)
        sums = jax.tree.map(lambda total, term: pick(b_i * term, total + b_i * term), sums, terms)
        return (sums, stage_data.qvel, stage_data, start), None

    rows = (jnp.arange(4) == 0, jnp.concatenate([jnp.zeros(1), jnp.diag(a)]), jnp.asarray(b),
            jnp.concatenate([data.time[None], stage_times]))
    zeros = jax.tree.map(jnp.zeros_like, (data.qvel, data.qacc, data.act_dot))
    (sums, _, last, start), _ = jax.lax.scan(stage, (zeros, data.qvel, data, data), rows)
    qvel_sum, qacc_sum, act_dot_sum = sums
    last = last.replace(qpos=start.qpos, qvel=start.qvel, act=start.act, time=start.time)
    return mjx_forward._advance(model, last, act_dot_sum, qacc_sum, qvel_sum)  # pylint: disable=protected-access


def _worlds_per_call(impl: str, asked: int, data_template: mjx.Data, steps_cost_each_world: bool) -> int | None:
    """The most worlds one physics call steps (None: the whole batch): ``asked``, or where a
    batched step costs each world's work (a CPU's JAX physics) the largest power of two whose
    worlds' data fit :data:`CPU_CALL_BYTES`."""
    if impl == "warp":
        if asked:
            raise ValueError(f"worlds_per_call={asked} splits the JAX physics' batch; MuJoCo Warp steps one flat batch "
                             "(leave worlds_per_call at 0, or use physics=jax)")
        return None
    if asked:
        return asked
    if not steps_cost_each_world:
        return None
    world_bytes = sum(leaf.nbytes for leaf in jax.tree.leaves(data_template))
    return 2 ** int(math.log2(max(1, CPU_CALL_BYTES // world_bytes)))


def in_one_flat_batch(world_fn: Callable[..., Any], worlds_per_call: int | None = None) -> Callable[..., Any]:
    """``world_fn`` (one world's arrays in, one world's out) that, under any nesting of
    ``vmap``, runs as a single ``vmap`` over one flat batch of all the worlds, or with
    ``worlds_per_call`` as ``vmap``s over pieces of at most that many worlds, one after another.

    Each vmap level's batch axis is merged into the next one's by a reshape around the whole
    call, not inside it, and unbatched inputs are broadcast to the batch (a Warp call writes
    every world's data). Results equal ``world_fn``'s under the same vmaps, world by world
    (to float rounding, where XLA vectorises the flat batch or a piece otherwise).
    """

    @custom_vmap
    def worlds(*args):  # every leaf: worlds on its leading axis
        return _in_pieces(jax.vmap(world_fn), args, worlds_per_call)

    @worlds.def_vmap
    def worlds_batched(axis_size: int, in_batched: list[Any], *args):
        outer = broadcast_unbatched(axis_size, args, tuple(in_batched))
        worlds_each = jax.tree.leaves(outer)[0].shape[1]
        merged = worlds(*jax.tree.map(lambda leaf: leaf.reshape((axis_size * worlds_each, *leaf.shape[2:])), outer))
        out = jax.tree.map(lambda leaf: leaf.reshape((axis_size, worlds_each, *leaf.shape[1:])), merged)
        return out, jax.tree.map(lambda _: True, out)

    @custom_vmap
    def world(*args):
        return world_fn(*args)

    @world.def_vmap
    def world_batched(axis_size: int, in_batched: list[Any], *args):
        out = worlds(*broadcast_unbatched(axis_size, args, tuple(in_batched)))
        return out, jax.tree.map(lambda _: True, out)

    return world


def _in_pieces(batch_fn: Callable[..., Any], args: tuple[Any, ...], worlds_per_call: int | None) -> Any:
    """``batch_fn(*args)`` (every leaf: worlds on its leading axis) in as few even pieces of
    at most ``worlds_per_call`` worlds as hold them, one after another (``lax.map``); the
    last piece is padded with copies of the last world, whose results are dropped."""
    num_worlds = jax.tree.leaves(args)[0].shape[0]
    if worlds_per_call is None or num_worlds <= worlds_per_call:
        return batch_fn(*args)
    num_pieces = -(-num_worlds // worlds_per_call)
    piece = -(-num_worlds // num_pieces)  # even pieces: fewer padded worlds than pieces
    padded = num_pieces * piece

    def split(leaf: jax.Array) -> jax.Array:
        leaf = jnp.concatenate([leaf, jnp.repeat(leaf[-1:], padded - num_worlds, axis=0)])
        return leaf.reshape((num_pieces, piece, *leaf.shape[1:]))

    out = jax.lax.map(lambda pieces_args: batch_fn(*pieces_args), jax.tree.map(split, args))
    return jax.tree.map(lambda leaf: leaf.reshape((padded, *leaf.shape[2:]))[:num_worlds], out)


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
