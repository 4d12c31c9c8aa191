"""How many MuJoCo Warp kernels one env step launches, and how many solver iterations it uses.

    python benchmarks/warp_launches.py env=hopper solver_iterations=0,10,4

On a latency-bound GPU an env step costs about its kernel launches (benchmarks/README: the
campaign's scoring round is 1,000 sequential steps). This counts them on the CPU, where
MuJoCo Warp runs the same Python launch sequence a CUDA graph captures (``wp.launch`` and
``wp.launch_tiled`` wrapped), for each ``solver_iterations`` setting (0 = the XML's, 100):
whether a lower iteration cap would cut launches, i.e. whether the Newton loop launches
every iteration or stops when all worlds converge (MuJoCo Warp's ``capture_while`` when
``opt.graph_conditional``). ``deterministic`` (default true) is MuJoCo Warp's deterministic
mode (the count is the same either way: on a GPU its ``RUN_TO_RUN`` kernels with atomics
add sort-reduce kernels within their launches, which this count does not see and
``warp_atomics.py`` counts); ``ADMISSABLE_MJX_OWN_WARP=1`` with ``deterministic=false``
counts MJX's own copy of MuJoCo Warp, as every GPU record before 2026-12-04 ran. It also
steps a random-action rollout and histograms
``solver_niter``, the iterations the last forward of each step used. Appends a record per
setting to benchmarks/results/warp_launches.jsonl.
"""

from __future__ import annotations

import collections
import dataclasses

import jax
import jax.numpy as jnp
import numpy as np

from admissable_jax.cli import check_at_least_one, parse_args
from admissable_jax.envs import canonical_env_name, make_env, reset_where_done, warp_package
from common import append_record, run_benchmark


@dataclasses.dataclass
class LaunchConfig:
    env: str = dataclasses.field(default="hopper", metadata={"help": "hopper, walker2d or ant"})
    solver_iterations: str = dataclasses.field(default="0,10,4", metadata={"help": "comma list; 0 = the XML's (100)"})
    num_envs: int = dataclasses.field(default=8, metadata={"help": "worlds stepped at once"})
    steps: int = dataclasses.field(default=200, metadata={"help": "steps of the random rollout for solver_niter"})
    deterministic: bool = dataclasses.field(default=True, metadata={"help": "MuJoCo Warp's deterministic mode (deterministic_physics)"})


def solver_caps(config: LaunchConfig) -> list[int]:
    """The ``solver_iterations`` settings; ValueError (parse_args makes it one line, exit 2)
    for bad settings or a GPU backend, where captured graphs are replayed and Python would
    see no launch after the first."""
    if jax.default_backend() != "cpu":
        raise ValueError("warp_launches.py counts launches on the CPU; run it with JAX_PLATFORMS=cpu")
    canonical_env_name(config.env)
    check_at_least_one(config, ("num_envs", "steps"))
    caps = [int(cap) for cap in config.solver_iterations.split(",") if cap.strip().isdigit()]
    if len(caps) != len(config.solver_iterations.split(",")):
        raise ValueError(f"solver_iterations must be a comma list of ints >= 0, got {config.solver_iterations!r}")
    return caps


def launched_kernels(warp, step, *args) -> tuple[dict, collections.Counter, set]:
    """One call of the compiled ``step``: its kernels by key, launches by key, and the keys of
    the kernels launched over no threads."""
    kernels, launches, empty = {}, collections.Counter(), set()
    originals = {name: getattr(warp, name) for name in ("launch", "launch_tiled")}

    def recorded(original):
        def launch(kernel, *launch_args, **kwargs):
            kernels[kernel.key] = kernel
            launches[kernel.key] += 1
            dim = kwargs.get("dim", launch_args[0] if launch_args else None)
            if dim is not None and 0 in (dim if isinstance(dim, (tuple, list)) else (dim,)):
                empty.add(kernel.key)
            return original(kernel, *launch_args, **kwargs)
        return launch

    for name, original in originals.items():
        setattr(warp, name, recorded(original))
    try:
        jax.block_until_ready(step(*args))
    finally:
        for name, original in originals.items():
            setattr(warp, name, original)
    return kernels, launches, empty


def solver_niter_histogram(env, num_envs: int, steps: int) -> dict[int, int]:
    """{iterations: count} of ``solver_niter`` after each step of a random-action rollout."""
    def step(states, rng):
        action_rng, reset_rng = jax.random.split(rng)
        actions = jax.random.uniform(action_rng, (num_envs, env.action_size), minval=env.action_low,
                                     maxval=env.action_high)
        states = jax.vmap(env.step)(states, actions)
        niter = states.data._impl.solver_niter.reshape(-1)  # pylint: disable=protected-access
        states = jax.vmap(reset_where_done, (None, 0, 0))(env, states, jax.random.split(reset_rng, num_envs))
        return states, niter

    def rollout(rng):
        start_rng, scan_rng = jax.random.split(rng)
        states = jax.vmap(env.reset)(jax.random.split(start_rng, num_envs))
        return jax.lax.scan(step, states, jax.random.split(scan_rng, steps))[1]

    values, counts = np.unique(np.asarray(jax.jit(rollout)(jax.random.key(0))), return_counts=True)
    return {int(value): int(count) for value, count in zip(values, counts)}


def main(argv: list[str]) -> None:
    import warp

    bench = parse_args(LaunchConfig, argv, "benchmarks/warp_launches.py", __doc__.splitlines()[0], solver_caps)
    for cap in solver_caps(bench):
        env = make_env(bench.env, physics="warp", solver_iterations=cap or None, max_batch=bench.num_envs,
                       deterministic=bench.deterministic)
        states = jax.vmap(env.reset)(jax.random.split(jax.random.key(0), bench.num_envs))
        step = jax.jit(jax.vmap(env.step))
        actions = jnp.zeros((bench.num_envs, env.action_size))
        states = jax.block_until_ready(step(states, actions))  # compiled and run once, uncounted
        _, counts, _ = launched_kernels(warp, step, states, actions)
        record = {
            "env": env.gymnasium_id, "solver_iterations": int(env.mj_model.opt.iterations),
            "graph_conditional": bool(env.physics.model.opt._impl.graph_conditional),  # pylint: disable=protected-access
            "num_envs": bench.num_envs, "deterministic": bench.deterministic,
            "mujoco_warp": warp_package.which(),
            "launches_per_env_step": sum(counts.values()),
            "most_launched": dict(counts.most_common(8)),
            "solver_niter_histogram": solver_niter_histogram(env, bench.num_envs, bench.steps),
        }
        append_record("warp_launches", record)
        print(f"{env.gymnasium_id} ({record['mujoco_warp']}, deterministic={bench.deterministic}) "
              f"solver_iterations={record['solver_iterations']}: {record['launches_per_env_step']} "
              f"launches per env step; solver iterations used (last forward of each step): "
              f"{record['solver_niter_histogram']}", flush=True)


if __name__ == "__main__":
    run_benchmark(main)
