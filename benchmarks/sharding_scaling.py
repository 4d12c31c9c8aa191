"""Aggregate training throughput of an experiment's pairs over 1, 2, 4, ... devices.

    python benchmarks/sharding_scaling.py env=hopper pairs=4 devices=1,2,4 iterations=50
    python benchmarks/sharding_scaling.py env=point_mass pairs=8 devices=1,2,4,8

Each device count runs in a process of its own (on a CPU the device count is fixed when
JAX starts: ``XLA_FLAGS=--xla_force_host_platform_device_count=N``; on GPUs the first N
GPUs), with the pairs placed as ``experiment devices=N`` places them
(:class:`admissable_jax.placement.PairPlacement`). A warm-up chunk (which compiles) passes
learning_starts, then one chunk of ``iterations`` learning iterations and one scoring round
are timed. Prints aggregate env steps/s over all pairs and the scoring round's seconds, and
appends a record per device count to benchmarks/results/sharding_scaling.jsonl.
"""

from __future__ import annotations

import dataclasses
import os
import subprocess
import sys

import jax
import numpy as np

from admissable_jax.cli import check_at_least_one, parse_args
from admissable_jax.config import TrainConfig
from admissable_jax.host_loop import make_trainer, pairs_init
from admissable_jax.placement import PairPlacement
from common import append_record, run_benchmark, timed


@dataclasses.dataclass
class ScalingBenchConfig:
    env: str = dataclasses.field(default="hopper", metadata={"help": "hopper, walker2d, ant or point_mass"})
    pairs: int = dataclasses.field(default=4, metadata={"help": "(seed, mode) pairs in the program"})
    devices: str = dataclasses.field(default="1,2,4", metadata={"help": "comma-separated device counts, one process each"})
    num_envs: int = dataclasses.field(default=8, metadata={"help": "parallel envs per pair"})
    iterations: int = dataclasses.field(default=50, metadata={"help": "timed iterations"})
    score_episodes: int = dataclasses.field(default=2, metadata={"help": "N of the timed scoring round"})
    episode_length: int = dataclasses.field(default=100, metadata={"help": "episode step limit (scoring round length)"})
    buffer_size: int = dataclasses.field(default=100_000, metadata={"help": "replay capacity per pair"})
    physics: str = dataclasses.field(default="auto", metadata={"help": "auto | jax | warp"})


def _validate(bench: ScalingBenchConfig) -> None:
    check_at_least_one(bench, ("pairs", "num_envs", "iterations"))  # (TrainConfig checks the others)


def measure(bench: ScalingBenchConfig, devices: int) -> dict:
    """Time one chunk and one scoring round of ``bench.pairs`` pairs on ``devices`` devices."""
    batch_size = 64
    warmup_iterations = -(-batch_size // bench.num_envs) + 1  # then every iteration learns
    config = TrainConfig(
        env=bench.env, num_envs=bench.num_envs, score_every=bench.num_envs * bench.iterations,
        learning_starts=batch_size, batch_size=batch_size, buffer_size=bench.buffer_size,
        score_episodes=bench.score_episodes, episode_length=bench.episode_length, physics=bench.physics,
    ).resolved()
    placement = PairPlacement.over(bench.pairs, devices)
    trainer = make_trainer(config, num_runs=placement.pairs_per_device)
    pairs = [dataclasses.replace(config, seed=seed) for seed in range(bench.pairs)]  # adversarial, as experiment's
    state = pairs_init(trainer, pairs, placement)()
    warmup = placement.jit(lambda s: trainer.run_chunk(s, warmup_iterations))
    chunk = placement.jit(lambda s: trainer.run_chunk(s, bench.iterations))
    score = placement.jit(trainer.score_and_update)
    (state, _), _ = timed(warmup, state)
    compiled_chunk, compile_s = timed(lambda: chunk.lower(state).compile())
    compiled_score = score.lower(state).compile()
    (state, metrics), run_s = timed(compiled_chunk, state)
    assert bool(np.all(placement.local_rows(metrics)["learned"]))
    (_, _), score_s = timed(compiled_score, state)
    env_steps = bench.iterations * bench.num_envs * bench.pairs
    return {
        "env": trainer.env.display_name, "physics": trainer.env.physics_name, "pairs": bench.pairs,
        "devices": devices, "pairs_per_device": placement.pairs_per_device, "num_envs": bench.num_envs,
        "iterations": bench.iterations, "compile_chunk_s": round(compile_s, 1), "chunk_s": round(run_s, 2),
        "aggregate_env_steps_per_s": round(env_steps / run_s, 1), "score_round_s": round(score_s, 2),
        "score_episodes": bench.score_episodes, "episode_length": bench.episode_length,
        "cpu_count": os.cpu_count(),
    }


def main(argv: list[str]) -> None:
    bench = parse_args(ScalingBenchConfig, argv, "benchmarks/sharding_scaling.py", __doc__.splitlines()[0], _validate)
    counts = [int(count) for count in bench.devices.split(",")]
    if len(counts) > 1:  # one process per device count
        on_cpu = os.environ.get("JAX_PLATFORMS", "") == "cpu" or not _has_accelerator()
        for count in counts:
            environment = dict(os.environ)
            if on_cpu:
                environment["XLA_FLAGS"] = (f"{environment.get('XLA_FLAGS', '')} "
                                            f"--xla_force_host_platform_device_count={count}")
            argv_one = [arg for arg in argv if not arg.startswith("devices=")] + [f"devices={count}"]
            subprocess.run([sys.executable, __file__, *argv_one], env=environment, check=True)
        return
    record = measure(bench, counts[0])
    print(f"{record['env']} ({record['physics']}): {bench.pairs} pairs on {counts[0]} {jax.devices()[0].platform} "
          f"device(s): {record['aggregate_env_steps_per_s']:,.1f} env steps/s over all pairs "
          f"(chunk {record['chunk_s']} s), scoring round {record['score_round_s']} s")
    append_record("sharding_scaling", record)


def _has_accelerator() -> bool:
    """Whether JAX would start on a GPU here (asked of a subprocess: this one must not start JAX)."""
    probe = subprocess.run([sys.executable, "-c", "import jax; print(jax.default_backend())"],
                           capture_output=True, text=True)
    return probe.stdout.strip() not in ("", "cpu")


if __name__ == "__main__":
    run_benchmark(main)
