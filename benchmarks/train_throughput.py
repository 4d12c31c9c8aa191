"""Time our SAC training iterations (env steps + buffer + gradient steps, one jitted scan).

    python benchmarks/train_throughput.py env=hopper num_envs=8 iterations=100

A warm-up chunk (which compiles) passes learning_starts; the timed chunk then runs
``iterations`` iterations in which every iteration learns (UTD as configured). Prints env
steps/s and gradient steps/s and appends a record to benchmarks/results/train_throughput.jsonl.
"""

from __future__ import annotations

import dataclasses
import sys
import time

import jax

from admissable_jax.cli import parse_args
from admissable_jax.config import TrainConfig
from admissable_jax.envs import make_env
from admissable_jax.training import Trainer
from common import append_record, peak_host_memory_mb


@dataclasses.dataclass
class TrainBenchConfig:
    env: str = dataclasses.field(default="hopper", metadata={"help": "hopper, walker2d or ant"})
    num_envs: int = dataclasses.field(default=8, metadata={"help": "parallel envs"})
    iterations: int = dataclasses.field(default=100, metadata={"help": "timed iterations"})
    utd: float = dataclasses.field(default=1.0, metadata={"help": "gradient steps per env step"})
    batch_size: int = dataclasses.field(default=256, metadata={"help": "SAC minibatch"})


def main(argv: list[str]) -> None:
    bench = parse_args(TrainBenchConfig, argv, "benchmarks/train_throughput.py", __doc__.splitlines()[0])
    learning_starts = max(bench.batch_size, bench.num_envs)
    warmup_iterations = learning_starts // bench.num_envs + 1
    config = TrainConfig(
        env=bench.env, num_envs=bench.num_envs, utd=bench.utd, batch_size=bench.batch_size,
        learning_starts=learning_starts, score_every=bench.num_envs, progress=False,
    ).resolved()
    env = make_env(config.env)
    trainer = Trainer(env, config)
    state = jax.jit(trainer.init)(0, True, True)
    run_chunk = jax.jit(trainer.run_chunk, static_argnums=1, donate_argnums=0)

    start = time.perf_counter()
    state, _ = jax.block_until_ready(run_chunk(state, warmup_iterations))
    warmup_s = time.perf_counter() - start
    start = time.perf_counter()
    compiled = run_chunk.lower(state, bench.iterations).compile()
    compile_s = time.perf_counter() - start
    start = time.perf_counter()
    state, metrics = jax.block_until_ready(compiled(state))
    run_s = time.perf_counter() - start
    assert bool(metrics["learned"].all())
    env_steps = bench.iterations * bench.num_envs
    grad_steps = bench.iterations * trainer.updates_per_iteration
    record = {
        "env": env.gymnasium_id, "num_envs": bench.num_envs, "utd": bench.utd,
        "batch_size": bench.batch_size, "hidden_sizes": [config.hidden_size] * config.hidden_layers,
        "buffer_size": trainer.capacity, "iterations": bench.iterations,
        "warmup_with_compile_s": round(warmup_s, 1), "compile_s": round(compile_s, 1), "run_s": round(run_s, 2),
        "env_steps_per_s": round(env_steps / run_s, 1), "grad_steps_per_s": round(grad_steps / run_s, 1),
        "peak_host_memory_mb": round(peak_host_memory_mb(), 1),
    }
    print(
        f"{env.gymnasium_id}: {bench.num_envs} envs, UTD {bench.utd}, batch {bench.batch_size}: "
        f"{env_steps / run_s:,.1f} env steps/s, {grad_steps / run_s:,.1f} gradient steps/s "
        f"(timed {bench.iterations} iterations in {run_s:.1f} s; compile {compile_s:.1f} s)"
    )
    append_record("train_throughput", record)


if __name__ == "__main__":
    main(sys.argv[1:])
