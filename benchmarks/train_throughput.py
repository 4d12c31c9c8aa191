"""Time our SAC training iterations (env steps + buffer + gradient steps, one jitted scan).

    python benchmarks/train_throughput.py env=hopper num_envs=8 iterations=100
    python benchmarks/train_throughput.py env=hopper num_envs=8 iterations=50 seeds=5
    python benchmarks/train_throughput.py env=hopper num_envs=128 iterations=50 roofline=true
    python benchmarks/train_throughput.py env=hopper num_envs=8 iterations=100 breakdown=true
    python benchmarks/train_throughput.py env=hopper num_envs=8 iterations=100 seeds=2 before_learning=true
    python benchmarks/train_throughput.py env=ant k=3 pool_size=16 num_envs=8 iterations=50

A warm-up chunk (which compiles) passes learning_starts; the timed chunk then runs
``iterations`` iterations in which every iteration learns (UTD as configured). With
``seeds=S`` the chunk is vmapped over S seeds in one program (aggregate figures are over
all seeds). With ``roofline=true`` it also times the SAC update alone (a scan of updates on
one fixed minibatch), takes its FLOPs from XLA's cost analysis, and measures the matmul
roofline of this device in the same run (a square float32 matmul at the default
precision), so the update's share of the device's matmul rate is measured, not guessed.
With ``breakdown=true`` it also times the whole iteration and its parts alone, in turn
(physics with resets, the iteration with learning switched off, the updates), and prints
what is left over (one seed). With ``before_learning=true`` the timed chunk instead runs
before ``learning_starts`` (random actions, no gradient steps): the first 1% of a paper run
(10k of 1M env steps), which costs only the env, the buffer and the set draws, vmapped over
seeds or not. ``k``, ``up_to_k`` and ``pool_size`` train against other sets than the
paper's single features; ``set_rows=computed`` computes every hidden set's row from its index
(``SetNumbering``) where U is small enough to gather it from the listed matrix, so that one U
times both ways.
Prints env steps/s and gradient steps/s and appends a record to
benchmarks/results/train_throughput.jsonl.
"""

from __future__ import annotations

import dataclasses
import time

import jax
import jax.numpy as jnp

from admissable_jax import method
from admissable_jax.agent import SACBatch
from admissable_jax.cli import check_at_least_one, parse_args
from admissable_jax.config import TrainConfig
from admissable_jax.rollout import random_rollout
from admissable_jax.host_loop import make_trainer, take_pair
from admissable_jax.training import Trainer
from common import append_record, compiled_updates, peak_host_memory_mb, run_benchmark, timed, update_flops


@dataclasses.dataclass
class TrainBenchConfig:
    env: str = dataclasses.field(default="hopper", metadata={"help": "hopper, walker2d, ant (or any env train takes)"})
    num_envs: int = dataclasses.field(default=8, metadata={"help": "parallel envs"})
    iterations: int = dataclasses.field(default=100, metadata={"help": "timed iterations"})
    utd: float = dataclasses.field(default=1.0, metadata={"help": "gradient steps per env step"})
    batch_size: int = dataclasses.field(default=256, metadata={"help": "SAC minibatch"})
    buffer_size: int = dataclasses.field(default=1_000_000, metadata={"help": "replay capacity (transitions)"})
    seeds: int = dataclasses.field(default=1, metadata={"help": "seeds vmapped in one program"})
    physics: str = dataclasses.field(default="auto", metadata={"help": "auto | jax | warp (the env's physics backend)"})
    roofline: bool = dataclasses.field(default=False, metadata={"help": "also time the SAC update alone against the matmul roofline"})
    breakdown: bool = dataclasses.field(default=False, metadata={"help": "also time the iteration and its parts alone, in turn, best of 3: physics, the iteration without learning, the updates (one seed)"})
    before_learning: bool = dataclasses.field(default=False, metadata={"help": "time iterations before learning_starts instead (no gradient steps)"})
    k: int = dataclasses.field(default=1, metadata={"help": "features hidden per episode"})
    up_to_k: bool = dataclasses.field(default=False, metadata={"help": "U also holds the sets of fewer than k features"})
    pool_size: int = dataclasses.field(default=0, metadata={"help": "the adversary's candidate pool (0: exact U)"})
    set_rows: str = dataclasses.field(default="auto", metadata={"help": "auto (listed up to MAX_CANDIDATE_SETS sets, else computed) | computed"})


def _validate(bench: TrainBenchConfig) -> None:
    check_at_least_one(bench, ("num_envs", "iterations", "seeds"))  # (TrainConfig checks the others)
    if bench.set_rows not in ("auto", "computed"):
        raise ValueError(f"set_rows must be auto or computed, got {bench.set_rows!r}")


def matmul_gflops(size: int = 4096, repeats: int = 10) -> float:
    """Measured rate of a square float32 matmul at JAX's default precision."""
    a, b = jax.random.normal(jax.random.key(1), (2, size, size))
    matmul = jax.jit(lambda a, b: a @ b)
    jax.block_until_ready(matmul(a, b))
    best = min(timed(matmul, a, b)[1] for _ in range(repeats))
    return 2 * size**3 / best / 1e9


def _random_batch(trainer: Trainer) -> SACBatch:
    """A fixed random minibatch of the trainer's shapes (masked inputs: 2·d)."""
    obs_size = 2 * trainer.env.observation_size
    keys = jax.random.split(jax.random.key(2), 4)
    return SACBatch(
        obs=jax.random.normal(keys[0], (trainer.spec.sac.batch_size, obs_size)),
        action=jax.random.uniform(keys[1], (trainer.spec.sac.batch_size, trainer.env.action_size), minval=-1, maxval=1),
        reward=jax.random.normal(keys[2], (trainer.spec.sac.batch_size,)),
        next_obs=jax.random.normal(keys[3], (trainer.spec.sac.batch_size, obs_size)),
        terminated=jnp.zeros(trainer.spec.sac.batch_size, bool),
    )


def _sac_update(trainer: Trainer):
    """The trainer's SAC update as ``(state, batch, key) -> state`` (metrics dropped)."""
    return lambda state, batch, key: trainer.agent.update(state, batch, key)[0]


def update_alone(trainer: Trainer, state, updates: int) -> dict:
    """Time ``updates`` SAC updates on one fixed minibatch; FLOPs from XLA's cost analysis."""
    batch = _random_batch(trainer)
    flops = update_flops(trainer.agent.update, state.sac, batch)
    _, seconds = timed(compiled_updates(_sac_update(trainer), state.sac, batch, updates))
    roof = matmul_gflops()
    achieved = flops * updates / seconds / 1e9
    return {
        "update_flops": flops, "updates_per_s": round(updates / seconds, 1),
        "update_gflops_per_s": round(achieved, 2), "matmul_roofline_gflops_per_s": round(roof, 1),
        "update_share_of_roofline": round(achieved / roof, 4),
        "roofline_updates_per_s": round(roof * 1e9 / flops, 1),
    }


def iteration_breakdown(trainer: Trainer, state, iterations: int, rounds: int = 3) -> dict:
    """Milliseconds per iteration of the whole iteration and of its parts, each timed alone:
    the iteration with learning switched off (acting, physics, resets, replay insert and
    sampling, set draws), the batched env step with auto-reset under random actions
    (``rollout.random_rollout``), and the iteration's updates (a scan on one minibatch).
    All four run in turn, ``rounds`` times, each keeping its best round, so that drifts of
    the machine's speed hit them alike."""
    no_learning = Trainer(trainer.env, dataclasses.replace(trainer.spec, learning_starts=2**30))
    full_chunk = jax.jit(trainer.run_chunk, static_argnums=1)
    quiet_chunk = jax.jit(no_learning.run_chunk, static_argnums=1)
    physics = jax.jit(random_rollout, static_argnums=(0, 1, 2))
    updates = compiled_updates(_sac_update(trainer), state.sac, _random_batch(trainer), iterations * trainer.spec.updates_per_iteration)
    parts = {
        "full": lambda: full_chunk(state, iterations),
        "no_learning": lambda: quiet_chunk(state, iterations),
        "physics": lambda: physics(trainer.env, trainer.spec.num_envs, iterations, jax.random.key(6)),
        "updates": updates,
    }
    best = dict.fromkeys(parts, float("inf"))
    for round_index in range(rounds + 1):  # round 0 compiles
        for name, part in parts.items():
            seconds = timed(part)[1]
            if round_index:
                best[name] = min(best[name], seconds)
    return {f"{name}_ms_per_iteration": round(1000 * seconds / iterations, 2) for name, seconds in best.items()}


def main(argv: list[str]) -> None:
    bench = parse_args(TrainBenchConfig, argv, "benchmarks/train_throughput.py", __doc__.splitlines()[0], _validate)
    learning_starts = 2**30 if bench.before_learning else max(bench.batch_size, bench.num_envs)
    warmup_iterations = 1 if bench.before_learning else learning_starts // bench.num_envs + 1
    config = TrainConfig(
        env=bench.env, num_envs=bench.num_envs, utd=bench.utd, batch_size=bench.batch_size,
        learning_starts=learning_starts, score_every=bench.num_envs, buffer_size=bench.buffer_size, progress=False,
        physics=bench.physics, k=bench.k, up_to_k=bench.up_to_k, pool_size=bench.pool_size,
    ).resolved()
    if bench.set_rows == "computed":
        method.MAX_CANDIDATE_SETS = 0  # SetNumbering.rows then computes every row, as beyond the limit
    trainer = make_trainer(config, num_runs=bench.seeds)
    env = trainer.env
    seeds = jnp.arange(bench.seeds)
    state = jax.jit(jax.vmap(trainer.init, (0, None, None, None)))(seeds, True, True, config.lower_bound)
    run_chunk = jax.jit(jax.vmap(trainer.run_chunk, (0, None)), static_argnums=1, donate_argnums=0)

    (state, _), warmup_s = timed(run_chunk, state, warmup_iterations)
    start = time.perf_counter()
    compiled = run_chunk.lower(state, bench.iterations).compile()
    compile_s = time.perf_counter() - start
    (state, metrics), run_s = timed(compiled, state)
    learned = metrics["learned"]
    assert not learned.any() if bench.before_learning else learned.all()
    env_steps = bench.iterations * bench.num_envs * bench.seeds
    grad_steps = int(learned.sum()) * trainer.spec.updates_per_iteration
    record = {
        "env": env.display_name, "physics": env.physics_name, "num_envs": bench.num_envs, "seeds": bench.seeds, "utd": bench.utd,
        "batch_size": bench.batch_size, "hidden_sizes": [config.hidden_size] * config.hidden_layers,
        "buffer_size": trainer.spec.buffer_capacity, "iterations": bench.iterations, "before_learning": bench.before_learning,
        "k": bench.k, "up_to_k": bench.up_to_k, "pool_size": bench.pool_size, "sets": trainer.num_sets,
        "set_rows": "listed" if trainer.sets.listed else "computed",
        "warmup_with_compile_s": round(warmup_s, 1), "compile_s": round(compile_s, 1), "run_s": round(run_s, 2),
        "env_steps_per_s": round(env_steps / run_s, 1), "grad_steps_per_s": round(grad_steps / run_s, 1),
        "peak_host_memory_mb": round(peak_host_memory_mb(), 1),
    }
    if jax.devices()[0].platform != "cpu":
        record["peak_device_memory_mb"] = round(jax.devices()[0].memory_stats().get("peak_bytes_in_use", 0) / 2**20, 1)
    print(
        f"{record['env']} ({env.physics_name} physics): {bench.seeds} seed(s) x {bench.num_envs} envs, UTD {bench.utd}, batch {bench.batch_size}, "
        f"|U| = {trainer.num_sets:,} ({record['set_rows']} rows{f', pool {bench.pool_size}' if bench.pool_size else ''}): "
        f"{env_steps / run_s:,.1f} env steps/s, {grad_steps / run_s:,.1f} gradient steps/s over all seeds "
        f"(timed {bench.iterations} iterations in {run_s:.1f} s; compile {compile_s:.1f} s)"
    )
    single = take_pair(state, 0)
    if bench.roofline:
        record.update(update_alone(trainer, single, updates=max(200, trainer.spec.updates_per_iteration)))
        print(
            f"SAC update alone: {record['update_flops'] / 1e9:.3f} GFLOP, {record['updates_per_s']:,.1f} updates/s "
            f"= {record['update_gflops_per_s']:.1f} GFLOP/s; matmul roofline {record['matmul_roofline_gflops_per_s']:.1f} "
            f"GFLOP/s -> {record['update_share_of_roofline']:.1%} of it (roofline bound {record['roofline_updates_per_s']:,.0f} updates/s)"
        )
    if bench.breakdown:
        parts = iteration_breakdown(trainer, single, bench.iterations)
        record.update(parts)
        rest = parts["full_ms_per_iteration"] - parts["no_learning_ms_per_iteration"] - parts["updates_ms_per_iteration"]
        print(
            f"per iteration, best of 3 rounds each: {parts['full_ms_per_iteration']:.1f} ms in all; without learning "
            f"{parts['no_learning_ms_per_iteration']:.1f} ms (of which the batched env step with resets alone "
            f"{parts['physics_ms_per_iteration']:.1f} ms); {trainer.spec.updates_per_iteration} updates alone "
            f"{parts['updates_ms_per_iteration']:.1f} ms; left over {rest:.1f} ms"
        )
    append_record("train_throughput", record)


if __name__ == "__main__":
    run_benchmark(main)
