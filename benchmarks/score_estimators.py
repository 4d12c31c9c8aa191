"""How well the cheap score estimators track the paper's rollout, and what they cost.

    python benchmarks/score_estimators.py runs=runs/hopper-adversarial-s0 steps=50000,100000 horizons=0,10,100

For each run and checkpoint (``load_policy``: actor and twin critic), every u of the run's k
is scored by ``rollout`` (``score_missingness``, N whole episodes) and by each estimator
(``horizon=0`` is ``critic``; ``estimate_scores``), from the same N start states. Each
estimator's record holds, against ``rollout``:

- ``spearman``: the rank correlation of the |U| scores;
- ``argmin_agrees``: whether both name the same worst set;
- ``p_miss_tv``: the total-variation distance between the p_miss each induces
  (p ∝ 1/(a_u − l + ε), the run's l and ε);
- ``physics_steps`` and ``run_s`` of each (compiling excluded, reported apart), and their
  ratios.

It appends one record per (run, checkpoint, estimator) to ``results/score_estimators.jsonl``.
"""

from __future__ import annotations

import dataclasses
import time

import jax
import numpy as np

from admissable_jax.cli import parse_args
from admissable_jax.envs import make_env
from admissable_jax.method import inverse_score_p_miss
from admissable_jax.policies import load_policy
from admissable_jax.scoring import estimate_scores, score_missingness
from common import append_record, run_benchmark, timed


@dataclasses.dataclass
class ScoreEstimatorsConfig:
    runs: str = dataclasses.field(default="", metadata={"help": "comma list of train run directories (or experiment pairs')"})
    steps: str = dataclasses.field(default="-1", metadata={"help": "comma list of checkpoints (env steps); -1 = the latest"})
    horizons: str = dataclasses.field(default="0,10,100", metadata={"help": "H of each estimator; 0 = critic"})
    n_episodes: int = dataclasses.field(default=10, metadata={"help": "N: episodes (start states) per set"})
    seed: int = dataclasses.field(default=0, metadata={"help": "seed of the N start states"})


def _validate(config: ScoreEstimatorsConfig) -> None:
    if not config.runs:
        raise ValueError("give runs=RUN_DIR[,RUN_DIR...]")
    if config.n_episodes < 2 or any(int(h) < 0 for h in config.horizons.split(",")):
        raise ValueError("n_episodes must be >= 2 and horizons >= 0")


def compare(run_dir: str, step: int, horizons: list[int], n_episodes: int, seed: int) -> list[dict]:
    from scipy import stats

    policy = load_policy(run_dir, None if step < 0 else step)
    config, trainer = policy.config, policy.trainer
    sets = trainer.hidden_sets
    episodes = (int(sets.shape[0]) + 1) * n_episodes
    env = make_env(config.env, physics=config.physics, episode_length=config.episode_length, max_batch=episodes)
    rng = jax.random.key(seed)

    start = time.perf_counter()
    rollout_fn = jax.jit(lambda params, key: score_missingness(env, trainer.policy, params, key, sets, n_episodes,
                                                                num_slots=config.score_envs))  # as training scores
    rollout_fn = rollout_fn.lower(policy.actor_params, rng).compile()
    rollout_compile_s = time.perf_counter() - start
    rollout, rollout_s = timed(rollout_fn, policy.actor_params, rng)
    rollout_scores = np.asarray(rollout.scores, np.float64)
    p_rollout = inverse_score_p_miss(rollout_scores, config.lower_bound, config.epsilon)

    records = []
    for horizon in horizons:
        def estimate(actor, critic, key, horizon=horizon):
            return estimate_scores(env, trainer.policy, actor, trainer.critic_values, critic, key, sets, n_episodes,
                                   horizon, config.gamma)

        start = time.perf_counter()
        compiled = jax.jit(estimate).lower(policy.actor_params, policy.critic_params, rng).compile()
        compile_s = time.perf_counter() - start
        estimated, run_s = timed(compiled, policy.actor_params, policy.critic_params, rng)
        scores = np.asarray(estimated.scores, np.float64)
        p_estimate = inverse_score_p_miss(scores, config.lower_bound, config.epsilon)
        records.append({
            "run": run_dir, "env": env.gymnasium_id, "physics": env.physics_name, "checkpoint": policy.step,
            "k": config.k, "sets": int(sets.shape[0]), "n_episodes": n_episodes,
            "estimator": "critic" if horizon == 0 else "horizon", "horizon": horizon,
            "spearman": float(stats.spearmanr(scores, rollout_scores).statistic),
            "argmin_agrees": bool(np.argmin(scores) == np.argmin(rollout_scores)),
            "argmin_rollout": int(np.argmin(rollout_scores)), "argmin_estimate": int(np.argmin(scores)),
            "p_miss_tv": float(0.5 * np.abs(p_estimate - p_rollout).sum()),
            "physics_steps": horizon, "rollout_physics_steps": int(rollout.loop_steps),
            "run_s": round(run_s, 3), "rollout_run_s": round(rollout_s, 3),
            "compile_s": round(compile_s, 2), "rollout_compile_s": round(rollout_compile_s, 2),
            "cost_ratio_steps": horizon / max(1, int(rollout.loop_steps)), "cost_ratio_time": run_s / rollout_s,
            "scores": scores.tolist(), "rollout_scores": rollout_scores.tolist(),
        })
    return records


def main(argv: list[str]) -> None:
    config = parse_args(ScoreEstimatorsConfig, argv, "benchmarks/score_estimators.py", __doc__.strip().splitlines()[0],
                        _validate)
    horizons = [int(h) for h in config.horizons.split(",")]
    for run_dir in config.runs.split(","):
        for step in (int(s) for s in config.steps.split(",")):
            for record in compare(run_dir, step, horizons, config.n_episodes, config.seed):
                path = append_record("score_estimators", record)
                print(f"{record['env']} step {record['checkpoint']} {record['estimator']} H={record['horizon']}: "
                      f"spearman {record['spearman']:.2f}, argmin {'agrees' if record['argmin_agrees'] else 'differs'}, "
                      f"p_miss TV {record['p_miss_tv']:.3f}, physics steps {record['physics_steps']} vs "
                      f"{record['rollout_physics_steps']}, time {record['run_s']:.2f} s vs {record['rollout_run_s']:.2f} s "
                      f"({path})")


if __name__ == "__main__":
    run_benchmark(main)
