"""Orbax checkpoints of the whole training state, keyed by env step.

A checkpoint holds the :class:`~admissable_jax.training.TrainState` pytree: network
parameters, optimizer states, p_miss, step counters, the RNG, the env states and the
replay buffer, so a resumed run continues exactly where the saved one stood. Orbax cannot
write zero-size arrays (``mjx.Data`` has several), so those leaves are left out and taken
from the run's own freshly built state on restore. A checkpoint written before a mode's flag
was appended to the state (``greedy``, mode ``worst``'s, 2026-12-08) lacks only that last
bool leaf: it restores with the flag False, as every run of that version had it.
"""

from __future__ import annotations

import dataclasses
import os
import shutil
from typing import Any, Callable

import jax
import jax.numpy as jnp
import orbax.checkpoint as ocp

from admissable_jax.errors import USAGE_ERROR, RunFailed


class CheckpointError(RunFailed):
    """A checkpoint that is missing, unreadable or does not fit the run's state."""


class NoSuchCheckpoint(CheckpointError):
    """A checkpoint step asked for (``resume_step=``, ``step=``) that was never saved: a bad
    setting, so it exits as one (status 2, as ``audit steps=`` does)."""

    exit_status = USAGE_ERROR


class OtherStateLayout(CheckpointError):
    """A checkpoint whose state holds other arrays than this version's
    :class:`~admissable_jax.training.TrainState` (one written before a field was added):
    every checkpoint of the run is alike, so no older one is offered."""


class Checkpoints:
    def __init__(self, directory: str, max_to_keep: int = 2):
        self.directory = os.path.abspath(directory)
        options = ocp.CheckpointManagerOptions(
            max_to_keep=max_to_keep, create=True, enable_async_checkpointing=False
        )
        self._manager = ocp.CheckpointManager(self.directory, options=options,
                                              item_handlers=ocp.StandardCheckpointHandler())

    def latest_step(self) -> int | None:
        return self._manager.latest_step()

    def save(self, step: int, state) -> None:
        """Write ``state`` as checkpoint ``step`` and wait until it is on disk.

        A write that fails (a full disk, most often) leaves no partial checkpoint behind:
        orbax's temporary folder is removed, earlier checkpoints stay as they were, and a
        one-line CheckpointError names the directory and the newest checkpoint kept."""
        try:
            self._manager.save(step, args=ocp.args.StandardSave(_non_empty_leaves(state)), force=True)
            self._manager.wait_until_finished()
        except Exception as error:  # orbax wraps the OSError in several layers
            for name in os.listdir(self.directory):
                if ".orbax-checkpoint-tmp" in name:
                    shutil.rmtree(os.path.join(self.directory, name), ignore_errors=True)
            self._manager.reload()
            kept = self._manager.latest_step()
            kept = f"checkpoint {kept} is intact" if kept is not None else "no earlier checkpoint"
            raise CheckpointError(
                f"cannot write checkpoint {step} in {self.directory}: {_reason(error)}; the partial write was "
                f"removed and {kept}; free space, then continue with resume=true"
            ) from error

    @staticmethod
    def steps_in(directory: str) -> list[int]:
        """The checkpoint steps saved in ``directory`` (without opening any)."""
        if not os.path.isdir(directory):
            return []
        return sorted(int(name) for name in os.listdir(directory) if name.isdigit())

    def step_to_restore(self, step: int | None = None) -> int:
        """``step`` if it was saved, or the latest saved step for ``None``; CheckpointError otherwise."""
        steps = self._manager.all_steps()
        if not steps:
            raise CheckpointError(f"no checkpoint to resume from in {self.directory}")
        if step is None:
            return max(steps)
        if step not in steps:
            raise NoSuchCheckpoint(f"no checkpoint {step} in {self.directory}; saved: {sorted(steps)}")
        return step

    def restore(self, like, step: int | None = None, resizable_leading_axis: bool = False) -> tuple[int, object]:
        """(step, state) of checkpoint ``step`` (default: the latest), shaped and placed like
        ``like`` (a state, or its ``jax.eval_shape``, with shardings or without). With
        ``resizable_leading_axis`` the saved leading axis (the pairs, padded to the saving
        run's device count) may differ from ``like``'s: it is cut or zero-padded to fit.

        A checkpoint that cannot be read raises a one-line CheckpointError naming it and the
        newest older checkpoint that can (pass that as ``step`` to continue from it).
        Checkpoints newer than a chosen older ``step`` are moved aside to
        ``<directory>-superseded/`` (never deleted), since the run continues from ``step``.
        """
        step, state = self.read(like, step, resizable_leading_axis)
        self._set_aside_newer_than(step)
        return step, state

    def read(self, like, step: int | None = None, resizable_leading_axis: bool = False,
             part: Callable[[Any], Any] | None = None) -> tuple[int, object]:
        """:meth:`restore` without moving anything: for reading a run (a policy, an audit)
        rather than continuing it. ``part`` (e.g. ``lambda state: state.sac``) reads only
        that subtree of ``like`` from disk and returns it, not the replay buffer beside it
        (GBs in a 1M-step run, more in an experiment's)."""
        step = self.step_to_restore(step)
        try:
            return step, self._restore(like, step, resizable_leading_axis, part)
        except OtherStateLayout:
            raise
        except CheckpointError as error:
            older = sorted((s for s in self._manager.all_steps() if s < step), reverse=True)
            intact = next((s for s in older if self._readable(like, s, resizable_leading_axis, part)), None)
            offer = (f"checkpoint {intact} is intact: resume with resume_step={intact}" if intact is not None
                     else "no older checkpoint is intact")
            raise CheckpointError(f"{error}; {offer}") from error.__cause__

    def _restore(self, like, step: int, resizable_leading_axis: bool = False, part: Callable[[Any], Any] | None = None):
        leaves, treedef = jax.tree.flatten(like)
        wanted = {id(leaf) for leaf in jax.tree.leaves(part(like))} if part else {id(leaf) for leaf in leaves}
        abstract = self._without_flags_added_since(step, {key: _placed_shape(leaf)
                                                          for key, leaf in _non_empty_leaves(like).items()})
        try:
            resize = resizable_leading_axis and self._differs_in_leading_axis_only(abstract, step)
            if part:
                saved = self._read_part(step, {key: shape for key, shape in abstract.items()
                                               if id(leaves[int(key)]) in wanted}, strict=not resize)
            else:
                saved = self._manager.restore(step, args=ocp.args.StandardRestore(abstract, strict=not resize))
        except Exception as error:  # orbax raises many types for unreadable data
            self._check_layout(step, abstract)
            first_line = str(error).strip().splitlines()[0][:200] if str(error).strip() else type(error).__name__
            raise CheckpointError(
                f"checkpoint {step} in {self.directory} is corrupt or does not fit this run ({first_line})"
            ) from error
        # Zero-size leaves were not saved: the run's own (or, for an abstract ``like``, zeros).
        leaves = [leaf if id(leaf) not in wanted else saved[str(i)] if str(i) in saved
                  else jnp.zeros(leaf.shape, leaf.dtype) for i, leaf in enumerate(leaves)]
        restored = jax.tree.unflatten(treedef, leaves)
        return part(restored) if part else restored

    def _read_part(self, step: int, abstract: dict, strict: bool) -> dict:
        """The leaves of checkpoint ``step`` that ``abstract`` names, and nothing else read
        from disk: orbax's partial restore, which its StandardCheckpointHandler (the one
        the manager writes with; the same files) does not offer."""
        restore_args = ocp.checkpoint_utils.construct_restore_args(abstract)
        if not strict:
            restore_args = jax.tree.map(lambda arg: dataclasses.replace(arg, strict=False), restore_args)
        reader = ocp.Checkpointer(ocp.PyTreeCheckpointHandler())
        try:
            return reader.restore(os.path.join(self.directory, str(step), ocp.checkpoint_manager.DEFAULT_ITEM_NAME),
                                  args=ocp.args.PyTreeRestore(item=abstract, restore_args=restore_args,
                                                              partial_restore=True))
        finally:
            reader.close()

    def _without_flags_added_since(self, step: int, abstract: dict) -> dict:
        """``abstract`` less the bool leaves that checkpoint ``step`` lacks where they all come
        after every leaf it holds: flags appended to the state since it was written, which
        restore as False (zeros), the only value that version knew. Any other difference
        stays, for the restore to refuse (:meth:`_check_layout`)."""
        try:
            saved = set(self._manager.item_metadata(step))
        except Exception:  # unreadable metadata: the restore itself says what is wrong
            return abstract
        missing = set(abstract) - saved
        appended_flags = (saved and saved < set(abstract) and min(map(int, missing)) > max(map(int, saved))
                          and all(abstract[key].dtype == bool for key in missing))
        if not appended_flags:
            return abstract
        return {key: shape for key, shape in abstract.items() if key not in missing}

    def _check_layout(self, step: int, abstract: dict) -> None:
        """OtherStateLayout where checkpoint ``step`` holds another number of arrays than
        ``abstract`` (nothing where its metadata cannot be read: then it is corrupt)."""
        try:
            saved = len(self._manager.item_metadata(step))
        except Exception:  # unreadable metadata: the caller's corrupt-checkpoint message says so
            return
        if saved != len(abstract):
            raise OtherStateLayout(
                f"checkpoint {step} in {self.directory} holds {saved} arrays where this version's training state has "
                f"{len(abstract)}: another version of admissable_jax wrote it, so it cannot be resumed here (its "
                "policy still loads: load_policy, audit, video)")

    def _differs_in_leading_axis_only(self, abstract: dict, step: int) -> bool:
        """Whether checkpoint ``step`` holds the same leaves as ``abstract`` with the same
        shapes but for the leading axis (which then differs in every leaf)."""
        saved = self._manager.item_metadata(step)
        if set(saved) != set(abstract):
            return False
        shapes = [(tuple(saved[key].shape), tuple(abstract[key].shape)) for key in abstract]
        return (all(len(a) == len(b) > 0 and a[1:] == b[1:] for a, b in shapes)
                and len({a[0] for a, _ in shapes}) == 1 and any(a[0] != b[0] for a, b in shapes))

    def _readable(self, like, step: int, resizable_leading_axis: bool = False,
                  part: Callable[[Any], Any] | None = None) -> bool:
        try:
            self._restore(like, step, resizable_leading_axis, part)
        except CheckpointError:
            return False
        return True

    def _set_aside_newer_than(self, step: int) -> None:
        newer = [later for later in self._manager.all_steps() if later > step]
        if not newer:
            return
        aside = self.directory + "-superseded"
        os.makedirs(aside, exist_ok=True)
        for later in newer:
            shutil.move(os.path.join(self.directory, str(later)), os.path.join(aside, str(later)))
        self._manager.reload()

    def close(self) -> None:
        self._manager.close()


def _placed_shape(leaf) -> jax.ShapeDtypeStruct:
    """The leaf's shape, dtype and sharding; one without a sharding goes to this process's
    first device (not where the saving run's devices were, which may not exist here)."""
    shape = ocp.utils.to_shape_dtype_struct(leaf)
    if getattr(shape, "sharding", None) is None:
        shape = jax.ShapeDtypeStruct(shape.shape, shape.dtype,
                                     sharding=jax.sharding.SingleDeviceSharding(jax.local_devices()[0]))
    return shape


def _non_empty_leaves(state) -> dict[str, jax.Array]:
    """The pytree's leaves with at least one element, keyed by their flat index."""
    return {str(i): leaf for i, leaf in enumerate(jax.tree.leaves(state)) if leaf.size > 0}


def _reason(error: BaseException) -> str:
    """The root OSError's message in an exception chain (e.g. "No space left on device"),
    else the first line of the error itself."""
    seen = error
    while seen is not None:
        if isinstance(seen, OSError) and seen.strerror:
            return seen.strerror
        seen = seen.__cause__ or seen.__context__
    text = str(error).strip()
    return text.splitlines()[0][:200] if text else type(error).__name__
