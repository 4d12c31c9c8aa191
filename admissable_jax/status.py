"""Where runs stand: which finished, which run now, which stopped, and the command that continues each.

    python -m admissable_jax.status runs

One row per run under the folders given (an experiment's pairs each): env, mode, seed, the
env steps scored of those planned, the run's state, the last scoring's min_u a_u and clean
return, the best min_u a_u of its scorings and its env step (whose policy ``best_policy.npz``
keeps), how long ago the last scoring was written, and the wall time the rest takes at the pace
the run's own records measured (its last few scoring intervals: training and scoring). The
states (:data:`STATES`):

- ``running``: a live process holds the run's lock (its pid and host are named; one of
  another host while it renews the lock, as ``train`` takes it: :mod:`admissable_jax.locks`);
- ``finished``: its records (or a checkpoint) reach the planned env steps (a run copied
  without its checkpoints, as the GPU campaign brings its runs back, is finished too: its
  row names the checkpoint it lacks);
- ``stopped``: anything else that a command can continue (paused at ``time_limit``,
  interrupted, killed, crashed, refused a checkpoint by a full disk; *killed* where its
  process ended without giving back its lock, as no exit of Python does: SIGKILL, the
  out-of-memory killer, a machine that went down). The command that continues it is
  printed: ``resume=true`` from the latest checkpoint; ``fast_forward=true`` where the
  checkpoints are gone but the records can rebuild the run; the run's own settings again
  where it stopped before its first scoring;
- ``unreadable``: its ``config.yaml`` or records cannot be read (the reason is printed).

It only reads files (no JAX program is built), so it is safe beside running runs, on a
cluster's login node too. ``format=jsonl`` prints one JSON object per run for scripts.
"""

from __future__ import annotations

import dataclasses
import json
import os
import shlex
import time

from admissable_jax.best_policy import best_kept
from admissable_jax.checkpointing import Checkpoints
from admissable_jax.cli import fail, parse_args, run_main, setting
from admissable_jax.config import EXPERIMENT_SETTINGS, RUN_SETTINGS, TrainConfig
from admissable_jax.locks import LOCK_NAME, live_holder
from admissable_jax.loggers import FINGERPRINT
from admissable_jax.results import check_is_folder, distinct_directories, interval_seconds, paths_of
from admissable_jax.run_directory import (PACE_INTERVALS, best_scoring, experiment_of, load_config, read_run_file,
                                          run_config_path, trained_at)

STATES = ("running", "finished", "stopped", "unreadable")


@dataclasses.dataclass(frozen=True)
class RunStatus:
    """Where one run stands, read from its folder (:func:`run_status`)."""

    path: str
    state: str  # one of STATES
    env: str = ""
    mode: str = ""
    seed: int = 0
    planned_steps: int = 0  # total_steps rounded up to ζ: the env steps of the finished run
    scored_steps: int = 0  # the last scoring's env step (0: none yet)
    checkpoint_steps: int = 0  # the latest checkpoint's env step, where a resume starts (0: none)
    min_score: float | None = None  # the last scoring's min_u a_u
    clean_score: float | None = None  # the last scoring's clean return
    best_score: float | None = None  # the highest min_u a_u of its scorings after learning_starts
    best_steps: int = 0  # the env step of that scoring (0: none yet)
    best_policy_kept: bool = False  # best_policy.npz holds that scoring's policy (load_policy(run, "best"))
    seconds_since_scoring: float | None = None  # since the last scoring row was written
    seconds_left: float | None = None  # the steps left (from the checkpoint, for a stopped run) at the records' pace
    holder: str = ""  # running: "process <pid> on <host>"
    killed: bool = False  # stopped, and its process ended without giving back its lock
    experiment: str = ""  # the experiment folder of a pair ('' for a run of its own)
    continue_with: str = ""  # stopped: the command that continues it
    problem: str = ""  # unreadable: why


def run_status(run_dir: str) -> RunStatus:
    """Where the run in ``run_dir`` stands (``unreadable``, with the reason, where its
    settings or records cannot be read: one bad folder does not hide the others)."""
    try:
        config = load_config(run_config_path(run_dir), TrainConfig)
        scores, metrics = (read_run_file(run_dir, name, torn="drop") for name in ("scores.jsonl", "metrics.jsonl"))
    except (OSError, ValueError, KeyError) as error:  # KeyError: OmegaConf's, a key TrainConfig does not know
        return RunStatus(run_dir, "unreadable", problem=str(error).strip().splitlines()[0])
    experiment = experiment_of(run_dir) or ""
    checkpoint_steps = max(Checkpoints.steps_in(os.path.join(experiment or run_dir, "checkpoints")), default=0)
    holder = live_holder(run_dir)
    planned = config.planned_steps
    last = scores[-1] if scores else {}
    scored = last.get("env_steps", 0)
    best = best_scoring(scores, config) or {}
    if holder is not None:
        state = "running"
    elif max(checkpoint_steps, scored) >= planned:  # its records complete, though its checkpoints may be elsewhere
        state = "finished"
    else:
        state = "stopped"
    interval = _interval_seconds(metrics, config)
    start = scored if state == "running" else checkpoint_steps
    return RunStatus(
        path=run_dir, state=state, env=config.env, mode=config.missingness, seed=config.seed, planned_steps=planned,
        scored_steps=scored, checkpoint_steps=checkpoint_steps, min_score=last.get("min_score"),
        clean_score=last.get("clean_score"), best_score=best.get("min_score"), best_steps=best.get("env_steps", 0),
        best_policy_kept=bool(best) and best_kept(run_dir) == (best["env_steps"], best["min_score"]),
        seconds_since_scoring=time.time() - os.path.getmtime(os.path.join(run_dir, "scores.jsonl")) if scores else None,
        seconds_left=(planned - start) / config.score_every * interval if interval and state != "finished" else None,
        holder=f"process {holder.get('pid')} on {holder.get('host')}" if holder is not None else "",
        killed=state == "stopped" and os.path.exists(os.path.join(run_dir, LOCK_NAME)),
        experiment=experiment,
        continue_with=_continue_with(run_dir, experiment, checkpoint_steps, metrics) if state == "stopped" else "",
    )


def _interval_seconds(metrics: list[dict], config: TrainConfig) -> float | None:
    """The mean wall time of the run's last scoring intervals (training, then scoring) that
    trained SAC, from its ``metrics.jsonl``; None where it records none. The intervals of the
    random-action warm-up (up to ``learning_starts``) take no gradient step, so they run far
    faster than the rest (the point mass: 40,000 env steps/s, then 24) and would promise a
    run's end far too soon."""
    trained = [row for row in metrics if row.get("env_steps_per_s") and "score_seconds" in row
               and trained_at(row, config)]
    recent = trained[-PACE_INTERVALS:]
    if not recent:
        return None
    return sum(interval_seconds(row, config.score_every) for row in recent) / len(recent)


def _continue_with(run_dir: str, experiment: str, checkpoint_steps: int, metrics: list[dict]) -> str:
    """The command that continues a stopped run: from its latest checkpoint; from its
    records where the checkpoints are gone but its rows hold state fingerprints (a run
    copied without them, or a crash before the first); else its own settings again (it
    stopped before its first checkpoint, and a new start sets the earlier rows aside)."""
    if experiment:
        command, out, settings = "experiment", experiment, EXPERIMENT_SETTINGS
    else:
        command, out, settings = "train", run_dir, RUN_SETTINGS
    if checkpoint_steps:
        items = ["resume=true"]
    elif any(FINGERPRINT in row for row in metrics):
        items = ["resume=true", "fast_forward=true"]
    else:
        items = [f"config={os.path.join(out, settings)}"]
    return shlex.join(["python", "-m", f"admissable_jax.{command}", *items, f"out={out}"])


def find_run_folders(paths: list[str] | str) -> list[str]:
    """Every run directory (a folder holding a ``config.yaml``) at or under ``paths``, each
    once, sorted: a run that has not scored yet is one too. FileNotFoundError for a path
    that is no directory; ValueError where none holds a run."""
    found = []
    for path in paths_of(paths):
        check_is_folder(path)
        found += [root for root, _, files in os.walk(path) if RUN_SETTINGS in files]
    if not found:
        raise ValueError(f"no run directories (config.yaml) under {', '.join(paths_of(paths))}")
    return sorted(distinct_directories(found))


def duration_text(seconds: float) -> str:
    """A wall time as a person reads it: 45 s, 12 min, 3 h 5 min, 2 d 4 h."""
    minutes, hours = seconds / 60, seconds / 3600
    if seconds < 60:
        return f"{seconds:.0f} s"
    if minutes < 60:
        return f"{minutes:.0f} min"
    if hours < 48:
        return f"{int(hours)} h {int(minutes % 60)} min"
    return f"{int(hours // 24)} d {int(hours % 24)} h"


def status_table(statuses: list[RunStatus]) -> str:
    """One aligned row per run, then how many are in each state, then the command that
    continues each stopped run (an experiment's once, for all its pairs) and why each
    unreadable one is."""
    header = ("run", "env", "mode", "seed", "env steps", "state", "min_u a_u", "clean", "best min_u a_u", "last scoring",
              "time left")
    rows = [header] + [_row(status) for status in statuses]
    widths = [max(len(row[column]) for row in rows) for column in range(len(header))]
    lines = ["  ".join(cell.ljust(width) for cell, width in zip(row, widths)).rstrip() for row in rows]
    counts = {state: sum(status.state == state for status in statuses) for state in STATES}
    lines.append(f"\n{len(statuses)} run(s): "
                 + ", ".join(f"{count} {state}" for state, count in counts.items() if count))
    if any(status.best_score is not None and not status.best_policy_kept for status in statuses):
        lines.append("*: best_policy.npz does not hold that scoring's policy (a run of an older version, records copied "
                     "without it, or a run resumed from a checkpoint before its best scoring)")
    if any(status.killed for status in statuses):
        lines.append("killed: its process ended without giving back its lock, as no exit of Python does (SIGKILL, the "
                     "out-of-memory killer, a machine that went down)")
    commands = list(dict.fromkeys(status.continue_with for status in statuses if status.continue_with))
    if commands:
        lines.append("to continue the stopped runs:")
        lines += [f"  {command}" for command in commands]
    lines += [f"{status.path}: {status.problem}" for status in statuses if status.problem]
    return "\n".join(lines)


def _row(status: RunStatus) -> tuple[str, ...]:
    if status.state == "unreadable":
        return (status.path, "", "", "", "", "unreadable", "", "", "", "", "")
    number = lambda value: "—" if value is None else f"{value:.1f}"
    checkpoint = f"checkpoint {status.checkpoint_steps:,}" if status.checkpoint_steps else "no checkpoint"
    state = {"running": f"running ({status.holder})",
             "stopped": f"stopped ({'killed; ' * status.killed}{checkpoint})",
             "finished": "finished" if status.checkpoint_steps >= status.planned_steps else f"finished ({checkpoint})",
             }.get(status.state, status.state)
    return (status.path, status.env, status.mode, str(status.seed),
            f"{status.scored_steps:,} / {status.planned_steps:,}",
            state, number(status.min_score), number(status.clean_score),
            "—" if status.best_score is None else
            f"{status.best_score:.1f} at {status.best_steps:,}{'' if status.best_policy_kept else ' *'}",
            "—" if status.seconds_since_scoring is None else f"{duration_text(status.seconds_since_scoring)} ago",
            "" if status.state == "finished" else
            "—" if status.seconds_left is None else f"about {duration_text(status.seconds_left)}")


@dataclasses.dataclass
class StatusConfig:
    state: str = setting("", "list only the runs in these states, comma separated: running, finished, stopped, "
                             "unreadable ('' = all)")
    format: str = setting("table", "table (aligned rows, then the commands that continue the stopped runs) | "
                                   "jsonl (one JSON object per run, for scripts)")


def requested_states(config: StatusConfig) -> list[str]:
    """The states ``state=`` lists (every state for ''); ValueError naming one that is none."""
    states = [state.strip() for state in config.state.split(",") if state.strip()] or list(STATES)
    unknown = [state for state in states if state not in STATES]
    if unknown:
        raise ValueError(f"state={config.state}: {unknown[0]!r} is no state; the states are {', '.join(STATES)}")
    return states


def check_status_config(config: StatusConfig) -> None:
    requested_states(config)
    if config.format not in ("table", "jsonl"):
        raise ValueError(f"format={config.format}: give table or jsonl")


def main(argv: list[str]) -> int:
    paths = [arg for arg in argv if "=" not in arg and not arg.startswith("-")]
    config = parse_args(StatusConfig, [arg for arg in argv if arg not in paths],
                        "admissable_jax.status [FOLDER ...]", __doc__.splitlines()[0], validate=check_status_config)
    try:
        statuses = [run_status(path) for path in find_run_folders(paths or ["runs"])]
    except (ValueError, FileNotFoundError) as error:
        fail(f"{error}{'' if paths else ' (give the folder your runs are in)'}")
    states = requested_states(config)
    statuses = [status for status in statuses if status.state in states]
    if config.format == "jsonl":
        print("\n".join(json.dumps(dataclasses.asdict(status)) for status in statuses))
    elif statuses:
        print(status_table(statuses))
    else:
        print(f"no run is {' or '.join(states)}")
    return 0


if __name__ == "__main__":
    run_main(main)
