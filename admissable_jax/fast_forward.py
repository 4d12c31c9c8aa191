"""Fast-forward: rebuild a run's training state from its records, where its checkpoints are
out of reach (``resume=true fast_forward=true``).

A scoring round changes three things in the training state (:meth:`Trainer.after_scoring
<admissable_jax.training.Trainer.after_scoring>`): p_miss, the pool, and the PRNG key, moved
on as every round moves it. The first two are in the round's ``scores.jsonl`` row, exactly
(float32 values written in full); training between two scorings reads nothing else of a
round. So the training chunks re-run from the last checkpoint (or from the start) with
each recorded round's p_miss and pool put in its place rebuild the state the run had, at
the cost of the chunks alone: the scoring rounds, much of a run's time once its episodes
run long, are skipped, and a run whose checkpoints are lost, or stayed on a machine its
replay buffer could not leave, goes on from its records. A device gives the same state only
where it computes as the recording one did (the same program on the same kind of device,
deterministic kernels: the CPU does; on a GPU, MuJoCo Warp only in its deterministic mode,
``deterministic_physics``, and XLA with deterministic ops), so every rebuilt state's fingerprint
(:meth:`Trainer.fingerprint <admissable_jax.training.Trainer.fingerprint>`) is checked
against the one its ``metrics.jsonl`` row recorded, and the first that differs stops the
command in one line, the records untouched.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from admissable_jax.errors import RunFailed
from admissable_jax.loggers import FINGERPRINT
from admissable_jax.method import SetNumbering, hidden_row, parse_set
from admissable_jax.run_directory import RunDirectory, read_run_file


class FastForwardDiverged(RunFailed):
    """A rebuilt state's fingerprint differs from the recorded one: this device does not
    compute the run as the one that recorded it did."""


@dataclasses.dataclass(frozen=True)
class RecordedScoring:
    """What one scoring round left in the training state, from its rows: p_miss (P,), the
    pool's indices into U ((0,) without a pool), and the state's fingerprint after it."""

    env_steps: int
    p_miss: np.ndarray
    pool: np.ndarray
    fingerprint: int


def recorded_rows(run_path: str, after: int, score_every: int) -> list[tuple[dict, int]]:
    """(``scores.jsonl`` row, recorded state fingerprint) of each round the run in ``run_path``
    recorded after env step ``after``, ζ apart from it, as far as both of its files hold them
    with a fingerprint. Reads only: a plan may ask before any run directory is opened."""
    scores = {row["env_steps"]: row for row in read_run_file(run_path, "scores.jsonl")}
    metrics = {row["env_steps"]: row for row in read_run_file(run_path, "metrics.jsonl")}
    found = []
    step = after + score_every
    while step in scores and FINGERPRINT in metrics.get(step, {}):
        found.append((scores[step], int(metrics[step][FINGERPRINT])))
        step += score_every
    return found


def recorded_scorings(run: RunDirectory, after: int, score_every: int, pooled_sets: SetNumbering | None
                      ) -> list[RecordedScoring]:
    """:func:`recorded_rows` as what each round left in the state. ``pooled_sets`` numbers U,
    to turn a pool's recorded sets (by name) into their indices; ``None`` for a run without a pool."""
    def pool(row: dict) -> np.ndarray:
        if pooled_sets is None:
            return np.zeros((0,), np.int32)
        d = pooled_sets.num_features
        return pooled_sets.indices(np.stack([hidden_row(parse_set(name), d) for name in row["sets"]]))

    return [RecordedScoring(row["env_steps"], np.asarray(row["p_miss"], np.float32), pool(row), fingerprint)
            for row, fingerprint in recorded_rows(run.path, after, score_every)]


def check_fingerprint(run: RunDirectory, recorded: RecordedScoring, rebuilt: int) -> None:
    """:class:`FastForwardDiverged` in one line where the rebuilt state is not the recorded one."""
    if rebuilt != recorded.fingerprint:
        raise FastForwardDiverged(
            f"fast-forward diverged at env step {recorded.env_steps} in {run.path}: the rebuilt state's fingerprint "
            f"{rebuilt:#010x} is not the recorded {recorded.fingerprint:#010x} (this device, or this version of the code, "
            f"does not compute the run as the recording one did); the records are untouched: resume from a checkpoint, "
            f"or start over"
        )
