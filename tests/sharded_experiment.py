"""Run by tests/test_sharding.py in a process of its own with 4 CPU devices
(``XLA_FLAGS=--xla_force_host_platform_device_count=4``, which must be set before JAX
starts): one point-mass experiment of 4 pairs on 4 devices and on 1, then its checkpoint
read back onto 3 devices (4 pairs padded to 6) and trained on there; the padding slots
that such a restore leaves, refilled with the last pair; one pair's policy read from that
padded checkpoint; and a function spread over the devices whose arguments and results hold
an empty array.

    python tests/sharded_experiment.py OUT

writes ``OUT/four`` (4 devices), ``OUT/one`` (1 device) and ``OUT/report.json``: the
largest difference between the state saved on 4 devices and the state restored onto 3,
leaf by leaf, and what the resumed run printed. The test reads the report and the files.
"""

from __future__ import annotations

import contextlib
import io
import json
import os
import sys

import jax
import numpy as np

from admissable_jax.cli import exit_with
from admissable_jax.experiment import ExperimentConfig, run_experiment
from admissable_jax.placement import PairPlacement
from admissable_jax.policies import load_policy

EXPERIMENT = dict(
    env="point_mass", seeds=2, modes="adversarial,uniform", score_every=1000, num_envs=4, physics="jax",
    learning_starts=500, episode_length=50, score_episodes=2, batch_size=64, buffer_size=5000, hidden_size=32,
    checkpoint_every=1, progress=False,
)


def largest_difference(first, second) -> float:
    """The largest absolute difference over every leaf of two states (inf if shapes differ)."""
    def difference(a, b):
        a, b = np.asarray(a), np.asarray(b)
        if a.shape != b.shape:
            return np.inf
        return float(np.max(np.abs(a.astype(np.float64) - b.astype(np.float64)))) if a.size else 0.0
    return max(jax.tree.leaves(jax.tree.map(difference, first, second)))


def main(out: str) -> None:
    assert jax.device_count() == 4, f"needs 4 devices, has {jax.device_count()}"
    four = run_experiment(ExperimentConfig(**EXPERIMENT, total_steps=2000, devices=4, out=os.path.join(out, "four")))
    run_experiment(ExperimentConfig(**EXPERIMENT, total_steps=2000, devices=1, out=os.path.join(out, "one")))
    # Onto 3 devices: nothing left to train at 2000, so this only restores (4 pairs padded to 6).
    printed = io.StringIO()
    with contextlib.redirect_stderr(printed):
        restored = run_experiment(ExperimentConfig(**EXPERIMENT, total_steps=2000, devices=3, resume=True,
                                                   out=os.path.join(out, "four")))
        resumed = run_experiment(ExperimentConfig(**EXPERIMENT, total_steps=3000, devices=3, resume=True,
                                                  out=os.path.join(out, "four")))
    # What a restore onto a larger padded mesh leaves in the padding slots (zeros), refilled.
    placement = PairPlacement.over(3, 2)
    restored_padding = jax.device_put(np.array([[0.0], [1.0], [2.0], [0.0]]), placement.sharding)
    # An empty leaf (a run's candidate pool when all of U is scored) goes around the
    # shard_map: jaxlib 0.11.2 crashes compiling one that passes it beside other arrays.
    spread = placement.spread(lambda tree: {"pool": tree["pool"], "doubled": 2 * tree["x"]})
    tree = jax.device_put({"pool": np.zeros((4, 0), np.int32), "x": np.arange(4.0)}, placement.sharding)
    (shard_map,) = [eqn for eqn in jax.make_jaxpr(spread)(tree).eqns if eqn.primitive.name == "shard_map"]
    spread_out = jax.jit(spread)(tree)
    report = {
        "shard_map_operand_sizes": [var.aval.size for var in [*shard_map.invars, *shard_map.outvars]],
        "spread_out": {name: [list(leaf.shape), np.asarray(leaf).ravel().tolist()] for name, leaf in spread_out.items()},
        "refilled": np.asarray(placement.refill_padding(restored_padding)).ravel().tolist(),
        "placed": np.asarray(placement.place(np.array([5.0, 6.0, 7.0]))).tolist(),  # padded as a restore refills
        "restored_pairs": [f"{r.config.missingness}-s{r.config.seed}" for r in restored],
        # Each pair's final state as the experiment returns it: on its own device alone.
        "result_devices": [sorted({device.id for leaf in jax.tree.leaves(r.state) for device in leaf.devices()})
                           for r in four],
        "restored_vs_saved": max(largest_difference(a.state, b.state) for a, b in zip(four, restored)),
        "resumed_steps": [[row["env_steps"] for row in r.scores] for r in resumed],
        "resumed_pairs": [f"{r.config.missingness}-s{r.config.seed}" for r in resumed],
        "resumed_finite": all(np.isfinite(row["min_score"]) for r in resumed for row in r.scores),
        # The resumed run's last checkpoint holds 6 pairs (4 padded to 3 devices × 2); a
        # pair's policy reads its networks alone and cuts the padding off.
        "policy_vs_resumed": largest_difference(
            load_policy(os.path.join(out, "four", "uniform-s1")).actor_params, resumed[3].actor_params),
        "stderr": printed.getvalue(),
    }
    with open(os.path.join(out, "report.json"), "w") as file:
        json.dump(report, file)


if __name__ == "__main__":
    main(sys.argv[1])
    exit_with(0)  # as the commands end, without the closing garbage collections
