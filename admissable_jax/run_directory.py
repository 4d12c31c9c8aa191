"""A run's directory: its files, their row formats, and the rules for starting and resuming.

``config.yaml`` (the resolved config), ``observation_names.json`` (the names of the d
features u hides, as the env names them, so that a run is read back without its env's
code), ``scores.jsonl`` (one row per scoring), ``metrics.jsonl`` (one row of training
curves per scoring interval); checkpoints are kept by whoever drives the run. One process
owns the directory at a time (:mod:`.locks`).
"""

from __future__ import annotations

import dataclasses
import datetime
import glob
import json
import math
import os
from typing import Any

import numpy as np
import yaml
from omegaconf import OmegaConf

from admissable_jax.best_policy import BEST_POLICY, best_kept
from admissable_jax.checkpointing import CheckpointError, Checkpoints
from admissable_jax.cli import report, yaml_problem
from admissable_jax.config import EXPERIMENT_SETTINGS, RUN_SETTINGS, TrainConfig
from admissable_jax.envs import env_physics, observation_names
from admissable_jax.errors import make_directory, remove_if_unused
from admissable_jax.locks import RunLock
from admissable_jax.loggers import FINGERPRINT, Loggers
from admissable_jax.missingness import describe_set
from admissable_jax.provenance import INVOCATIONS
from admissable_jax.scoring import MissingnessScores

# Settings that may change when a run is resumed; any other difference is refused.
# score_envs only changes how many episodes a scoring round steps at once, not its scores,
# and worlds_per_call how many envs one physics call steps (the same physics, to float rounding);
# out is wherever the run directory is now (it may have been moved or copied).
RESUMABLE_CHANGES = ("resume", "resume_step", "fast_forward", "total_steps", "progress", "checkpoint_every",
                     "keep_checkpoints", "score_envs", "worlds_per_call", "out", "time_limit", "logger")


OBSERVATION_NAMES = "observation_names.json"
# What a run writes before its first scoring: a folder holding only these is removed again.
SETTINGS_FILES = (RUN_SETTINGS, OBSERVATION_NAMES)


def run_config_path(path: str) -> str:
    """The ``config.yaml`` of the run in ``path``; FileNotFoundError in one line where there
    is none, naming a run folder under ``path`` where it holds some (an experiment's)."""
    config_path = os.path.join(path, RUN_SETTINGS)
    if os.path.isfile(config_path):
        return config_path
    below = sorted(os.path.dirname(found) for found in glob.glob(os.path.join(glob.escape(path), "*", RUN_SETTINGS)))
    holds = f"; the runs under it are its folders, like {below[0]}" if below else ""
    raise FileNotFoundError(f"{path} is not a run directory (no config.yaml){holds}")


def is_experiment(path: str) -> bool:
    """Whether the folder ``path`` holds an experiment (its ``experiment.yaml``)."""
    return os.path.isfile(os.path.join(path, EXPERIMENT_SETTINGS))


def experiment_pairs(root: str) -> list[str]:
    """The pair folders of the experiment in ``root`` (each with its ``config.yaml``), in name
    order; FileNotFoundError in one line where it holds none (moved away)."""
    pairs = sorted(name for name in os.listdir(root) if os.path.isfile(os.path.join(root, name, RUN_SETTINGS)))
    if not pairs:
        raise FileNotFoundError(f"{root} holds an experiment.yaml but no pair directories")
    return [os.path.join(root, name) for name in pairs]


def experiment_of(run_dir: str) -> str | None:
    """The folder of the experiment whose pair the run in ``run_dir`` is (a run without
    checkpoints of its own in a folder that holds an experiment, whose checkpoints hold
    every pair), as spelt from ``run_dir``; None for a run of its own."""
    parent = os.path.normpath(os.path.join(run_dir, os.pardir))
    if Checkpoints.steps_in(os.path.join(run_dir, "checkpoints")) or not is_experiment(parent):
        return None
    return parent


def _first_command(run: str) -> str | None:
    """The first line of ``run``'s ``invocations.jsonl`` (when and where the run began, and
    the command): a run keeps it wherever it is moved or copied; None where ``run`` holds none."""
    try:
        with open(os.path.join(run, INVOCATIONS)) as file:
            return file.readline() or None
    except OSError:
        return None


def same_run_at(then: str, now: str, written: str) -> bool:
    """Whether the run that was at ``then`` when ``written`` (a file or folder made for it:
    an audit, an exported policy) was written is the run now at ``now``: the same folder by
    another name (a link) or a copy (the same first command), or moved since with ``written``
    in its folder (``then`` holds no run any more)."""
    first = _first_command(then)
    if first is None:
        inside = os.path.realpath(now)
        return os.path.commonpath([inside, os.path.realpath(written)]) == inside
    return first == _first_command(now)


def same_policy_record(then: dict[str, Any], now: dict[str, Any], written: str) -> bool:
    """Whether ``then``, what ``written`` (an audit, an exported policy, a video) recorded of
    the run it came from, is ``now``: equal (its run may be gone since), or equal but for the
    ``"run"`` path, that path's run the run now at ``now``'s (:func:`same_run_at`): the same
    policy of the same run, moved, linked or copied."""
    if then == now:
        return True
    run, earlier = now.get("run"), then.get("run")
    return bool(run and earlier) and {**then, "run": run} == now and same_run_at(earlier, run, written)


def check_folder_kind(out: str, command: str) -> None:
    """FileExistsError in one line where ``out`` of ``command`` (``train`` or ``experiment``)
    is another command's folder: an experiment's, or one of its pairs, for ``train`` (whose
    run would sit inside it, or miss the checkpoints the experiment keeps for every pair); a
    train run's, or an experiment's pair, for ``experiment``. It names the command that
    continues what is there. A pair is a run without checkpoints of its own in a folder that
    holds an experiment."""
    holds_run = os.path.isfile(os.path.join(out, RUN_SETTINGS))
    experiment = experiment_of(out) if holds_run else None
    if experiment is not None:
        found = f"a pair of the experiment in {experiment}, whose checkpoints hold every pair"
        owner, where = "experiment", experiment
    elif command == "train" and is_experiment(out):
        found, owner, where = "an experiment", "experiment", out
    elif command == "experiment" and holds_run:
        found, owner, where = "a train run", "train", out
    else:
        return
    raise FileExistsError(f"{out} is {found}: choose another out, or continue it with python -m admissable_jax.{owner} "
                          f"resume=true out={where}")


def recorded_observation_names(run_dir: str) -> list[str] | None:
    """The feature names a run recorded (``observation_names.json``); None for a run from
    before the file was written, whose env's code names them."""
    path = os.path.join(run_dir, OBSERVATION_NAMES)
    try:
        with open(path) as file:
            names = json.load(file)
    except FileNotFoundError:
        return None
    except (OSError, ValueError) as error:
        raise ValueError(f"{path} cannot be read ({error})") from None
    if not isinstance(names, list) or not all(isinstance(name, str) for name in names):
        raise ValueError(f"{path} must hold a JSON list of feature names")
    return names


# What every scores.jsonl and metrics.jsonl row holds, and what every scores.jsonl row holds
# (score_row): read_jsonl's required keys for them.
RECORD_KEYS = ("env_steps",)
SCORING_KEYS = ("env_steps", "scores", "p_miss", "min_score", "clean_score")


class TornLine(ValueError):
    """A JSONL file's last line is cut off (a crash mid-append)."""


def read_jsonl(path: str, torn: str = "raise", required: tuple[str, ...] = ()) -> list[dict[str, Any]]:
    """The rows of a JSONL file, each a JSON object holding the keys ``required``. A last
    line that does not parse is what a crash in mid-append leaves: ``torn="drop"`` leaves it
    out (the caller says so), ``"raise"`` raises :class:`TornLine` naming the file. A bad
    line before the last, or a row that is no object or lacks a key (an edit by hand,
    another tool's line), is corruption: a ValueError naming the file and line."""
    with open(path) as file:
        lines = [line for line in file.read().split("\n") if line.strip()]
    rows = []
    for number, line in enumerate(lines, 1):
        try:
            row = json.loads(line)
        except json.JSONDecodeError as error:
            if number < len(lines):
                raise ValueError(f"{path} line {number} is not valid JSON ({error.msg}); the file is corrupt") from None
            if torn == "drop":
                return rows
            raise TornLine(f"{path}: the last line is cut off (a crash mid-write?): {error.msg}") from None
        missing = [key for key in required if key not in row] if isinstance(row, dict) else None
        if missing is None or missing:
            what = f"holds no {missing[0]!r}" if missing else f"is a JSON {type(row).__name__}, not an object"
            raise ValueError(f"{path} line {number} {what}; the file is corrupt")
        rows.append(row)
    return rows


def read_run_file(run_path: str, name: str, torn: str = "raise") -> list[dict[str, Any]]:
    """The rows of the run's JSONL file ``name`` (scores.jsonl, metrics.jsonl: each row at
    its ``env_steps``; none where it has no such file yet). ``torn``: what a cut-off last
    line does (:func:`read_jsonl`)."""
    path = os.path.join(run_path, name)
    return read_jsonl(path, torn, RECORD_KEYS) if os.path.exists(path) else []


def load_config_yaml(path: str):
    """A run's ``config.yaml`` as an OmegaConf node; one-line ValueError if it is not valid YAML."""
    try:
        return OmegaConf.load(path)
    except yaml.YAMLError as error:
        raise ValueError(f"{path} is not valid YAML{yaml_problem(error)}") from None


def load_config(path: str, cls=TrainConfig):
    """The ``cls`` dataclass saved in the YAML file ``path``; keys it lacks take their
    defaults (files written before a key existed), a key it does not know is an error."""
    return OmegaConf.to_object(OmegaConf.merge(OmegaConf.structured(cls), load_config_yaml(path)))


def score_row(env_steps: int, scores: MissingnessScores, p_miss, hidden_sets, estimator: str,
              listed: bool = False, fail_steps: tuple[int, ...] = (0,)) -> dict[str, Any]:
    """One ``scores.jsonl`` row: every a_u, the minimum and its set, the clean score, p_miss,
    and which estimator made the scores (``rollout``: the paper's undiscounted returns;
    ``critic``/``horizon``: discounted values, whose ``mean_episode_length`` counts the
    physics steps each estimate ran). ``hidden_sets`` are the scored sets' rows; ``listed``
    adds them as ``sets`` (a pool's sets change from row to row; U's are the same in all).
    A row that scores all of U also holds ``mean_score``, the mean of a_u over U: the
    average case beside the worst (the return when u is drawn uniformly from U, which is
    what uniform training optimises); a pool's row has none, its sets being the worst found.
    A row scored with sensors failing mid-episode (``fail_steps``, ``score_fail_at``) names
    the steps as ``score_fail_at``."""
    argmin = int(scores.argmin)
    sets = {"sets": [describe_set(row) for row in np.asarray(hidden_sets)]} if listed else {}
    average = {} if listed else {"mean_score": float(scores.mean_score)}
    return {
        "env_steps": env_steps,
        "score_estimator": estimator,
        **({"score_fail_at": ",".join(map(str, fail_steps))} if fail_steps != (0,) else {}),
        "min_score": float(scores.min_score),
        "argmin": argmin,
        "argmin_set": describe_set(np.asarray(hidden_sets[argmin])),
        **average,
        "clean_score": float(scores.clean_score),
        "scores": np.asarray(scores.scores).tolist(),
        "p_miss": np.asarray(p_miss).tolist(),
        "mean_episode_length": float(np.asarray(scores.lengths).mean()),
        **sets,
    }


def metrics_row(env_steps, grad_steps, chunk, train_seconds, score_seconds, config, num_runs,
                fingerprint: int) -> dict[str, Any]:
    """One run's training curves over the last chunk. Speeds are per run: a batch of
    ``num_runs`` runs shares the wall-clock time. ``state_fingerprint``, the training
    state's after the scoring, is what a fast-forward checks (admissable_jax.fast_forward)."""
    learned = chunk["learned"].astype(bool)
    episodes = int(chunk["episodes"].sum())
    row = {
        "env_steps": env_steps,
        "grad_steps": grad_steps,
        "episodes": episodes,
        "episode_return": float(chunk["episode_return_sum"].sum() / episodes) if episodes else None,
        "episode_length": float(chunk["episode_length_sum"].sum() / episodes) if episodes else None,
        "env_steps_per_s": config.score_every / train_seconds,
        "grad_steps_per_s": float(learned.sum()) * config.updates_per_iteration / train_seconds,
        "score_seconds": score_seconds,
        "runs_in_program": num_runs,
        FINGERPRINT: fingerprint,
    }
    for name in ("critic_loss", "actor_loss", "alpha", "entropy", "q_mean"):
        row[name] = float(chunk[name][learned].mean()) if learned.any() else None
    return row


# The last scoring intervals (of SAC's training, after the warm-up) whose wall time gives a
# run's pace: `status`'s time left, and the progress bar's.
PACE_INTERVALS = 5


def trained_at(row: dict[str, Any], config: TrainConfig) -> bool:
    """Whether the scoring ``row`` scored a policy SAC had trained: one after ``learning_starts``.
    Before it the actor is its random initialisation, which may score high without being any
    product of training (Ant's stands still and earns about 990 of healthy reward with every
    feature hidden, more than its runs' trained policies reached at 120k env steps)."""
    return row["env_steps"] > config.learning_starts


def best_scoring(rows: list[dict[str, Any]], config: TrainConfig) -> dict[str, Any] | None:
    """The first of the scoring ``rows`` with the highest min_u a_u among those SAC had trained
    (:func:`trained_at`); None where there is none: the scoring whose policy
    ``best_policy.npz`` keeps."""
    trained = [row for row in rows if trained_at(row, config)]
    return max(trained, key=lambda row: row["min_score"]) if trained else None


class RunDirectory:
    """A run's folder: config.yaml, observation_names.json, scores.jsonl, metrics.jsonl
    (checkpoints are kept by whoever drives the run: the run's own ``checkpoints/`` or the
    experiment's)."""

    def __init__(self, config: TrainConfig, checkpoint_dir: str):
        self.path, self.config = config.out, config
        self._best_score: float | None = None  # the highest min_u a_u scored so far (beats_best)
        config_path = os.path.join(self.path, RUN_SETTINGS)
        if config.resume and not os.path.exists(config_path):  # checked before anything is created
            raise CheckpointError(f"nothing to resume: {config_path} does not exist")
        self.made_here = not os.path.exists(self.path)
        make_directory(self.path, "run directory")
        self.lock = RunLock(self.path)
        self.lock.acquire()
        try:
            self._prepare(config, config_path, checkpoint_dir)
            self.loggers = Loggers(config.logger, self.path, dataclasses.asdict(config))
        except BaseException:
            self.lock.release()
            self._remove_if_unused()
            raise

    def _prepare(self, config: TrainConfig, config_path: str, checkpoint_dir: str) -> None:
        has_checkpoints = os.path.isdir(checkpoint_dir) and bool(os.listdir(checkpoint_dir))
        if config.resume:
            self._check_same_run(config, config_path, checkpoint_dir)
        elif has_checkpoints:
            raise FileExistsError(
                f"{self.path} already holds a run; pass resume=true to continue it or choose another out"
            )
        else:  # rows of an earlier run that stopped before its first checkpoint: not beside this config
            for note in self.set_aside_rows_after(0):
                report(note)
        OmegaConf.save(OmegaConf.structured(config), config_path)
        with open(os.path.join(self.path, OBSERVATION_NAMES), "w") as file:
            json.dump(observation_names(config.env), file)

    def close(self) -> None:
        """Give the directory back (close the logger, remove the lock). A folder this run
        made and wrote nothing into but its settings (it stopped before its first scoring:
        refused for memory, ``budget_only``, interrupted while compiling) is removed again."""
        self.loggers.close()
        self.lock.release()
        self._remove_if_unused()

    def _remove_if_unused(self) -> None:
        if self.made_here:
            remove_if_unused(self.path, SETTINGS_FILES)

    @staticmethod
    def _check_same_run(config: TrainConfig, config_path: str, checkpoint_dir: str) -> None:
        saved = load_config(config_path)
        saved.physics = env_physics(saved.env, saved.physics)  # saved as "auto", or as warp for a JAX env
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

    def record_invocation(self, record: dict[str, Any]) -> None:
        """Add the command now training to ``invocations.jsonl`` (admissable_jax.provenance)."""
        with open(os.path.join(self.path, INVOCATIONS), "a") as file:
            file.write(json.dumps(record) + "\n")

    def append(self, name: str, row: dict[str, Any]) -> None:
        """Append ``row`` to the JSONL file ``name`` (the record), and to the loggers if any."""
        with open(os.path.join(self.path, name), "a") as file:
            file.write(json.dumps(row) + "\n")
        self.loggers.log(name, row)

    def read(self, name: str) -> list[dict[str, Any]]:
        return read_run_file(self.path, name)

    def set_aside_rows_after(self, step: int) -> list[str]:
        """Move the rows written after env step ``step``, where this run starts (0, when the
        directory is prepared, or the checkpoint it resumes from), from scores.jsonl and metrics.jsonl to
        scores-superseded.jsonl and metrics-superseded.jsonl, each stamped ``set_aside_at``:
        the run writes those steps again, and what an earlier run measured there (one that
        stopped before its checkpoint, or a branch ``resume_step`` left) is kept, as its
        checkpoints are in ``checkpoints-superseded/``. A torn last line is dropped (the
        checkpoint, not the log, is the truth). Returns one note per thing done."""
        notes, moved = [], {}
        stamp = datetime.datetime.now(datetime.timezone.utc).isoformat(timespec="seconds")
        for name in ("scores.jsonl", "metrics.jsonl"):
            path = os.path.join(self.path, name)
            if not os.path.exists(path):
                continue
            try:
                rows = read_jsonl(path, required=RECORD_KEYS)
            except TornLine:
                rows = read_jsonl(path, torn="drop", required=RECORD_KEYS)
                notes.append(f"dropped the cut-off last line of {path} (a crash mid-write)")
            later = [row for row in rows if row["env_steps"] > step]
            if later:
                aside = os.path.join(self.path, name.replace(".jsonl", "-superseded.jsonl"))
                with open(aside, "a") as file:
                    file.writelines(json.dumps({**row, "set_aside_at": stamp}) + "\n" for row in later)
                moved[name] = len(later)
            with open(path, "w") as file:
                file.writelines(json.dumps(row) + "\n" for row in rows if row["env_steps"] <= step)
        if moved:
            counts = " and ".join(f"{count} row(s) of {name}" for name, count in moved.items())
            notes.append(f"set aside {counts} from after env step {step} in {self.path} (*-superseded.jsonl): "
                         f"this run writes those steps again")
        best = best_kept(self.path)
        if best is not None and best[0] > step:  # the best of rows set aside: no longer the best of those kept
            aside = os.path.join(self.path, f"best_policy-superseded-step{best[0]}.npz")
            os.replace(os.path.join(self.path, BEST_POLICY), aside)
            notes.append(f"set aside the best policy of env step {best[0]} as {aside}")
        return notes

    def beats_best(self, row: dict[str, Any]) -> bool:
        """Whether the scoring ``row`` (the last appended) has a higher min_u a_u than every
        earlier scoring of the run that followed SAC's training, whose policy is then the one
        to keep (:mod:`admissable_jax.best_policy`). The earlier scorings are read from
        ``scores.jsonl`` once per command, then followed."""
        if not trained_at(row, self.config):
            return False
        if self._best_score is None:
            earlier = best_scoring([kept for kept in self.read("scores.jsonl") if kept["env_steps"] < row["env_steps"]],
                                   self.config)
            self._best_score = -math.inf if earlier is None else earlier["min_score"]
        if row["min_score"] > self._best_score:
            self._best_score = row["min_score"]
            return True
        return False
