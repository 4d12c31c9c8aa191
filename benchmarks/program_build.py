"""How long a run's two programs take to build: JAX tracing them, lowering them, XLA compiling them.

    python benchmarks/program_build.py envs=hopper physics=jax,warp repeats=2
    XLA_FLAGS=--xla_backend_optimization_level=0 python benchmarks/program_build.py   # as the tests compile

Before a run trains it builds its train chunk and its scoring round (``host_loop``); on a
small CPU that is most of a short run, and of each test that trains. For each env, physics
and repeat, a fresh Python process on the CPU (no JAX compilation cache, so nothing is loaded
instead of compiled) builds the trainer of a short run (``train``: its keys, by default the GPU
campaign's smoke sizes), then traces, lowers and compiles the two programs one after the
other, as ``jax.jit(...).trace(state).lower().compile()``, and reports each stage's CPU
seconds (this process's, so a busy machine distorts them less than wall seconds) and wall
seconds. The chunk goes first, so its tracing includes what the two share (one world's
physics step, traced once per env: ``envs/physics.py``). Appends one record per process to
``benchmarks/results/program_build.jsonl``, with the programs' MLIR sizes.
"""

from __future__ import annotations

import dataclasses
import json
import os
import shlex
import time

from admissable_jax.cli import parse_args
from admissable_jax.config import TrainConfig
from admissable_jax.envs import canonical_env_name
from common import append_record, measured_in_fresh_process, run_benchmark

SMOKE_SIZES = ("score_every=40 num_envs=4 learning_starts=48 batch_size=32 hidden_size=32 buffer_size=1000 "
               "score_episodes=2 score_envs=24 episode_length=10")
PHYSICS = ("jax", "warp")
STAGES = ("trace", "lower", "compile")


@dataclasses.dataclass
class ProgramBuildConfig:
    envs: str = dataclasses.field(default="hopper", metadata={"help": "comma-separated envs"})
    physics: str = dataclasses.field(default="jax,warp", metadata={"help": "comma-separated physics: jax, warp"})
    repeats: int = dataclasses.field(default=1, metadata={"help": "fresh processes per env and physics"})
    train: str = dataclasses.field(default=SMOKE_SIZES, metadata={"help": "the run's keys, 'key=value ...' (python -m admissable_jax.train --help)"})


def _train_config(env: str, physics: str, train: str) -> TrainConfig:
    keys = [f"env={env}", f"physics={physics}", "progress=false", *shlex.split(train)]
    return parse_args(TrainConfig, keys, "python -m admissable_jax.train", "the run's keys").resolved()


def _validate(bench: ProgramBuildConfig) -> None:
    for physics in bench.physics.split(","):
        if physics.strip() not in PHYSICS:
            raise ValueError(f"physics must be comma-separated {' or '.join(PHYSICS)}, got {bench.physics!r}")
    if bench.repeats < 1:
        raise ValueError(f"repeats must be >= 1, got {bench.repeats}")
    for name in bench.envs.split(","):
        _train_config(canonical_env_name(name.strip()), "jax", bench.train)  # the train keys, checked here


def _timed(build) -> tuple:
    """(``build()``, the CPU and the wall seconds it took)."""
    cpu, wall = time.process_time(), time.perf_counter()
    built = build()
    return built, {"cpu_s": time.process_time() - cpu, "wall_s": time.perf_counter() - wall}


def _measure_in_this_process(env: str, physics: str, train: str) -> dict:
    import jax

    from admissable_jax.host_loop import init_arguments, interval_pieces, make_trainer

    config = _train_config(env, physics, train)
    trainer = make_trainer(config)
    state = jax.eval_shape(lambda: trainer.init(*init_arguments(config)))
    iterations = trainer.spec.iterations_per_scoring // interval_pieces(trainer.spec.iterations_per_scoring)
    programs = {"train_chunk": lambda s: trainer.run_chunk(s, iterations), "scoring_round": trainer.score_and_update}
    record = {"env": trainer.env.gymnasium_id, "physics": trainer.env.physics_name, "train": train,
              "xla_flags": os.environ.get("XLA_FLAGS", "")}
    per_program = []
    for name, program in programs.items():
        traced, trace = _timed(lambda: jax.jit(program).trace(state))
        lowered, lower = _timed(traced.lower)
        _, compile_ = _timed(lowered.compile)
        seconds = dict(zip(STAGES, (trace, lower, compile_)))
        record[name] = {**{f"{stage}_{kind}": round(value, 2) for stage in STAGES for kind, value in seconds[stage].items()},
                        "mlir_chars": len(lowered.as_text())}
        per_program.append(seconds)
    record.update({f"{stage}_{kind}": round(sum(seconds[stage][kind] for seconds in per_program), 2)
                   for stage in STAGES for kind in ("cpu_s", "wall_s")})
    return record


def main(argv: list[str]) -> None:
    if argv[:1] == ["--child"]:
        print(json.dumps(_measure_in_this_process(*argv[1:])))
        return
    bench = parse_args(ProgramBuildConfig, argv, "benchmarks/program_build.py", __doc__.strip().splitlines()[0], _validate)
    for env in (canonical_env_name(name.strip()) for name in bench.envs.split(",")):
        for physics in (name.strip() for name in bench.physics.split(",")):
            for _ in range(bench.repeats):
                record = measured_in_fresh_process(__file__, [env, physics, bench.train], {})
                path = append_record("program_build", record)
                print(f"{record['env']} ({record['physics']}): CPU-s trace {record['trace_cpu_s']}, lower "
                      f"{record['lower_cpu_s']}, compile {record['compile_cpu_s']} (the train chunk, then the "
                      f"scoring round; wall {sum(record[f'{stage}_wall_s'] for stage in STAGES):.1f} s) ({path})")


if __name__ == "__main__":
    run_benchmark(main)
