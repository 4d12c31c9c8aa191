"""Where an experiment's (seed, mode) pairs run: the pair axis split over a device mesh.

The pairs lie along a one-axis :class:`jax.sharding.Mesh` (axis ``"pairs"``) over the chosen
devices, those of one process or, under ``jax.distributed``, of every process. Each device
runs its own pairs' train chunk and scoring round (``jax.shard_map`` of the vmapped
programs, or of the pairs one after another where the host loop asks: :meth:`PairPlacement.spread`;
the devices never talk to each other), and each process reads back, logs and
checkpoints only the pairs its own devices hold. A pair count that does not divide over the
devices is padded with copies of the last pair; their results are computed and dropped.
The host loop asks this module where things are; it never places anything itself.
"""

from __future__ import annotations

import dataclasses
import os
from typing import Any, Callable

import jax
import jax.numpy as jnp
import numpy as np
from jax.experimental import multihost_utils
from jax.sharding import Mesh, NamedSharding, PartitionSpec

PAIR_AXIS = "pairs"


def initialize_distributed() -> bool:
    """Join a multi-process JAX job when the environment names one; True when in one.

    Plain processes: ``JAX_COORDINATOR_ADDRESS`` (host:port of process 0, which JAX reads
    itself), ``JAX_NUM_PROCESSES`` and ``JAX_PROCESS_ID``. SLURM (``srun``, more than one
    task): JAX finds all three in SLURM's variables. Anything else: one process."""
    if jax.distributed.is_initialized():
        return True
    environ = os.environ
    if environ.get("JAX_COORDINATOR_ADDRESS"):
        missing = [name for name in ("JAX_NUM_PROCESSES", "JAX_PROCESS_ID") if not environ.get(name, "").isdigit()]
        if missing:
            raise ValueError(f"JAX_COORDINATOR_ADDRESS is set, so {' and '.join(missing)} must be too "
                             f"(non-negative integers)")
        jax.distributed.initialize(num_processes=int(environ["JAX_NUM_PROCESSES"]),
                                   process_id=int(environ["JAX_PROCESS_ID"]))
    elif int(environ.get("SLURM_NTASKS", "1") or 1) > 1 and "SLURM_STEP_NODELIST" in environ:
        jax.distributed.initialize()  # SLURM: JAX's cluster detection fills in every argument
    else:
        return False
    return True


@dataclasses.dataclass(frozen=True)
class PairPlacement:
    """``num_pairs`` pairs on a mesh of ``mesh.size`` devices, ``padded_pairs`` slots in all."""

    mesh: Mesh
    num_pairs: int

    @classmethod
    def over(cls, num_pairs: int, devices: int = 0) -> "PairPlacement":
        """The pairs over the first ``devices`` devices (0: every device of every process).

        ValueError (one line) for more devices than there are, or for a device subset
        under ``jax.distributed``, where every process must hold pairs."""
        available = jax.devices()
        if devices < 0 or devices > len(available):
            raise ValueError(f"devices must be 0 (all) or 1..{len(available)} here "
                             f"({len(available)} {available[0].platform} device(s)), got {devices}")
        if jax.process_count() > 1 and devices not in (0, len(available)):
            raise ValueError(f"under jax.distributed the pairs use every device of every process "
                             f"({len(available)}); leave devices=0, got {devices}")
        chosen = available[: devices or len(available)]
        return cls(Mesh(np.array(chosen), (PAIR_AXIS,)), num_pairs)

    # --- sizes ----------------------------------------------------------------------------
    @property
    def num_devices(self) -> int:
        return self.mesh.size

    @property
    def pairs_per_device(self) -> int:
        return -(-self.num_pairs // self.num_devices)

    @property
    def padded_pairs(self) -> int:
        return self.pairs_per_device * self.num_devices

    def describe(self) -> str:
        """One line: pairs, devices, processes, and the padding if any."""
        where = (f"{self.num_pairs} pair(s) on {self.num_devices} {self.mesh.devices.flat[0].platform} device(s)"
                 f"{f' of {jax.process_count()} processes' if jax.process_count() > 1 else ''}, "
                 f"{self.pairs_per_device} per device")
        padding = self.padded_pairs - self.num_pairs
        if padding:
            where += (f"; {self.num_pairs} does not divide over {self.num_devices}, so {padding} copy(ies) of the last "
                      f"pair pad the batch (computed, not recorded)")
        return where

    # --- placing and running ----------------------------------------------------------------
    @property
    def sharding(self) -> NamedSharding:
        """Leading (pair) axis split over the mesh: one prefix for a whole pytree."""
        return NamedSharding(self.mesh, PartitionSpec(PAIR_AXIS))

    def spread(self, per_pair: Callable[..., Any], in_turn: bool = False) -> Callable[..., Any]:
        """``per_pair`` vmapped over each device's own pairs, on every device of the mesh.
        Every argument and result has the (padded) pair axis first. ``in_turn``: each
        device's pairs one after another (``lax.map``) instead, for a program whose pairs
        loop for different numbers of steps (a scoring round runs until its last episode
        ends) on a device whose batched step costs each pair's work: vmapped, every pair
        would step until the slowest ends.

        Arrays with no elements (the candidate pool of a run that scores all of U) go around
        the ``shard_map``, not through it: they hold nothing, and jaxlib 0.11.2's Shardy
        crashes (a segfault) compiling a ``shard_map`` over two or more devices that passes
        one beside other arrays."""
        batched = (lambda *args: jax.lax.map(lambda pair: per_pair(*pair), args)) if in_turn else jax.vmap(per_pair)

        def spread_call(*args: Any) -> Any:
            leaves, args_tree = jax.tree.flatten(args)
            traced: dict[str, Any] = {}  # the results' tree and the global shape of each empty one

            def per_device(*held: jax.Array) -> list[jax.Array]:
                held_leaves = iter(held)
                local = [next(held_leaves) if leaf.size else jnp.zeros((self.pairs_per_device, *leaf.shape[1:]), leaf.dtype)
                         for leaf in leaves]
                results, traced["tree"] = jax.tree.flatten(batched(*jax.tree.unflatten(args_tree, local)))
                traced["empty"] = [None if result.size else jax.ShapeDtypeStruct((self.padded_pairs, *result.shape[1:]),
                                                                               result.dtype) for result in results]
                return [result for result in results if result.size]

            sharded = jax.shard_map(per_device, mesh=self.mesh, in_specs=PartitionSpec(PAIR_AXIS),
                                    out_specs=PartitionSpec(PAIR_AXIS), check_vma=False)
            held_results = iter(sharded(*[leaf for leaf in leaves if leaf.size]))
            return jax.tree.unflatten(traced["tree"], [next(held_results) if empty is None else jnp.zeros(empty.shape, empty.dtype)
                                                       for empty in traced["empty"]])

        return spread_call

    def jit(self, per_pair: Callable[..., Any], in_turn: bool = False) -> Callable[..., Any]:
        """``per_pair``, whose first argument and first result are a pair's training state,
        :meth:`spread` (``in_turn`` as there) and jitted with the pairs' sharding in and out
        and the state donated."""
        return jax.jit(self.spread(per_pair, in_turn), donate_argnums=0, in_shardings=self.sharding,
                       out_shardings=self.sharding)

    def place(self, values: np.ndarray) -> jax.Array:
        """A per-pair host array (``num_pairs`` first) as a global array on the mesh, padded
        with the last pair; every process passes the same values and sends its own part."""
        values = np.asarray(values)
        if values.shape[0] != self.num_pairs:
            raise ValueError(f"expected {self.num_pairs} per-pair values, got {values.shape[0]}")
        padded = np.concatenate([values, np.repeat(values[-1:], self.padded_pairs - self.num_pairs, axis=0)])
        return jax.make_array_from_callback(padded.shape, self.sharding, lambda index: padded[index])

    def refill_padding(self, state: Any) -> Any:
        """``state`` with its padding slots copies of the last pair again (after a restore,
        which pads or truncates the pair axis to this mesh's size)."""
        if self.padded_pairs == self.num_pairs:
            return state
        last = self.num_pairs - 1
        refill = lambda leaf: leaf.at[self.num_pairs:].set(jnp.broadcast_to(leaf[last], leaf[self.num_pairs:].shape))
        return jax.jit(lambda tree: jax.tree.map(refill, tree), out_shardings=self.sharding, donate_argnums=0)(state)

    # --- reading back -------------------------------------------------------------------------
    @property
    def local_pairs(self) -> list[int]:
        """The real pairs this process's devices hold, in pair order."""
        index_map = self.sharding.addressable_devices_indices_map((self.padded_pairs,))
        held = sorted({pair for (rows,) in index_map.values() for pair in range(*rows.indices(self.padded_pairs))})
        return [pair for pair in held if pair < self.num_pairs]

    def local_rows(self, tree: Any, pairs: list[int] | None = None) -> Any:
        """Pairs ``pairs`` (default: ``local_pairs``, all held by this process) of a
        pair-sharded pytree, as host arrays with that leading axis."""
        pairs = self.local_pairs if pairs is None else pairs
        # Wait here, where Ctrl-C and SIGTERM are handled while the device works: NumPy's
        # fetch below would hold them until it is done (minutes, for a scoring round on a CPU).
        jax.block_until_ready(tree)

        def fetch(leaf: jax.Array) -> np.ndarray:
            by_pair = {}
            for shard in leaf.addressable_shards:
                start = shard.index[0].indices(leaf.shape[0])[0]
                data = np.asarray(shard.data)
                by_pair.update((start + offset, data[offset]) for offset in range(data.shape[0]))
            return np.stack([by_pair[pair] for pair in pairs])

        return jax.tree.map(fetch, tree)

    def pair_state(self, tree: Any, pair: int) -> Any:
        """Pair ``pair``'s part of a pair-sharded pytree, on the device that holds it, read from
        that device's shard alone. (Indexing the global array instead compiles a gather in
        which every device takes part in an all-reduce; XLA:CPU deadlocked once with a pytree's
        worth of them in flight.) One program takes every leaf's row: indexed leaf by leaf, each
        leaf's shape compiled two small programs of its own. ValueError when no device of this
        process holds the pair."""
        def shard_and_row(leaf: jax.Array) -> tuple[jax.Array, int]:
            for shard in leaf.addressable_shards:
                start, stop, _ = shard.index[0].indices(leaf.shape[0])
                if start <= pair < stop:
                    return shard.data, pair - start
            raise ValueError(f"pair {pair} is not on a device of process {jax.process_index()}")

        leaves, structure = jax.tree.flatten(tree)
        shards, rows = zip(*map(shard_and_row, leaves)) if leaves else ((), ())
        return jax.tree.unflatten(structure, _rows_of(list(shards), list(rows)))

    def any_process(self, flag: bool) -> bool:
        """Whether ``flag`` holds in any process (every process gets the same answer, so
        they stop, pause or checkpoint together)."""
        if jax.process_count() == 1:
            return bool(flag)
        return bool(np.any(multihost_utils.process_allgather(np.asarray(flag, bool))))


@jax.jit
def _rows_of(leaves: list[jax.Array], rows: list[int]) -> list[jax.Array]:
    """Row ``rows[i]`` of each ``leaves[i]``, in one program."""
    return [leaf[row] for leaf, row in zip(leaves, rows)]
