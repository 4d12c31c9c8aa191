"""The policy of a run's best scoring, kept beside its records: ``best_policy.npz``.

A run keeps its newest ``keep_checkpoints`` checkpoints, to resume from, so by its end the
policy of its scoring with the highest min_u a_u (the paper's headline metric) is usually
gone. After each scoring whose min_u a_u beats every earlier scoring of the run (its
``scores.jsonl``), the actor's and the critic's parameters (not the replay buffer: about a
megabyte) are written to ``<run>/best_policy.npz`` with that env step and score, in place
of the earlier best. Only scorings after ``learning_starts`` count: before it the actor is its
random initialisation (``run_directory.trained_at``). So the file always holds the policy of
the row of ``scores.jsonl`` with the highest min_u a_u of those, or is absent where that row's
policy was never seen by this version
(older runs, records copied without it) or was set aside with the rows after a checkpoint a
resume continues from (until a scoring beats the rows kept). ``load_policy(run, "best")``,
``audit RUN best=true`` and ``video RUN best=true`` read it.

The score that picked it is the training's own estimate of N episodes, the highest of many
noisy ones, so it reads high: audit the policy with fresh start states for an honest score.
"""

from __future__ import annotations

import dataclasses
import os
from typing import Any

import jax
import numpy as np

from admissable_jax.errors import RunFailed, write_whole

BEST_POLICY = "best_policy.npz"


@dataclasses.dataclass(frozen=True)
class KeptPolicy:
    """A best policy as kept: the scoring that picked it and the networks' parameters."""

    env_steps: int
    min_score: float
    actor_params: Any
    critic_params: Any


def _arrays(prefix: str, params: Any) -> dict[str, np.ndarray]:
    """``params``' leaves as NumPy arrays named by ``prefix`` and their path in the tree."""
    leaves, _ = jax.tree_util.tree_flatten_with_path(params)
    return {f"{prefix}{jax.tree_util.keystr(path)}": np.asarray(leaf) for path, leaf in leaves}


class BestPolicyNotWritten(RunFailed):
    """The best policy could not be written (a full disk, most often)."""


def write_best_policy(run_dir: str, kept: KeptPolicy) -> None:
    """Write ``kept`` as ``run_dir``'s best policy, whole or not at all: a crash mid-write
    leaves the earlier best in place, and a write that fails removes what it wrote and stops
    the run in one line (:class:`BestPolicyNotWritten`)."""
    try:
        write_whole(os.path.join(run_dir, BEST_POLICY), lambda file: np.savez(
            file, env_steps=np.int64(kept.env_steps), min_score=np.float64(kept.min_score),
            **_arrays("actor", kept.actor_params), **_arrays("critic", kept.critic_params)))
    except OSError as error:
        raise BestPolicyNotWritten(f"cannot write the best policy of env step {kept.env_steps} in {run_dir}: "
                                   f"{error.strerror or error}; the partial write was removed; free space, then "
                                   f"continue with resume=true") from error


def best_kept(run_dir: str) -> tuple[int, float] | None:
    """(env step, min_u a_u) of the best policy ``run_dir`` keeps, without reading the
    networks; None where it keeps none."""
    path = os.path.join(run_dir, BEST_POLICY)
    if not os.path.isfile(path):
        return None
    with np.load(path) as data:
        return int(data["env_steps"]), float(data["min_score"])


def read_best_policy(run_dir: str, actor_like: Any, critic_like: Any) -> KeptPolicy:
    """The best policy ``run_dir`` keeps, its parameters in the trees ``actor_like`` and
    ``critic_like`` (shapes: ``jax.eval_shape`` of the run's networks). FileNotFoundError
    in one line where it keeps none; ValueError where the file does not fit those networks."""
    path = os.path.join(run_dir, BEST_POLICY)
    if not os.path.isfile(path):
        raise FileNotFoundError(f"{run_dir} keeps no {BEST_POLICY}: a run writes it at each scoring that beats its "
                                f"earlier ones, so a run of an older version, records copied without it, or a run resumed "
                                f"from before its best scoring (until a scoring beats it) have none")
    with np.load(path) as data:

        def rebuilt(prefix: str, like: Any) -> Any:
            leaves, tree = jax.tree_util.tree_flatten_with_path(like)
            names = [f"{prefix}{jax.tree_util.keystr(key)}" for key, _ in leaves]
            if any(name not in data or data[name].shape != leaf.shape for name, (_, leaf) in zip(names, leaves)):
                raise ValueError(f"{path} does not hold the networks of the run in {run_dir} (another run's file?)")
            return jax.tree_util.tree_unflatten(tree, [data[name] for name in names])

        return KeptPolicy(int(data["env_steps"]), float(data["min_score"]), rebuilt("actor", actor_like),
                          rebuilt("critic", critic_like))
