"""A fixed-capacity ring buffer of transitions that lives on the device.

It stores the raw observation and the index of the episode's missing set rather than the
2·d masked vector (half the memory, and the mask is applied once, at sampling). Where u's
sensors fail mid-episode (``fail_at``), each row also says how far past the failure its
observation was, so that the sampler hides u from the observation and the next one on either
side of it. Inserts
write a whole batch of parallel-env transitions with one ``dynamic_update_slice``; the
capacity is a multiple of that batch so a write never wraps mid-batch.
"""

from __future__ import annotations

import chex
import jax
import jax.numpy as jnp
from flax import struct


@struct.dataclass
class Transitions:
    """Transitions as stored: raw observations and u's index (masked at sampling)."""

    obs: jax.Array  # (..., d) raw observation
    set_index: jax.Array  # (...,) index of the episode's missing set
    action: jax.Array  # (..., A)
    reward: jax.Array  # (...,)
    next_obs: jax.Array  # (..., d) raw observation after the step (before any reset)
    terminated: jax.Array  # (...,) true termination only; truncation bootstraps
    # (...,) int32: env steps taken before obs minus the episode's failure step (u hidden in
    # obs from 0 on, in next_obs from -1 on); None where u is hidden from the start (the paper)
    steps_past_failure: jax.Array | None = None


@struct.dataclass
class ReplayBuffer:
    """The ring buffer: ``capacity`` rows of :class:`Transitions`, where the next write goes, how many are filled."""

    data: Transitions  # leading axis: capacity
    position: jax.Array  # () next row to write
    size: jax.Array  # () rows filled


def buffer_capacity(requested: int, insert_batch: int) -> int:
    """The largest multiple of ``insert_batch`` not above ``requested`` (at least one batch)."""
    return max(insert_batch, requested // insert_batch * insert_batch)


def init_buffer(capacity: int, obs_size: int, action_size: int, failing: bool = False) -> ReplayBuffer:
    """An empty buffer; ``failing``: with the column ``steps_past_failure`` (sensors that fail mid-episode)."""
    data = Transitions(
        obs=jnp.zeros((capacity, obs_size), jnp.float32),
        set_index=jnp.zeros((capacity,), jnp.int32),
        action=jnp.zeros((capacity, action_size), jnp.float32),
        reward=jnp.zeros((capacity,), jnp.float32),
        next_obs=jnp.zeros((capacity, obs_size), jnp.float32),
        terminated=jnp.zeros((capacity,), bool),
        steps_past_failure=jnp.zeros((capacity,), jnp.int32) if failing else None,
    )
    return ReplayBuffer(data=data, position=jnp.zeros((), jnp.int32), size=jnp.zeros((), jnp.int32))


def insert(buffer: ReplayBuffer, batch: Transitions) -> ReplayBuffer:
    """Write a batch of transitions (leading axis n, capacity % n == 0) at ``position``."""
    n = batch.reward.shape[0]
    capacity = buffer.data.reward.shape[0]
    chex.assert_equal(capacity % n, 0)
    data = jax.tree.map(
        lambda column, rows: jax.lax.dynamic_update_slice_in_dim(column, rows.astype(column.dtype), buffer.position, 0),
        buffer.data,
        batch,
    )
    return ReplayBuffer(
        data=data,
        position=(buffer.position + n) % capacity,
        size=jnp.minimum(buffer.size + n, capacity),
    )


def latest(buffer: ReplayBuffer, count: int) -> Transitions:
    """The ``count`` rows written last (at most the capacity), oldest first."""
    capacity = buffer.data.reward.shape[0]
    count = min(count, capacity)
    indices = (buffer.position - count + jnp.arange(count)) % capacity
    return jax.tree.map(lambda column: column[indices], buffer.data)


def sample(buffer: ReplayBuffer, rng: jax.Array, batch_size: int) -> Transitions:
    """``batch_size`` transitions drawn uniformly, with replacement, from the filled rows."""
    indices = jax.random.randint(rng, (batch_size,), 0, jnp.maximum(buffer.size, 1))
    return jax.tree.map(lambda column: column[indices], buffer.data)
