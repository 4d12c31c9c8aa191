"""One training run: ``train_fn(config)`` and its run directory.

The host loop alternates two jitted functions: ``run_chunk`` (ζ env steps of SAC over the
parallel envs, on the device) and ``score_and_update`` (every u scored in one batched
rollout, then the adversary's p_miss update). After each scoring it appends one row to
``scores.jsonl`` and one to ``metrics.jsonl`` in the run directory, and every
``checkpoint_every`` scorings (and at the end) it saves an orbax checkpoint of the whole
training state, from which ``resume=true`` continues.
"""

from __future__ import annotations

import dataclasses
import json
import math
import os
import time
from typing import Any

import jax
import numpy as np
from omegaconf import OmegaConf
from tqdm.auto import tqdm

from admissable_jax.checkpointing import CheckpointError, Checkpoints
from admissable_jax.config import TrainConfig, validate
from admissable_jax.envs import make_env
from admissable_jax.missingness import describe_set
from admissable_jax.scoring import MissingnessScores
from admissable_jax.training import Trainer, TrainState

# Settings that may change when a run is resumed; any other difference is refused.
RESUMABLE_CHANGES = ("resume", "total_steps", "progress", "checkpoint_every")


class TrainingDiverged(RuntimeError):
    """A loss became NaN or infinite; the last checkpoint is kept."""


@dataclasses.dataclass
class TrainResult:
    """What a run produced. ``scores`` and ``metrics`` are the rows of the JSONL files."""

    config: TrainConfig
    trainer: Trainer
    state: TrainState
    scores: list[dict[str, Any]]
    metrics: list[dict[str, Any]]

    @property
    def actor_params(self):
        return self.state.sac.actor_params

    @property
    def run_dir(self) -> str:
        return self.config.out


def mode_flags(missingness: str) -> tuple[bool, bool]:
    """(adversarial, masking) for a missingness mode."""
    return missingness == "adversarial", missingness != "none"


def train_fn(config: TrainConfig) -> TrainResult:
    """Train SAC against missingness as ``config`` says; returns params and histories."""
    validate(config)
    config = config.resolved()
    env = make_env(config.env)
    env.max_episode_steps = config.episode_length
    trainer = Trainer(env, config)
    run = _RunDirectory(config)

    state = jax.jit(trainer.init)(config.seed, *mode_flags(config.missingness))
    start_step = 0
    if config.resume:
        start_step, state = run.checkpoints.restore(state)
        run.truncate_logs(start_step)

    num_scorings = math.ceil(config.total_steps / config.score_every)
    total = num_scorings * config.score_every
    run_chunk = jax.jit(trainer.run_chunk, static_argnums=1, donate_argnums=0)
    score_and_update = jax.jit(trainer.score_and_update, static_argnums=1, donate_argnums=0)

    bar = tqdm(total=total, initial=start_step, unit="step", disable=not config.progress, dynamic_ncols=True)
    try:
        for scoring in range(start_step // config.score_every, num_scorings):
            started = time.perf_counter()
            state, chunk_metrics = run_chunk(state, trainer.iterations_per_scoring)
            chunk_metrics = jax.device_get(chunk_metrics)
            train_seconds = time.perf_counter() - started
            env_steps = int(state.env_steps)
            _check_finite(chunk_metrics, env_steps, run)

            started = time.perf_counter()
            state, scores = score_and_update(state, config.score_episodes)
            score_row = _score_row(env_steps, scores, state, trainer)
            score_seconds = time.perf_counter() - started
            run.append("scores.jsonl", score_row)
            run.append("metrics.jsonl", _metrics_row(env_steps, state, chunk_metrics, train_seconds, score_seconds, config))

            last = scoring == num_scorings - 1
            if (scoring + 1) % config.checkpoint_every == 0 or last:
                run.checkpoints.save(env_steps, state)
            bar.update(config.score_every)
            bar.set_postfix(
                min_a_u=f"{score_row['min_score']:.1f}",
                clean=f"{score_row['clean_score']:.1f}",
                train_sps=f"{config.score_every / train_seconds:.0f}",
            )
    finally:
        bar.close()
        run.checkpoints.close()
    return TrainResult(config, trainer, state, run.read("scores.jsonl"), run.read("metrics.jsonl"))


def _check_finite(chunk_metrics: dict[str, np.ndarray], env_steps: int, run: "_RunDirectory") -> None:
    learned = chunk_metrics["learned"].astype(bool)
    for name in ("critic_loss", "actor_loss", "alpha"):
        if not np.all(np.isfinite(chunk_metrics[name][learned])):
            kept = run.checkpoints.latest_step()
            where = f"last checkpoint (step {kept}) kept" if kept is not None else "no checkpoint yet"
            raise TrainingDiverged(f"{name} became non-finite before env step {env_steps}; {where} in {run.path}")


def _score_row(env_steps: int, scores: MissingnessScores, state: TrainState, trainer: Trainer) -> dict[str, Any]:
    argmin = int(scores.argmin)
    return {
        "env_steps": env_steps,
        "min_score": float(scores.min_score),
        "argmin": argmin,
        "argmin_set": describe_set(np.asarray(trainer.hidden_sets[argmin])),
        "clean_score": float(scores.clean_score),
        "scores": np.asarray(scores.scores).round(4).tolist(),
        "p_miss": np.asarray(state.p_miss).tolist(),
        "mean_episode_length": float(np.asarray(scores.lengths).mean()),
    }


def _metrics_row(env_steps, state, chunk, train_seconds, score_seconds, config) -> dict[str, Any]:
    learned = chunk["learned"].astype(bool)
    episodes = int(chunk["episodes"].sum())
    row = {
        "env_steps": env_steps,
        "grad_steps": int(state.grad_steps),
        "episodes": episodes,
        "episode_return": float(chunk["episode_return_sum"].sum() / episodes) if episodes else None,
        "episode_length": float(chunk["episode_length_sum"].sum() / episodes) if episodes else None,
        "env_steps_per_s": config.score_every / train_seconds,
        "grad_steps_per_s": float(learned.sum()) * max(1, round(config.num_envs * config.utd)) / train_seconds,
        "score_seconds": score_seconds,
    }
    for name in ("critic_loss", "actor_loss", "alpha", "entropy", "q_mean"):
        row[name] = float(chunk[name][learned].mean()) if learned.any() else None
    return row


class _RunDirectory:
    """The run's folder: config.yaml, scores.jsonl, metrics.jsonl, checkpoints/."""

    def __init__(self, config: TrainConfig):
        self.path = config.out
        os.makedirs(self.path, exist_ok=True)
        config_path = os.path.join(self.path, "config.yaml")
        checkpoint_dir = os.path.join(self.path, "checkpoints")
        has_checkpoints = os.path.isdir(checkpoint_dir) and bool(os.listdir(checkpoint_dir))
        if config.resume:
            if not os.path.exists(config_path):
                raise CheckpointError(f"nothing to resume: {config_path} does not exist")
            self._check_same_run(config, config_path)
        elif has_checkpoints:
            raise FileExistsError(
                f"{self.path} already holds a run; pass resume=true to continue it or choose another out"
            )
        else:
            for name in ("scores.jsonl", "metrics.jsonl"):
                if os.path.exists(os.path.join(self.path, name)):
                    os.remove(os.path.join(self.path, name))
        OmegaConf.save(OmegaConf.structured(config), config_path)
        self.checkpoints = Checkpoints(checkpoint_dir)

    @staticmethod
    def _check_same_run(config: TrainConfig, config_path: str) -> None:
        saved = OmegaConf.to_object(OmegaConf.merge(OmegaConf.structured(TrainConfig), OmegaConf.load(config_path)))
        for field in dataclasses.fields(TrainConfig):
            if field.name in RESUMABLE_CHANGES:
                continue
            if getattr(saved, field.name) != getattr(config, field.name):
                raise ValueError(
                    f"cannot resume with {field.name}={getattr(config, field.name)!r}: "
                    f"the run in {config.out} has {field.name}={getattr(saved, field.name)!r}"
                )

    def append(self, name: str, row: dict[str, Any]) -> None:
        with open(os.path.join(self.path, name), "a") as file:
            file.write(json.dumps(row) + "\n")

    def read(self, name: str) -> list[dict[str, Any]]:
        path = os.path.join(self.path, name)
        if not os.path.exists(path):
            return []
        with open(path) as file:
            return [json.loads(line) for line in file if line.strip()]

    def truncate_logs(self, step: int) -> None:
        """Drop rows written after checkpoint ``step`` (the resumed run writes them again)."""
        for name in ("scores.jsonl", "metrics.jsonl"):
            rows = [row for row in self.read(name) if row["env_steps"] <= step]
            with open(os.path.join(self.path, name), "w") as file:
                file.writelines(json.dumps(row) + "\n" for row in rows)
