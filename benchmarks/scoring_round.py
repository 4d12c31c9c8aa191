"""Time one full scoring round: every u ∈ U plus the clean case, N episodes each, as ONE
batched rollout (``score_missingness``), with the SAC actor of a given run or a fresh one,
against the pure-physics time of the same rollout.

    python benchmarks/scoring_round.py env=hopper n_episodes=10
    python benchmarks/scoring_round.py env=hopper run=runs/h100k   # the run's final actor
    python benchmarks/scoring_round.py env=hopper slots=0 n_episodes=5   # every episode at once
    python benchmarks/scoring_round.py env=hopper run=runs/h100k sequential=true
    python benchmarks/scoring_round.py env=ant slots=0 terminate=false   # every episode 1000 steps

``slots`` is the number of envs stepped at once (``score_envs`` of training; -1 = this
backend's default, 0 = every episode at once). The pure-physics ceiling runs the same rollout
(same slots, same refills, same early exit) with the policy replaced by a zero action: no
network, no masking. Its cost per env step stepped, times the env steps the scoring round
stepped, is the ceiling the round is compared with (``over_physics``; the target is ≤ 1.2).
Zero actions visit other states than the policy does (the solver's work depends on the
contacts), so the policy's own work is also timed alone: its masked forwards of the batch
for the round's loop steps (``policy_share`` of the round).
``terminate=false`` builds the env with Gymnasium's ``terminate_when_unhealthy=False``, so
every episode runs ``max_steps`` steps: the longest round, as late in training, timed with
any actor.
The round is timed on its program's second run (the first also builds what runs once,
Warp's kernels and graphs; both are recorded). ``steps_per_check`` > 1 checks whether an
episode still runs only every that many steps (``score_missingness``): on a GPU each check
waits for the device.
``sequential=true`` also runs the paper's way for comparison: Gymnasium's C-MuJoCo env, one
episode after another for every u, the same actor through a jitted forward per step.

Prints compile and run times, loop steps, env steps stepped and env steps/s, and appends a
record to benchmarks/results/scoring_round.jsonl.
"""

from __future__ import annotations

import dataclasses
import time

import jax
import jax.numpy as jnp
import numpy as np

from admissable_jax.checkpointing import Checkpoints
from admissable_jax.cli import check_at_least_one, parse_args
from admissable_jax.config import TrainConfig, default_score_envs
from admissable_jax.envs import make_env, observation_size
from admissable_jax.host_loop import init_arguments
from admissable_jax.missingness import mask_observation, num_candidate_sets
from admissable_jax.run_spec import RunSpec
from admissable_jax.scoring import score_missingness
from admissable_jax.training import Trainer
from common import append_record, peak_host_memory_mb, run_benchmark, timed


@dataclasses.dataclass
class ScoringBenchConfig:
    env: str = dataclasses.field(default="hopper", metadata={"help": "hopper, walker2d or ant"})
    n_episodes: int = dataclasses.field(default=10, metadata={"help": "N episodes per set"})
    max_steps: int = dataclasses.field(default=1000, metadata={"help": "episode step limit"})
    slots: int = dataclasses.field(default=-1, metadata={"help": "envs stepped at once (-1 = this backend's default, 0 = all episodes)"})
    run: str = dataclasses.field(default="", metadata={"help": "run directory whose last checkpoint gives the actor ('' = untrained actor)"})
    seed: int = dataclasses.field(default=0, metadata={"help": "PRNG seed"})
    physics: str = dataclasses.field(default="auto", metadata={"help": "auto | jax | warp (the env's physics backend)"})
    terminate: bool = dataclasses.field(default=True, metadata={"help": "false: episodes never terminate (every one runs max_steps)"})
    ceiling: bool = dataclasses.field(default=True, metadata={"help": "also time the pure-physics ceiling (zero actions, no policy)"})
    sequential: bool = dataclasses.field(default=False, metadata={"help": "also time the paper-style sequential Gymnasium loop"})
    steps_per_check: int = dataclasses.field(default=1, metadata={"help": "rollout steps between checks whether an episode still runs (score_missingness)"})


def _validate(bench: ScoringBenchConfig) -> None:
    check_at_least_one(bench, ("n_episodes", "max_steps", "steps_per_check"))
    if bench.slots < -1:
        raise ValueError(f"slots must be -1 (the backend's default), 0 (all episodes) or >= 1, got {bench.slots}")


def _compile_and_run(env, policy_fn, params, bench, hidden_sets, slots) -> tuple[object, float, float, float]:
    """(scores, compile seconds, first run's seconds, second run's seconds) of one scoring
    rollout: a program's first run also builds what it runs once (Warp's kernels and
    graphs), so the second one is the round's own time."""
    score = jax.jit(lambda *args: score_missingness(*args, steps_per_check=bench.steps_per_check),
                    static_argnums=(0, 1, 5, 6, 7))
    args = (env, policy_fn, params, jax.random.key(bench.seed), hidden_sets, bench.n_episodes, bench.max_steps, slots)
    start = time.perf_counter()
    compiled = score.lower(*args).compile()
    compile_s = time.perf_counter() - start
    result, first_s = timed(compiled, *args[2:5])
    _, run_s = timed(compiled, *args[2:5])
    return result, compile_s, first_s, run_s


def _policy_seconds(policy_fn, params, hidden: jax.Array, loop_steps: int) -> float:
    """Run seconds of the round's policy work alone: ``loop_steps`` masked forwards of the
    batch (each step's observations depend on the last actions, so nothing is hoisted)."""
    policy = jax.vmap(policy_fn, in_axes=(None, 0))

    def forward(_, obs):
        actions = policy(params, mask_observation(obs, hidden))
        return obs + 1e-6 * actions.sum(axis=-1, keepdims=True)

    run = jax.jit(lambda params, obs: jax.lax.fori_loop(0, loop_steps, forward, obs))
    obs = jax.random.normal(jax.random.key(0), hidden.shape)
    jax.block_until_ready(run(params, obs))
    start = time.perf_counter()
    jax.block_until_ready(run(params, obs))
    return time.perf_counter() - start


def main(argv: list[str]) -> None:
    bench = parse_args(ScoringBenchConfig, argv, "benchmarks/scoring_round.py", __doc__.splitlines()[0], _validate)
    config = TrainConfig(env=bench.env, num_envs=8, buffer_size=8, learning_starts=256, progress=False,
                         physics=bench.physics).resolved()
    if bench.run:  # its sets (k, up_to_k, the empty set) and network sizes
        config = TrainConfig(**{**dataclasses.asdict(config), **_saved_sizes(bench.run)}).resolved()
    num_sets = num_candidate_sets(observation_size(config.env), config.k, config.include_empty_set, config.up_to_k)
    episodes = (num_sets + 1) * bench.n_episodes
    slots = {-1: default_score_envs(episodes), 0: episodes}.get(bench.slots, min(bench.slots, episodes))
    env = make_env(config.env, episode_length=bench.max_steps, physics=config.physics, max_batch=slots,
                   terminate_when_unhealthy=bench.terminate)
    trainer = Trainer(env, RunSpec.of(config))
    state = jax.jit(trainer.init)(*init_arguments(config))
    label = "untrained actor"
    if bench.run:
        step, state = Checkpoints(f"{bench.run}/checkpoints").restore(state)
        label = f"actor of {bench.run} at {step} env steps"
    result, compile_s, first_s, run_s = _compile_and_run(env, trainer.policy, state.sac.actor_params, bench,
                                                         trainer.hidden_sets, slots)
    lengths = np.asarray(result.lengths)
    loop_steps = int(result.loop_steps)
    stepped = loop_steps * slots
    record = {
        "env": env.display_name, "physics": env.physics_name, "n_episodes": bench.n_episodes, "sets": trainer.num_sets,
        "batch_episodes": episodes, "slots": slots, "max_steps": bench.max_steps, "terminate": bench.terminate,
        "policy": label, "steps_per_check": bench.steps_per_check,
        "compile_s": round(compile_s, 2), "first_run_s": round(first_s, 3), "run_s": round(run_s, 3),
        "loop_steps": loop_steps, "env_steps_stepped": stepped,
        "env_steps_in_episodes": int(lengths.sum()),
        "stepped_per_s": round(stepped / run_s, 1),
        "min_score": float(result.min_score), "clean_score": float(result.clean_score),
    }
    print(
        f"{record['env']} ({env.physics_name} physics), {label}: {trainer.num_sets}+1 sets x {bench.n_episodes} episodes = {episodes} "
        f"episodes on {slots} slots; {loop_steps} loop steps, {stepped:,} env steps stepped for "
        f"{record['env_steps_in_episodes']:,} in episodes (a check every {bench.steps_per_check} steps); "
        f"compile {compile_s:.1f} s, run {run_s:.2f} s (its first {first_s:.2f} s), "
        f"{stepped / run_s:,.0f} env steps/s stepped; min_u a_u {record['min_score']:.1f}, clean {record['clean_score']:.1f}"
    )
    if bench.ceiling:
        zero_action = jnp.zeros(env.action_size)
        physics, _, _, physics_s = _compile_and_run(env, lambda params, obs: zero_action, None, bench, trainer.hidden_sets, slots)
        physics_stepped = int(physics.loop_steps) * slots
        ceiling_s = physics_s / physics_stepped * stepped
        hidden = jnp.concatenate([trainer.hidden_sets, jnp.zeros((1, env.observation_size))])
        policy_s = _policy_seconds(trainer.policy, state.sac.actor_params, hidden[jnp.arange(slots) % len(hidden)], loop_steps)
        record.update({
            "physics_run_s": round(physics_s, 3), "physics_env_steps_stepped": physics_stepped,
            "physics_stepped_per_s": round(physics_stepped / physics_s, 1),
            "ceiling_s": round(ceiling_s, 3), "over_physics": round(run_s / ceiling_s, 3),
            "policy_alone_s": round(policy_s, 3), "policy_share": round(policy_s / run_s, 4),
        })
        print(
            f"pure physics (zero actions, same slots and refills): {physics_stepped:,} env steps in {physics_s:.2f} s "
            f"({physics_stepped / physics_s:,.0f}/s); ceiling for this round {ceiling_s:.2f} s; "
            f"scoring / ceiling = {record['over_physics']:.2f}; the policy's forwards alone take "
            f"{policy_s:.3f} s ({record['policy_share']:.1%} of the round)"
        )
    if bench.sequential:
        record.update(_sequential_round(env, trainer, state.sac.actor_params, bench))
        record["sequential_over_batched"] = round(record["sequential_s"] / run_s, 3)
        print(
            f"sequential Gymnasium loop: {record['sequential_env_steps']} env steps in "
            f"{record['sequential_s']:.1f} s ({record['sequential_ms_per_step']:.3f} ms/step); "
            f"sequential time / batched time = {record['sequential_over_batched']:.2f}"
        )
    record["peak_host_memory_mb"] = round(peak_host_memory_mb(), 1)
    append_record("scoring_round", record)


def _sequential_round(env, trainer, actor_params, bench) -> dict:
    """Every set (and the clean case), N episodes each, one at a time on Gymnasium."""
    import gymnasium

    gym_env = gymnasium.make(env.gymnasium_id, max_episode_steps=bench.max_steps)
    act = jax.jit(lambda params, obs, hidden: trainer.policy(params, mask_observation(obs, hidden)))
    rows = [*np.asarray(trainer.hidden_sets), np.zeros(env.observation_size, np.float32)]
    act(actor_params, jnp.zeros(env.observation_size), jnp.asarray(rows[0]))  # compile outside the timing
    steps, returns = 0, []
    start = time.perf_counter()
    for hidden in rows:
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
    keys = ("num_envs", "buffer_size", "hidden_size", "hidden_layers", "k", "up_to_k", "include_empty_set",
            "score_every", "learning_starts", "batch_size")
    return {key: saved[key] for key in keys if key in saved}  # up_to_k: not in a config written before it


if __name__ == "__main__":
    run_benchmark(main)
