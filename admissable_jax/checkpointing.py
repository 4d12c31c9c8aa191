"""Orbax checkpoints of the whole training state, keyed by env step.

A checkpoint holds the :class:`~admissable_jax.training.TrainState` pytree: network
parameters, optimizer states, p_miss, step counters, the RNG, the env states and the
replay buffer, so a resumed run continues exactly where the saved one stood. Orbax cannot
write zero-size arrays (``mjx.Data`` has several), so those leaves are left out and taken
from the run's own freshly built state on restore.
"""

from __future__ import annotations

import os

import jax
import orbax.checkpoint as ocp


class CheckpointError(RuntimeError):
    """A checkpoint that is missing, unreadable or does not fit the run's state."""


class Checkpoints:
    def __init__(self, directory: str, max_to_keep: int = 2):
        self.directory = os.path.abspath(directory)
        options = ocp.CheckpointManagerOptions(
            max_to_keep=max_to_keep, create=True, enable_async_checkpointing=False
        )
        self._manager = ocp.CheckpointManager(self.directory, options=options)

    def latest_step(self) -> int | None:
        return self._manager.latest_step()

    def save(self, step: int, state) -> None:
        """Write ``state`` as checkpoint ``step`` and wait until it is on disk."""
        self._manager.save(step, args=ocp.args.StandardSave(_non_empty_leaves(state)), force=True)
        self._manager.wait_until_finished()

    def restore(self, like) -> tuple[int, object]:
        """(step, state) of the latest checkpoint, shaped like the pytree ``like``."""
        step = self.latest_step()
        if step is None:
            raise CheckpointError(f"no checkpoint to resume from in {self.directory}")
        abstract = jax.tree.map(ocp.utils.to_shape_dtype_struct, _non_empty_leaves(like))
        try:
            saved = self._manager.restore(step, args=ocp.args.StandardRestore(abstract))
        except Exception as error:  # orbax raises many types for unreadable data
            first_line = str(error).strip().splitlines()[0] if str(error).strip() else type(error).__name__
            raise CheckpointError(
                f"checkpoint {step} in {self.directory} cannot be restored: {first_line}"
            ) from error
        leaves, treedef = jax.tree.flatten(like)
        leaves = [saved.get(str(i), leaf) for i, leaf in enumerate(leaves)]
        return step, jax.tree.unflatten(treedef, leaves)

    def close(self) -> None:
        self._manager.close()


def _non_empty_leaves(state) -> dict[str, jax.Array]:
    """The pytree's leaves with at least one element, keyed by their flat index."""
    return {str(i): leaf for i, leaf in enumerate(jax.tree.leaves(state)) if leaf.size > 0}
