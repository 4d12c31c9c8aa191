"""Time and peak host memory of ``load_policy`` on a run or an experiment pair.

    JAX_PLATFORMS=cpu python benchmarks/load_policy_memory.py RUN_DIR

``load_policy`` (and so ``audit`` and ``video``) reads only the networks from a checkpoint
that also holds the replay buffers; until commit 6636fe8 it restored the whole training
state (benchmarks/README, *Reading a policy*, has both). One measurement per process: the
peak is the process's. Appends a record to benchmarks/results/load_policy_memory.jsonl.
"""

from __future__ import annotations

import time

import jax
import numpy as np

from admissable_jax.cli import fail
from admissable_jax.policies import load_policy
from common import append_record, peak_host_memory_mb, run_benchmark


def main(argv: list[str]) -> None:
    if any(arg in ("-h", "--help") for arg in argv):
        print(__doc__.strip())
        return
    if len(argv) != 1:
        fail("give one run directory (a train run's or an experiment pair's)")
    started = time.perf_counter()
    policy = load_policy(argv[0])
    seconds = time.perf_counter() - started
    checksum = sum(float(np.abs(np.asarray(leaf)).sum()) for leaf in jax.tree.leaves(policy.actor_params))
    record = {"run_dir": argv[0], "step": policy.step, "seconds": round(seconds, 2),
              "peak_host_memory_mb": round(peak_host_memory_mb()), "actor_abs_sum": checksum}
    print(record, "->", append_record("load_policy_memory", record))


if __name__ == "__main__":
    run_benchmark(main)
