"""The sim-to-sim gap: a trained run's a_u in our MJX env and in Gymnasium's own C-MuJoCo env.

    python benchmarks/sim_to_sim.py run=runs/hopper-adversarial-s0 n_episodes=10 [step=-1 | best=true] [num_envs=8]

Loads the run's deterministic policy (``load_policy``), scores every u of the run's k on
both simulators with the same policy, the same sets and the same N: ours with
``score_missingness`` on the run's env (its physics backend, full 1,000-step episodes
unless the run set ``episode_length``), Gymnasium's with ``wrappers.score_policy`` on
``gymnasium.make_vec`` of the v5 env (its own episode starts). Prints a table per u and
appends a record to ``benchmarks/results/sim_to_sim.jsonl``. Episode starts differ between
the two, so a gap within the spread of the N returns is noise; a gap beyond it is the
simulators disagreeing under this policy.
"""

from __future__ import annotations

import dataclasses

import jax
import numpy as np

from admissable_jax.cli import parse_args
from admissable_jax.missingness import describe_set
from admissable_jax.policies import load_policy, requested_step
from admissable_jax.scoring import score_missingness
from admissable_jax.wrappers import score_policy
from common import append_record, run_benchmark


@dataclasses.dataclass
class SimToSimConfig:
    run: str = dataclasses.field(default="", metadata={"help": "a train run directory or an experiment pair's"})
    step: int = dataclasses.field(default=-1, metadata={"help": "checkpoint (env step); -1 = the latest"})
    best: bool = dataclasses.field(default=False, metadata={"help": "the policy the run kept at its best scoring "
                                                                    "(best_policy.npz) instead of a checkpoint"})
    n_episodes: int = dataclasses.field(default=10, metadata={"help": "N: episodes per set on each simulator"})
    num_envs: int = dataclasses.field(default=8, metadata={"help": "Gymnasium vector envs"})
    seed: int = dataclasses.field(default=0, metadata={"help": "seed of both simulators' episode starts"})


def _validate(config: SimToSimConfig) -> None:
    if not config.run:
        raise ValueError("run= is required (a run directory)")
    if config.n_episodes < 1 or config.num_envs < 1:
        raise ValueError("n_episodes and num_envs must be >= 1")
    if config.best and config.step >= 0:
        raise ValueError("best=true scores the policy the run kept at its best scoring: give no step=")


def main(argv: list[str]) -> None:
    config = parse_args(SimToSimConfig, argv, "benchmarks/sim_to_sim.py", __doc__.strip().splitlines()[0], _validate)
    policy = load_policy(config.run, requested_step(config.step, config.best))
    trainer, run = policy.trainer, policy.config
    ours = score_missingness(trainer.env, trainer.policy, policy.actor_params, jax.random.key(config.seed),
                             trainer.hidden_sets, config.n_episodes, None, run.score_envs)
    theirs = score_policy(trainer.env.gymnasium_id, policy.masked, n_episodes=config.n_episodes,
                          num_envs=config.num_envs, seed=config.seed, hidden_sets=np.asarray(trainer.hidden_sets),
                          max_episode_steps=trainer.env.max_episode_steps)
    names = [describe_set(row) for row in np.asarray(trainer.hidden_sets)]
    ours_scores, theirs_scores = np.asarray(ours.scores), theirs.scores
    spread = np.maximum(np.asarray(ours.returns).std(axis=1), theirs.returns.std(axis=1))
    kept = " (its best scoring's policy)" if config.best else ""
    print(f"{trainer.env.gymnasium_id}, {config.run} at env step {policy.step}{kept}, N = {config.n_episodes}")
    print("| u | MJX a_u | Gymnasium a_u | gap | larger std of the N returns |")
    print("|---|---|---|---|---|")
    for name, a, b, s in zip([*names, "clean"], [*ours_scores, float(ours.clean_score)],
                             [*theirs_scores, theirs.clean_score], spread):
        print(f"| {name} | {a:.1f} | {b:.1f} | {a - b:+.1f} | {s:.1f} |")
    record = {
        "run": config.run, "env": trainer.env.gymnasium_id, "physics": trainer.env.physics_name, "step": policy.step,
        "best_policy": policy.best_min_score is not None,
        "n_episodes": config.n_episodes, "sets": names, "mjx_scores": ours_scores.tolist(),
        "gymnasium_scores": theirs_scores.tolist(), "mjx_clean": float(ours.clean_score),
        "gymnasium_clean": float(theirs.clean_score), "mjx_min": float(ours_scores.min()),
        "gymnasium_min": float(theirs_scores.min()), "mjx_argmin": names[int(ours_scores.argmin())],
        "gymnasium_argmin": names[int(theirs_scores.argmin())], "spread": spread.tolist(),
    }
    print(f"min_u a_u: MJX {record['mjx_min']:.1f} ({record['mjx_argmin']}), Gymnasium {record['gymnasium_min']:.1f} "
          f"({record['gymnasium_argmin']}); record in {append_record('sim_to_sim', record)}")


if __name__ == "__main__":
    run_benchmark(main)
