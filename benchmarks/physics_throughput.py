"""Physics throughput per backend and batch: our env step against the bare physics step.

    python benchmarks/physics_throughput.py env=hopper physics=jax,warp batches=8,32 steps=50
    python benchmarks/physics_throughput.py env=ant physics=warp batches=125 graph_modes=default,WARP,WARP_STAGED
    python benchmarks/physics_throughput.py env=walker2d physics=jax batches=64 worlds_per_call=0,8,16,32,64

For every (backend, batch) pair: a batched random-policy rollout through our env (obs,
reward, termination, automatic resets: ``admissable_jax.rollout.random_rollout``) and the
bare physics of the same batch under the same actions (``frame_skip`` × ``mjx.step`` under
``vmap`` inside ``lax.scan``, no env logic, no resets), each compiled once and timed once
after a warm-up run. Prints ms per batched env step and env steps/s, and appends one record per
pair to ``benchmarks/results/physics_throughput.jsonl``; ``env_over_bare`` is the cost of
our env layer over the physics it wraps (the Warp issue's target: <= 1.15 on a GPU).
``graph_modes`` (Warp only) repeats each Warp measurement per MuJoCo Warp graph mode
(``default`` = MJX's own choice; ``NONE``: no CUDA graph, where a GPU's Warp checks the
deterministic mode's buffers after each launch, see ``EnvOptions.graph_mode``).
``deterministic`` (Warp only; default true, as runs) is MuJoCo Warp's deterministic mode;
``deterministic=false`` times the GPU's own order, and with ``ADMISSABLE_MJX_OWN_WARP=1``
MJX's own copy of MuJoCo Warp, as every record before 2026-12-04.
``worlds_per_call`` (JAX only) repeats each JAX measurement per piece size
(``EnvOptions.worlds_per_call``: 0 = the default, on a CPU from the world's data size; a
size at or above the batch = one call): where the per-world cost jumps on your CPU.
"""

from __future__ import annotations

import dataclasses
import time

import jax

from admissable_jax.cli import parse_args
from admissable_jax.envs import EnvOptions, canonical_env_name, make_env, resolve_physics, warp_package
from admissable_jax.rollout import random_actions, random_rollout
from common import append_record, run_benchmark


@dataclasses.dataclass
class PhysicsBenchConfig:
    env: str = dataclasses.field(default="hopper", metadata={"help": "hopper, walker2d or ant"})
    physics: str = dataclasses.field(default="jax,warp", metadata={"help": "comma-separated backends (auto, jax, warp)"})
    batches: str = dataclasses.field(default="8,32", metadata={"help": "comma-separated batch sizes (envs stepped at once)"})
    steps: int = dataclasses.field(default=50, metadata={"help": "batched steps per timed run"})
    graph_modes: str = dataclasses.field(default="default", metadata={"help": "comma-separated Warp graph modes: default, WARP, WARP_STAGED, NONE"})
    deterministic: bool = dataclasses.field(default=True, metadata={"help": "Warp: its deterministic mode (deterministic_physics)"})
    worlds_per_call: str = dataclasses.field(default="0", metadata={"help": "JAX: comma-separated most worlds per physics call (0 = the default)"})


def _graph_modes(bench: PhysicsBenchConfig) -> list[str | None]:
    return [None if mode.strip() == "default" else mode.strip() for mode in bench.graph_modes.split(",")]


def _validate(bench: PhysicsBenchConfig) -> None:
    canonical_env_name(bench.env)
    for physics in bench.physics.split(","):
        resolve_physics(physics.strip())
    if not all(int(batch) >= 1 for batch in bench.batches.split(",")) or bench.steps < 1:
        raise ValueError("batches and steps must be >= 1")
    for mode in _graph_modes(bench):
        EnvOptions(graph_mode=mode)  # validates the name
    for worlds in _worlds_per_call(bench):
        EnvOptions(worlds_per_call=worlds)


def _worlds_per_call(bench: PhysicsBenchConfig) -> list[int]:
    try:
        return [int(worlds) for worlds in bench.worlds_per_call.split(",")]
    except ValueError:
        raise ValueError(f"worlds_per_call must be comma-separated ints, got {bench.worlds_per_call!r}") from None


def _bare_rollout(env, num_envs: int, steps: int, rng: jax.Array):
    """The physics data after ``steps`` batched physics steps and nothing else, from
    ``random_rollout``'s first states under its actions (the same keys; no resets).

    Not zero controls: those time another solve than the env's (on a 2-core CPU, 16 Walker2d
    worlds: 10.3 ms per step against 15.0 under random actions; Ant's is slower), which read
    as our env layer's cost (Walker2d's env/bare 1.50 where it is 1.03; records before
    2026-12-06 have no ``bare_actions``)."""
    init_rng, scan_rng = jax.random.split(rng)
    data = jax.vmap(env.reset)(jax.random.split(init_rng, num_envs)).data

    def step(data, rng):
        action_rng, _ = jax.random.split(rng)
        return jax.vmap(env.physics.step)(data, random_actions(env, num_envs, action_rng)), None

    data, _ = jax.lax.scan(step, data, jax.random.split(scan_rng, steps))
    return data


def _time(function, *args) -> tuple[float, float]:
    """(compile seconds, run seconds of the second call)."""
    start = time.perf_counter()
    compiled = jax.jit(function, static_argnums=(0, 1, 2)).lower(*args).compile()
    compile_s = time.perf_counter() - start
    jax.block_until_ready(compiled(args[-1]))
    start = time.perf_counter()
    jax.block_until_ready(compiled(args[-1]))
    return compile_s, time.perf_counter() - start


def main(argv: list[str]) -> None:
    bench = parse_args(PhysicsBenchConfig, argv, "benchmarks/physics_throughput.py", __doc__.splitlines()[0], _validate)
    rng = jax.random.key(0)
    cases = [(resolve_physics(physics.strip()), batch, mode, worlds) for physics in bench.physics.split(",")
             for batch in (int(b) for b in bench.batches.split(",")) for mode in _graph_modes(bench)
             for worlds in _worlds_per_call(bench)]
    for physics, batch, mode, worlds in cases:
        if (physics == "warp" and worlds != _worlds_per_call(bench)[0]) or (physics != "warp" and mode != _graph_modes(bench)[0]):
            continue  # graph modes are Warp's, pieces JAX's: measure the other backend once
        env = make_env(bench.env, physics=physics, max_batch=batch, graph_mode=mode, deterministic=bench.deterministic,
                       worlds_per_call=0 if physics == "warp" else worlds)
        env_compile_s, env_s = _time(random_rollout, env, batch, bench.steps, rng)
        bare_compile_s, bare_s = _time(_bare_rollout, env, batch, bench.steps, rng)
        record = {
            "env": env.gymnasium_id, "physics": env.physics_name, "num_envs": batch, "steps": bench.steps,
            "graph_mode": mode if env.physics_name == "warp" else None,
            "deterministic": bench.deterministic if env.physics_name == "warp" else None,
            "mujoco_warp": warp_package.which() if env.physics_name == "warp" else None,
            "worlds_per_call": env.physics.worlds_per_call,
            "env_ms_per_step": round(1000 * env_s / bench.steps, 3),
            "bare_ms_per_step": round(1000 * bare_s / bench.steps, 3),
            "env_steps_per_s": round(batch * bench.steps / env_s, 1),
            "bare_env_steps_per_s": round(batch * bench.steps / bare_s, 1),
            "env_over_bare": round(env_s / bare_s, 3), "bare_actions": "random",
            "env_compile_s": round(env_compile_s, 1), "bare_compile_s": round(bare_compile_s, 1),
        }
        append_record("physics_throughput", record)
        pieces = f" in pieces of {env.physics.worlds_per_call}" if batch > (env.physics.worlds_per_call or batch) else ""
        print(
            f"{env.gymnasium_id} {env.physics_name:4s} {record['graph_mode'] or '':11s} x {batch:6d}{pieces}: env {record['env_ms_per_step']:8.2f} ms/step "
            f"({record['env_steps_per_s']:,.0f} env steps/s), bare physics {record['bare_ms_per_step']:8.2f} ms/step "
            f"-> env/bare {record['env_over_bare']:.2f}; compile {env_compile_s:.1f} s / {bare_compile_s:.1f} s"
        )


if __name__ == "__main__":
    run_benchmark(main)
