"""Time one full scoring round: every u ∈ U plus the clean case, N episodes each, as ONE
batched rollout (``score_missingness``), with the SAC actor of a given run or a fresh one.

    python benchmarks/scoring_round.py env=hopper n_episodes=10
    python benchmarks/scoring_round.py env=hopper run=runs/h100k   # the run's final actor
    python benchmarks/scoring_round.py env=ant n_episodes=10 max_steps=50
    python benchmarks/scoring_round.py env=hopper run=runs/h100k sequential=true

``sequential=true`` also runs the paper's way for comparison: Gymnasium's C-MuJoCo env, one
episode after another for every u, the same actor through a jitted forward per step.

Prints compile and run time, env steps executed (episodes stop early when they end) and
env steps/s, and appends a record to benchmarks/results/scoring_round.jsonl.
"""

from __future__ import annotations

import dataclasses
import sys
import time

import jax
import numpy as np

from admissable_jax.checkpointing import Checkpoints
from admissable_jax.cli import parse_args
from admissable_jax.config import TrainConfig
from admissable_jax.envs import make_env
from admissable_jax.scoring import score_missingness
from admissable_jax.training import Trainer
from common import append_record, peak_host_memory_mb


@dataclasses.dataclass
class ScoringBenchConfig:
    env: str = dataclasses.field(default="hopper", metadata={"help": "hopper, walker2d or ant"})
    n_episodes: int = dataclasses.field(default=10, metadata={"help": "N episodes per set"})
    max_steps: int = dataclasses.field(default=1000, metadata={"help": "episode step limit"})
    run: str = dataclasses.field(default="", metadata={"help": "run directory whose last checkpoint gives the actor ('' = untrained actor)"})
    seed: int = dataclasses.field(default=0, metadata={"help": "PRNG seed"})
    sequential: bool = dataclasses.field(default=False, metadata={"help": "also time the paper-style sequential Gymnasium loop"})


def main(argv: list[str]) -> None:
    bench = parse_args(ScoringBenchConfig, argv, "benchmarks/scoring_round.py", __doc__.splitlines()[0])
    env = make_env(bench.env)
    env.max_episode_steps = bench.max_steps
    config = TrainConfig(env=bench.env, num_envs=8, buffer_size=8, learning_starts=256, progress=False).resolved()
    trainer = Trainer(env, config)
    state = jax.jit(trainer.init)(0, True, True)
    label = "untrained actor"
    if bench.run:
        checkpoints = Checkpoints(f"{bench.run}/checkpoints")
        saved_config = TrainConfig(**{**dataclasses.asdict(config), **_saved_sizes(bench.run)}).resolved()
        trainer = Trainer(env, saved_config)
        step, state = checkpoints.restore(jax.jit(trainer.init)(0, True, True))
        label = f"actor of {bench.run} at {step} env steps"
    score = jax.jit(score_missingness, static_argnums=(0, 1, 5))
    args = (env, trainer.policy, state.sac.actor_params, jax.random.key(bench.seed), trainer.hidden_sets, bench.n_episodes)
    start = time.perf_counter()
    compiled = score.lower(*args).compile()
    compile_s = time.perf_counter() - start
    start = time.perf_counter()
    result = jax.block_until_ready(compiled(*args[2:5]))
    run_s = time.perf_counter() - start
    lengths = np.asarray(result.lengths)
    batch = lengths.size
    loop_steps = int(lengths.max())
    record = {
        "env": env.gymnasium_id, "n_episodes": bench.n_episodes, "sets": trainer.num_sets,
        "batch_episodes": batch, "max_steps": bench.max_steps, "policy": label,
        "compile_s": round(compile_s, 2), "run_s": round(run_s, 3),
        "loop_steps": loop_steps, "env_steps_stepped": batch * loop_steps,
        "env_steps_in_episodes": int(lengths.sum()),
        "stepped_per_s": round(batch * loop_steps / run_s, 1),
        "min_score": float(result.min_score), "clean_score": float(result.clean_score),
        "peak_host_memory_mb": round(peak_host_memory_mb(), 1),
    }
    print(
        f"{env.gymnasium_id}, {label}: {trainer.num_sets}+1 sets x {bench.n_episodes} episodes = {batch} "
        f"envs in one rollout; {loop_steps} loop steps (longest episode), compile {compile_s:.1f} s, "
        f"run {run_s:.2f} s, {batch * loop_steps / run_s:,.0f} env steps/s stepped; "
        f"min_u a_u {record['min_score']:.1f}, clean {record['clean_score']:.1f}"
    )
    if bench.sequential:
        record.update(_sequential_round(env, trainer, state.sac.actor_params, bench))
        record["sequential_over_batched"] = round(record["sequential_s"] / run_s, 3)
        print(
            f"sequential Gymnasium loop: {record['sequential_env_steps']} env steps in "
            f"{record['sequential_s']:.1f} s ({record['sequential_ms_per_step']:.3f} ms/step); "
            f"sequential time / batched time = {record['sequential_over_batched']:.2f}"
        )
    append_record("scoring_round", record)


def _sequential_round(env, trainer, actor_params, bench) -> dict:
    """Every set (and the clean case), N episodes each, one at a time on Gymnasium."""
    import gymnasium
    import jax.numpy as jnp

    from admissable_jax.missingness import mask_observation

    gym_env = gymnasium.make(env.gymnasium_id, max_episode_steps=bench.max_steps)
    act = jax.jit(lambda params, obs, hidden: trainer.policy(params, mask_observation(obs, hidden)))
    rows = [*np.asarray(trainer.hidden_sets), np.zeros(env.observation_size, np.float32)]
    act(actor_params, jnp.zeros(env.observation_size), jnp.asarray(rows[0]))  # compile outside the timing
    steps, returns = 0, []
    start = time.perf_counter()
    for row_index, hidden in enumerate(rows):
        hidden = jnp.asarray(hidden)
        for episode in range(bench.n_episodes):
            obs, _ = gym_env.reset(seed=bench.seed * 100_000 + episode)
            total, done = 0.0, False
            while not done:
                action = np.asarray(act(actor_params, jnp.asarray(obs, jnp.float32), hidden))
                obs, reward, terminated, truncated, _ = gym_env.step(action)
                total += reward
                steps += 1
                done = terminated or truncated
            returns.append(total)
    seconds = time.perf_counter() - start
    per_set = np.asarray(returns).reshape(len(rows), bench.n_episodes).mean(axis=1)
    return {
        "sequential_s": round(seconds, 2), "sequential_env_steps": steps,
        "sequential_ms_per_step": round(1000 * seconds / steps, 4),
        "sequential_min_score": float(per_set[:-1].min()), "sequential_clean_score": float(per_set[-1]),
    }


def _saved_sizes(run_dir: str) -> dict:
    """The network/buffer settings of a saved run (they fix the checkpoint's shapes)."""
    from omegaconf import OmegaConf

    saved = OmegaConf.to_container(OmegaConf.load(f"{run_dir}/config.yaml"))
    keys = ("num_envs", "buffer_size", "hidden_size", "hidden_layers", "k", "include_empty_set", "score_every", "learning_starts", "batch_size")
    return {key: saved[key] for key in keys}


if __name__ == "__main__":
    main(sys.argv[1:])
