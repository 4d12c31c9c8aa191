"""The memory a run needs on its device, counted before anything is allocated.

The training state's bytes come from its abstract shapes, the compiled programs'
temporaries from XLA's memory analysis; a run that would not fit stops with a one-line
message before it starts. With the pairs spread over several devices each holds its share
of the state; CPU "devices" share the host's memory, so there the shares add up.
"""

from __future__ import annotations

import dataclasses

import jax
import psutil

from admissable_jax.errors import RunFailed


class MemoryBudgetExceeded(RunFailed):
    """The compiled programs and the training state would not fit in this device's memory."""


@dataclasses.dataclass
class MemoryBudget:
    """Bytes the run needs on its device, from the compiled programs, against what it has."""

    state_bytes: int
    chunk_temp_bytes: int
    score_temp_bytes: int
    available_bytes: int
    device: str
    devices_sharing: int = 1  # devices whose needs come out of the same memory (CPU devices)

    @property
    def needed_bytes(self) -> int:
        # The state stays live; the two programs run one after the other, so their
        # temporaries do not add up.
        return self.devices_sharing * (self.state_bytes + max(self.chunk_temp_bytes, self.score_temp_bytes))

    def describe(self) -> str:
        gib = lambda b: f"{b / 2**30:.2f} GiB"
        shared = f" x {self.devices_sharing} devices" if self.devices_sharing > 1 else ""
        return (
            f"memory on {self.device}{shared}: training state {gib(self.state_bytes)} + largest program "
            f"temporaries {gib(max(self.chunk_temp_bytes, self.score_temp_bytes))} "
            f"(train chunk {gib(self.chunk_temp_bytes)}, scoring {gib(self.score_temp_bytes)}) "
            f"= {gib(self.needed_bytes)} of {gib(self.available_bytes)} available"
        )


def memory_budget(abstract_state, compiled_chunk, compiled_score, num_devices: int = 1) -> MemoryBudget:
    """What the state and the compiled programs need on each of ``num_devices`` devices
    (each holds 1/num_devices of the state), and what one device has free."""
    device = jax.local_devices()[0]
    total_state_bytes = sum(leaf.size * leaf.dtype.itemsize for leaf in jax.tree.leaves(abstract_state))
    stats = device.memory_stats() if device.platform != "cpu" else None
    if stats and "bytes_limit" in stats:
        available = int(stats["bytes_limit"]) - int(stats.get("bytes_in_use", 0))
    else:
        available = int(psutil.virtual_memory().available)
    temp = lambda compiled: int(getattr(compiled.memory_analysis(), "temp_size_in_bytes", 0) or 0)
    sharing = min(num_devices, jax.local_device_count()) if device.platform == "cpu" else 1
    return MemoryBudget(total_state_bytes // num_devices, temp(compiled_chunk), temp(compiled_score), available,
                        f"{device.platform}:{getattr(device, 'device_kind', '')}", sharing)
