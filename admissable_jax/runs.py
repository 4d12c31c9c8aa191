"""Training runs on the host: ``train_fn(config)`` for one run, and the loop it shares with
:mod:`admissable_jax.experiment` (many (seed, mode) pairs vmapped in one program).

The host loop alternates two jitted functions: ``run_chunk`` (ζ env steps of SAC over the
parallel envs, on the device) and ``score_and_update`` (every u scored in one batched
rollout, then the adversary's p_miss update). After each scoring it appends one row to
``scores.jsonl`` and one to ``metrics.jsonl`` of every run directory, and every
``checkpoint_every`` scorings (and at the end) it saves an orbax checkpoint of the whole
training state, from which ``resume=true`` continues. Both functions are compiled before
the state is allocated, so a run that would not fit in memory stops with a one-line
message before it starts (:func:`memory_budget`).
"""

from __future__ import annotations

import contextlib
import dataclasses
import json
import math
import os
import sys
import time
from typing import Any, Callable

import jax
import numpy as np
import psutil
from omegaconf import OmegaConf
from tqdm.auto import tqdm

from admissable_jax.checkpointing import CheckpointError, Checkpoints
from admissable_jax.cli import USAGE_ERROR
from admissable_jax.config import TrainConfig, env_options, validate
from admissable_jax.envs import make_env, resolve_physics
from admissable_jax.locks import RunDirectoryLocked, RunLock
from admissable_jax.missingness import describe_set
from admissable_jax.scoring import MissingnessScores
from admissable_jax.training import Trainer, TrainState

# Settings that may change when a run is resumed; any other difference is refused.
# score_envs only changes how many episodes a scoring round steps at once, not its scores;
# out is wherever the run directory is now (it may have been moved or copied).
RESUMABLE_CHANGES = ("resume", "resume_step", "total_steps", "progress", "checkpoint_every", "score_envs", "out")


class TrainingDiverged(RuntimeError):
    """A loss became NaN or infinite; the last checkpoint is kept."""


class MemoryBudgetExceeded(RuntimeError):
    """The compiled programs and the training state would not fit in this device's memory."""


class PhysicsCapacityExceeded(RuntimeError):
    """The env's physics ran out of a fixed-size buffer; the last checkpoint is kept."""


class Interrupted(RuntimeError):
    """Ctrl-C during training; says where the last checkpoint is."""


INTERRUPTED = 130  # the shell's status for a program ended by SIGINT


class RunDirectoryError(RuntimeError):
    """The run directory cannot be created where ``out`` says."""


def run_from_cli(function: Callable[[Any], Any], config: Any) -> tuple[Any, int]:
    """(result, exit status) of ``function(config)`` for a command line: bad settings exit 2,
    a corrupt checkpoint, a diverged run, or one too large for memory or for the physics
    buffers exit 1, Ctrl-C exits 130 saying where to resume from, each with one line on
    stderr (finished work stays in the run directory)."""
    try:
        return function(config), 0
    except (ValueError, TypeError, FileExistsError, RunDirectoryError, RunDirectoryLocked) as error:
        print(f"error: {error}", file=sys.stderr)
        return None, USAGE_ERROR
    except (CheckpointError, TrainingDiverged, MemoryBudgetExceeded, PhysicsCapacityExceeded) as error:
        print(f"error: {error}", file=sys.stderr)
        return None, 1
    except Interrupted as error:
        print(f"interrupted: {error}", file=sys.stderr)
        return None, INTERRUPTED
    except KeyboardInterrupt:
        print("interrupted before training started; nothing to resume from", file=sys.stderr)
        return None, INTERRUPTED


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


def make_trainer(config: TrainConfig, num_runs: int = 1) -> Trainer:
    """The env and the trainer for a resolved config, sized for ``num_runs`` vmapped runs."""
    return Trainer(make_env(config.env, env_options(config, num_runs)), config)


def train_fn(config: TrainConfig) -> TrainResult:
    """Train SAC against missingness as ``config`` says; returns params and histories."""
    validate(config)
    config = config.resolved()
    trainer = make_trainer(config)
    checkpoint_dir = os.path.join(config.out, "checkpoints")
    run = RunDirectory(config, checkpoint_dir)
    try:
        checkpoints = Checkpoints(checkpoint_dir)
        init = lambda: trainer.init(config.seed, *mode_flags(config.missingness))
        state = TrainingLoop(trainer, config, [run], checkpoints, init, batched=False).run()
    finally:
        run.close()
    return TrainResult(config, trainer, state, run.read("scores.jsonl"), run.read("metrics.jsonl"))


@dataclasses.dataclass
class MemoryBudget:
    """Bytes the run needs on its device, from the compiled programs, against what it has."""

    state_bytes: int
    chunk_temp_bytes: int
    score_temp_bytes: int
    available_bytes: int
    device: str

    @property
    def needed_bytes(self) -> int:
        # The state stays live; the two programs run one after the other, so their
        # temporaries do not add up.
        return self.state_bytes + max(self.chunk_temp_bytes, self.score_temp_bytes)

    def describe(self) -> str:
        gib = lambda b: f"{b / 2**30:.2f} GiB"
        return (
            f"memory on {self.device}: training state {gib(self.state_bytes)} + largest program "
            f"temporaries {gib(max(self.chunk_temp_bytes, self.score_temp_bytes))} "
            f"(train chunk {gib(self.chunk_temp_bytes)}, scoring {gib(self.score_temp_bytes)}) "
            f"= {gib(self.needed_bytes)} of {gib(self.available_bytes)} available"
        )


def memory_budget(abstract_state, compiled_chunk, compiled_score) -> MemoryBudget:
    """What the state and the compiled programs need, and what the device has free."""
    device = jax.devices()[0]
    state_bytes = sum(leaf.size * leaf.dtype.itemsize for leaf in jax.tree.leaves(abstract_state))
    stats = device.memory_stats() if device.platform != "cpu" else None
    if stats and "bytes_limit" in stats:
        available = int(stats["bytes_limit"]) - int(stats.get("bytes_in_use", 0))
    else:
        available = int(psutil.virtual_memory().available)
    temp = lambda compiled: int(getattr(compiled.memory_analysis(), "temp_size_in_bytes", 0) or 0)
    return MemoryBudget(state_bytes, temp(compiled_chunk), temp(compiled_score), available,
                        f"{device.platform}:{getattr(device, 'device_kind', '')}")


def report(message: str) -> None:
    """A status line on stderr, with or without the progress bar."""
    tqdm.write(message, file=sys.stderr)


@contextlib.contextmanager
def _reporting(what: str):
    """Say what is about to happen, then how long it took."""
    report(f"{what}...")
    started = time.perf_counter()
    yield
    report(f"{what}: done in {time.perf_counter() - started:.1f} s")


def take_pair(tree: Any, index: int) -> Any:
    """Run ``index``'s part of a pytree batched over runs (leading axis)."""
    return jax.tree.map(lambda leaf: leaf[index], tree)


class TrainingLoop:
    """The host loop over scorings for one run or a vmapped batch of runs.

    ``init()`` builds the training state (batched over runs along a leading axis when
    ``batched``); the train chunk and the scoring round are the trainer's, vmapped over
    that axis when ``batched``. ``runs[i]`` is run i's directory.
    """

    def __init__(
        self,
        trainer: Trainer,
        config: TrainConfig,
        runs: list["RunDirectory"],
        checkpoints: Checkpoints,
        init: Callable[[], TrainState],
        batched: bool,
    ):
        self.trainer, self.config, self.runs, self.checkpoints = trainer, config, runs, checkpoints
        self.init, self.batched = init, batched
        run_chunk = lambda state: trainer.run_chunk(state, trainer.iterations_per_scoring)
        score_and_update = lambda state: trainer.score_and_update(state, config.score_episodes)
        self._run_chunk = jax.vmap(run_chunk) if batched else run_chunk
        self._score_and_update = jax.vmap(score_and_update) if batched else score_and_update

    def select_pair(self, tree: Any, pair: int) -> Any:
        """Run ``pair``'s part of a pytree of the loop's (the tree itself for one run)."""
        return take_pair(tree, pair) if self.batched else tree

    def compile(self) -> MemoryBudget:
        """Compile both programs without allocating the state; refuse if they won't fit."""
        abstract_state = jax.eval_shape(self.init)
        env = self.trainer.env
        where = f"{self.config.env} ({env.physics_name} physics) on {jax.devices()[0].platform}"
        with _reporting(f"compiling the training step for {where}"):
            self.run_chunk = jax.jit(self._run_chunk, donate_argnums=0).lower(abstract_state).compile()
        with _reporting(f"compiling the scoring round for {where}"):
            self.score_and_update = jax.jit(self._score_and_update, donate_argnums=0).lower(abstract_state).compile()
        budget = memory_budget(abstract_state, self.run_chunk, self.score_and_update)
        if budget.needed_bytes > budget.available_bytes:
            raise MemoryBudgetExceeded(
                f"does not fit: {budget.describe()}; use fewer pairs, fewer num_envs or a smaller buffer_size"
            )
        return budget

    def run(self) -> TrainState:
        config = self.config
        budget = self.compile()
        report(f"{len(self.runs)} run(s) x {config.num_envs} envs of {config.env} on "
               f"{self.trainer.env.physics_name} physics: {budget.describe()}")
        state = jax.jit(self.init)()
        start_step = 0
        if config.resume:
            start_step, state = self.checkpoints.restore(state, None if config.resume_step < 0 else config.resume_step)
            for run in self.runs:
                run.truncate_logs(start_step)
        num_scorings = math.ceil(config.total_steps / config.score_every)
        total = num_scorings * config.score_every
        bar = tqdm(total=total, initial=start_step, unit="step", disable=not config.progress, dynamic_ncols=True)
        try:
            for scoring in range(start_step // config.score_every, num_scorings):
                started = time.perf_counter()
                state, chunk_metrics = self.run_chunk(state)
                chunk_metrics = jax.device_get(chunk_metrics)
                train_seconds = time.perf_counter() - started
                env_steps = int(np.max(state.env_steps))
                self._check_finite(chunk_metrics, env_steps)
                self._check_physics(np.any(chunk_metrics["capacity_exceeded"]), env_steps)

                started = time.perf_counter()
                state, scores = self.score_and_update(state)
                scores = jax.device_get(scores)
                self._check_physics(np.any(scores.capacity_exceeded), env_steps)
                score_seconds = time.perf_counter() - started
                rows = []
                for pair, run in enumerate(self.runs):
                    pick = lambda tree: self.select_pair(tree, pair)
                    rows.append(_score_row(env_steps, pick(scores), pick(state.p_miss), self.trainer))
                    run.append("scores.jsonl", rows[-1])
                    run.append("metrics.jsonl", _metrics_row(
                        env_steps, int(pick(state.grad_steps)), pick(chunk_metrics),
                        train_seconds, score_seconds, config, len(self.runs)))

                if (scoring + 1) % config.checkpoint_every == 0 or scoring == num_scorings - 1:
                    self.checkpoints.save(env_steps, state)
                bar.update(config.score_every)
                bar.set_postfix(
                    min_a_u=f"{np.mean([row['min_score'] for row in rows]):.1f}",
                    clean=f"{np.mean([row['clean_score'] for row in rows]):.1f}",
                    train_sps=f"{config.score_every * len(self.runs) / train_seconds:.0f}",
                )
        except KeyboardInterrupt:
            raise Interrupted(f"{self._kept_checkpoint()}; continue with resume=true") from None
        finally:
            bar.close()
            self.checkpoints.close()
        return state

    def _kept_checkpoint(self) -> str:
        kept = self.checkpoints.latest_step()
        where = f"last checkpoint (step {kept}) kept" if kept is not None else "no checkpoint yet"
        return f"{where} in {self.checkpoints.directory}"

    def _check_physics(self, exceeded: bool, env_steps: int) -> None:
        if exceeded:
            raise PhysicsCapacityExceeded(
                f"at env step {env_steps}: {self.trainer.env.capacity_message()}; {self._kept_checkpoint()}"
            )

    def _check_finite(self, chunk_metrics: dict[str, np.ndarray], env_steps: int) -> None:
        for pair, run in enumerate(self.runs):
            metrics = self.select_pair(chunk_metrics, pair)
            learned = metrics["learned"].astype(bool)
            for name in ("critic_loss", "actor_loss", "alpha"):
                if not np.all(np.isfinite(metrics[name][learned])):
                    raise TrainingDiverged(
                        f"{name} became non-finite before env step {env_steps} in {run.path}; "
                        f"{self._kept_checkpoint()}"
                    )


def _score_row(env_steps: int, scores: MissingnessScores, p_miss, trainer: Trainer) -> dict[str, Any]:
    argmin = int(scores.argmin)
    return {
        "env_steps": env_steps,
        "min_score": float(scores.min_score),
        "argmin": argmin,
        "argmin_set": describe_set(np.asarray(trainer.hidden_sets[argmin])),
        "clean_score": float(scores.clean_score),
        "scores": np.asarray(scores.scores).round(4).tolist(),
        "p_miss": np.asarray(p_miss).tolist(),
        "mean_episode_length": float(np.asarray(scores.lengths).mean()),
    }


def _metrics_row(env_steps, grad_steps, chunk, train_seconds, score_seconds, config, num_runs) -> dict[str, Any]:
    """One run's training curves over the last chunk. Speeds are per run: a batch of
    ``num_runs`` runs shares the wall-clock time."""
    learned = chunk["learned"].astype(bool)
    episodes = int(chunk["episodes"].sum())
    row = {
        "env_steps": env_steps,
        "grad_steps": grad_steps,
        "episodes": episodes,
        "episode_return": float(chunk["episode_return_sum"].sum() / episodes) if episodes else None,
        "episode_length": float(chunk["episode_length_sum"].sum() / episodes) if episodes else None,
        "env_steps_per_s": config.score_every / train_seconds,
        "grad_steps_per_s": float(learned.sum()) * max(1, round(config.num_envs * config.utd)) / train_seconds,
        "score_seconds": score_seconds,
        "runs_in_program": num_runs,
    }
    for name in ("critic_loss", "actor_loss", "alpha", "entropy", "q_mean"):
        row[name] = float(chunk[name][learned].mean()) if learned.any() else None
    return row


class RunDirectory:
    """A run's folder: config.yaml, scores.jsonl, metrics.jsonl (checkpoints are kept by
    whoever drives the run: the run's own ``checkpoints/`` or the experiment's)."""

    def __init__(self, config: TrainConfig, checkpoint_dir: str):
        self.path = config.out
        config_path = os.path.join(self.path, "config.yaml")
        if config.resume and not os.path.exists(config_path):  # checked before anything is created
            raise CheckpointError(f"nothing to resume: {config_path} does not exist")
        try:
            os.makedirs(self.path, exist_ok=True)
        except OSError as error:
            raise RunDirectoryError(f"cannot create the run directory {self.path}: {error.strerror}") from None
        self.lock = RunLock(self.path)
        self.lock.acquire()
        try:
            self._prepare(config, config_path, checkpoint_dir)
        except BaseException:
            self.lock.release()
            raise

    def _prepare(self, config: TrainConfig, config_path: str, checkpoint_dir: str) -> None:
        has_checkpoints = os.path.isdir(checkpoint_dir) and bool(os.listdir(checkpoint_dir))
        if config.resume:
            self._check_same_run(config, config_path, checkpoint_dir)
        elif has_checkpoints:
            raise FileExistsError(
                f"{self.path} already holds a run; pass resume=true to continue it or choose another out"
            )
        else:
            for name in ("scores.jsonl", "metrics.jsonl"):
                if os.path.exists(os.path.join(self.path, name)):
                    os.remove(os.path.join(self.path, name))
        OmegaConf.save(OmegaConf.structured(config), config_path)

    def close(self) -> None:
        """Give the directory back (remove the lock)."""
        self.lock.release()

    @staticmethod
    def _check_same_run(config: TrainConfig, config_path: str, checkpoint_dir: str) -> None:
        saved = OmegaConf.to_object(OmegaConf.merge(OmegaConf.structured(TrainConfig), OmegaConf.load(config_path)))
        saved.physics = resolve_physics(saved.physics)  # runs saved before the key read "auto"
        for field in dataclasses.fields(TrainConfig):
            if field.name in RESUMABLE_CHANGES:
                continue
            if getattr(saved, field.name) != getattr(config, field.name):
                raise ValueError(
                    f"cannot resume with {field.name}={getattr(config, field.name)!r}: "
                    f"the run in {config.out} has {field.name}={getattr(saved, field.name)!r}"
                )
        reached = max(Checkpoints.steps_in(checkpoint_dir), default=0)
        if config.total_steps < reached:
            raise ValueError(
                f"cannot resume with total_steps={config.total_steps}: the run in {config.out} "
                f"already reached {reached} env steps"
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
