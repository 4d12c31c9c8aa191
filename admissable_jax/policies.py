"""Trained policies outside the trainer: ``load_policy(run_dir, step=None)`` (``step="best"``:
the policy a run kept at its best scoring).

The returned :class:`TrainedPolicy` maps a Gymnasium observation (or a batch) and a hidden
set u to the trainer's deterministic action, in NumPy: the policy that scoring evaluates,
for Gymnasium's own C-MuJoCo envs (:func:`admissable_jax.wrappers.score_policy`), SB3-style
evaluation code, or a video. It reads a ``train`` run directory (``RUN/checkpoints``) or
one pair of an ``experiment`` (the pair's directory; the checkpoints are the experiment's).
``policy.exported()`` gives the same policy as NumPy arrays, to save and run without JAX
(:mod:`admissable_jax.exported_policy`, ``python -m admissable_jax.export``).
"""

from __future__ import annotations

import dataclasses
import os
from typing import Any, Iterable

import jax
import jax.numpy as jnp
import numpy as np

from admissable_jax.best_policy import read_best_policy
from admissable_jax.checkpointing import Checkpoints
from admissable_jax.config import EXPERIMENT_SETTINGS, FAILURE_STEPS, ExperimentConfig, TrainConfig, pair_configs
from admissable_jax.envs import observation_names
from admissable_jax.exported_policy import ExportedPolicy
from admissable_jax.host_loop import init_arguments, make_trainer, stacked_init_arguments, take_pair
from admissable_jax.method import act_with_hidden, check_masked_batch
from admissable_jax.run_directory import load_config, run_config_path
from admissable_jax.training import Trainer, TrainState

BEST = "best"  # load_policy's step for the policy a run kept at its best scoring


def requested_step(step: int, best: bool) -> int | str | None:
    """``load_policy``'s step for a command's ``step=`` (-1: the latest) and ``best=`` keys."""
    return BEST if best else None if step < 0 else step


@dataclasses.dataclass
class TrainedPolicy:
    """A run's deterministic policy at one checkpoint.

    ``policy(obs, hidden=())`` takes an observation (d,) or a batch (n, d) and u as feature
    indices (or a 0/1 row), and returns the action(s) as NumPy; ``policy.masked(batch)``
    takes observations already masked (n, 2·d), as :func:`~admissable_jax.wrappers.score_policy`
    hands them.
    """

    config: TrainConfig
    trainer: Trainer
    actor_params: object
    step: int
    critic_params: object  # the twin critic at the same checkpoint (score estimates)
    best_min_score: float | None = None  # kept as the run's best: the min_u a_u of the scoring that picked it

    def __post_init__(self):
        self._act = jax.jit(jax.vmap(self.trainer.policy, in_axes=(None, 0)))

    def __repr__(self) -> str:
        """Which policy, not its parameters (a notebook showing one printed thousands of lines)."""
        train = self.config
        best = "" if self.best_min_score is None else f", its best scoring (min_u a_u {self.best_min_score:.1f})"
        return (f"<TrainedPolicy of {train.env} {train.missingness} seed {train.seed} at env step {self.step}{best} "
                f"({train.out}): {self.observation_size} features in, {self.trainer.env.action_size} actions out>")

    @property
    def observation_size(self) -> int:
        return self.trainer.env.observation_size

    def __call__(self, obs: np.ndarray, hidden: Iterable[int] | np.ndarray = ()) -> np.ndarray:
        return act_with_hidden(self.masked, obs, hidden, self.observation_size)

    def masked(self, masked_obs: np.ndarray) -> np.ndarray:
        check_masked_batch(masked_obs, self.observation_size)
        return np.asarray(self._act(self.actor_params, jnp.asarray(masked_obs, jnp.float32)))

    @property
    def source(self) -> dict[str, Any]:
        """Where this policy came from, as what it makes records it (an exported policy, a
        video): the run (where it is now), its settings that matter, the env step, and its
        min_u a_u where it is the run's best."""
        train = self.config
        return {"run": os.path.abspath(train.out), "env": train.env, "gymnasium_id": self.trainer.env.gymnasium_id,
                "missingness": train.missingness, "seed": train.seed, "k": train.k, "up_to_k": train.up_to_k,
                "env_steps": self.step, "best_min_score": self.best_min_score,
                **{name: getattr(train, name) for name in FAILURE_STEPS if getattr(train, name) != "0"}}

    def exported(self) -> ExportedPolicy:
        """This policy as NumPy arrays (:mod:`admissable_jax.exported_policy`): the actor's
        hidden layers and mean head (not its log-std head, which only exploration reads), the
        action bounds, the feature names and where it came from; ``.save(path)`` writes it."""
        layers = self.actor_params["params"]
        mean_head = len(self.trainer.agent.hp.hidden_sizes)  # agent.Actor: Dense_0.. hidden, the mean head, the log-std head
        order = [f"Dense_{index}" for index in range(mean_head + 1)]
        env = self.trainer.env
        return ExportedPolicy(tuple(np.asarray(layers[name]["kernel"], np.float32) for name in order),
                              tuple(np.asarray(layers[name]["bias"], np.float32) for name in order),
                              np.asarray(env.action_low, np.float32), np.asarray(env.action_high, np.float32),
                              tuple(observation_names(self.config.env)), self.source)


def _checkpoint_dir(run_dir: str) -> str:
    """Where the run in ``run_dir`` keeps its checkpoints: its own ``checkpoints/``, or, for
    an experiment's pair, the experiment's beside it."""
    own_checkpoints = os.path.join(run_dir, "checkpoints")
    if os.path.isdir(own_checkpoints):
        return own_checkpoints
    return os.path.join(os.path.dirname(os.path.abspath(run_dir)), "checkpoints")


def checkpoint_steps(run_dir: str) -> list[int]:
    """The env steps of the checkpoints ``load_policy`` can read for the run in ``run_dir``
    (its own, or its experiment's), oldest first."""
    return Checkpoints.steps_in(_checkpoint_dir(run_dir))


def _own_state_shapes(config: TrainConfig) -> tuple[Trainer, TrainState]:
    """A run's trainer and the shapes of its training state (nothing allocated)."""
    trainer = make_trainer(config)
    return trainer, jax.eval_shape(lambda: trainer.init(*init_arguments(config)))


def load_policy(run_dir: str, step: int | str | None = None) -> TrainedPolicy:
    """The deterministic policy of the run in ``run_dir`` at checkpoint ``step`` (default:
    the latest), or, for ``step="best"``, the one it kept at its scoring with the highest
    min_u a_u (:mod:`admissable_jax.best_policy`). FileNotFoundError/CheckpointError with one
    line when there is none. Only the networks are read from a checkpoint, not the replay
    buffers beside them."""
    best = isinstance(step, str) and step == BEST
    if step is not None and not best and not isinstance(step, (int, np.integer)):
        raise TypeError(f"step must be an env step (an int), {BEST!r} or None for the latest, got {step!r}")
    # out: where the run is now (moved or copied since, its config.yaml names where it trained)
    config = dataclasses.replace(load_config(run_config_path(run_dir), TrainConfig), out=run_dir).resolved()
    if best:  # a pair's own networks, as a run of its own has them
        trainer, like = _own_state_shapes(config)
        kept = read_best_policy(run_dir, like.sac.actor_params, like.sac.critic_params)
        return TrainedPolicy(config, trainer, kept.actor_params, kept.env_steps, kept.critic_params, kept.min_score)
    checkpoint_dir = _checkpoint_dir(run_dir)
    experiment_yaml = os.path.join(os.path.dirname(os.path.abspath(run_dir)), EXPERIMENT_SETTINGS)
    if checkpoint_dir == os.path.join(run_dir, "checkpoints"):  # its own
        trainer, like = _own_state_shapes(config)
        pick = None
    elif os.path.isfile(experiment_yaml):
        experiment = load_config(experiment_yaml, ExperimentConfig)
        experiment.out = os.path.dirname(os.path.abspath(run_dir))
        pairs = pair_configs(experiment)
        names = [os.path.basename(pair.out) for pair in pairs]
        index = names.index(os.path.basename(os.path.abspath(run_dir)))
        trainer = make_trainer(pairs[0], num_runs=len(pairs))
        arguments = stacked_init_arguments(pairs)
        like = jax.eval_shape(lambda: jax.vmap(trainer.init)(*arguments))
        pick = lambda tree: take_pair(tree, index)
    else:
        raise FileNotFoundError(f"{run_dir} has no checkpoints (no checkpoints/ and no experiment.yaml above it)")
    checkpoints = Checkpoints(checkpoint_dir)
    try:  # the networks only; an experiment's checkpoint may hold padding pairs after the real ones: cut off
        restored_step, sac = checkpoints.read(like, step, resizable_leading_axis=pick is not None,
                                              part=lambda state: state.sac)
    finally:
        checkpoints.close()
    sac = pick(sac) if pick else sac
    return TrainedPolicy(config, trainer, sac.actor_params, restored_step, sac.critic_params)
