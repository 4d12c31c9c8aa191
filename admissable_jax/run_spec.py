"""What the pure training core reads about a run: one frozen spec, worked out once.

A :class:`~admissable_jax.config.TrainConfig` is what a user writes (with "0 = auto"
defaults); :meth:`TrainConfig.resolved` fills those in and validates, once, at the entry
point; :meth:`RunSpec.of` then derives every size the core needs (env options, envs per
iteration, gradient steps per iteration, iterations per scoring, replay capacity, SAC
hyperparameters). :class:`~admissable_jax.training.Trainer` reads only this spec; the host
loop keeps the run-level settings (total steps, checkpoints, resume, progress).
"""

from __future__ import annotations

import dataclasses

from admissable_jax.agent import SACHyperparams
from admissable_jax.config import TrainConfig
from admissable_jax.envs import EnvOptions, observation_size
from admissable_jax.method import fail_steps
from admissable_jax.replay import buffer_capacity


@dataclasses.dataclass(frozen=True)
class RunSpec:
    env: str  # canonical env name
    env_options: EnvOptions  # episode limit, physics backend, batch capacity (see `of`)
    k: int  # |u|, or the largest |u| with up_to_k
    up_to_k: bool  # U holds the sets of 1 .. k features
    include_empty_set: bool
    num_envs: int  # envs stepped per iteration
    score_envs: int  # envs stepped at once in a scoring round
    score_episodes: int  # N
    score_estimator: str  # rollout | critic | horizon (admissable_jax.scoring)
    score_horizon: int  # H of the horizon estimator (of the score or the pool ranker)
    pool_size: int  # P sets scored per round, found by beam search; 0 = all of U
    pool_ranker: str  # the estimator that ranks the pool search's candidates
    pool_explore: float  # share of adversarial episodes hiding a uniform set of all U
    iterations_per_scoring: int  # ζ / num_envs
    updates_per_iteration: int  # num_envs · utd, at least 1
    buffer_capacity: int  # replay rows (a multiple of num_envs)
    learning_starts: int
    sac: SACHyperparams
    epsilon: float  # ε
    fail_steps: tuple[int, ...]  # env steps at which an episode's u fails, one drawn per episode; (0,): the paper's
    score_fail_steps: tuple[int, ...]  # env steps at which a scoring episode's u fails, spread over N; (0,): the paper's

    @classmethod
    def of(cls, config: TrainConfig, num_runs: int = 1) -> "RunSpec":
        """The spec of a resolved config, its env sized for ``num_runs`` vmapped runs, each
        stepping ``num_envs`` (training) or ``score_envs`` (scoring) envs at once."""
        if config.score_envs < 1 or config.num_envs < 1:
            raise ValueError("RunSpec.of needs a resolved config (TrainConfig.resolved())")
        return cls(
            env=config.env,
            env_options=EnvOptions(
                episode_length=config.episode_length,
                physics=config.physics,
                deterministic=config.deterministic_physics,
                worlds_per_call=config.worlds_per_call,
                max_batch=num_runs * max(config.num_envs, config.score_envs, horizon_ranker_batch(config)),
            ),
            k=config.k,
            up_to_k=config.up_to_k,
            include_empty_set=config.include_empty_set,
            num_envs=config.num_envs,
            score_envs=config.score_envs,
            score_episodes=config.score_episodes,
            score_estimator=config.score_estimator,
            score_horizon=config.score_horizon,
            pool_size=config.pool_size,
            pool_ranker=config.pool_ranker,
            pool_explore=config.pool_explore,
            iterations_per_scoring=config.score_every // config.num_envs,
            updates_per_iteration=config.updates_per_iteration,
            buffer_capacity=buffer_capacity(config.buffer_size, config.num_envs),
            learning_starts=config.learning_starts,
            sac=SACHyperparams(
                learning_rate=config.learning_rate, gamma=config.gamma, tau=config.tau,
                batch_size=config.batch_size, hidden_sizes=(config.hidden_size,) * config.hidden_layers,
            ),
            epsilon=config.epsilon,
            fail_steps=fail_steps(config.fail_at),  # (both checked against episode_length by resolved())
            score_fail_steps=fail_steps(config.score_fail_at),
        )


def horizon_ranker_batch(config: TrainConfig) -> int:
    """Envs stepped at once by the pool search when ``pool_ranker=horizon`` (every level
    steps its b · d candidates' N episodes and the clean case's together), else 0."""
    if config.pool_size == 0 or config.pool_ranker != "horizon":
        return 0
    return (config.pool_size * observation_size(config.env) + 1) * config.score_episodes
