"""Train one agent: ``train_fn(config)`` in Python, ``python -m admissable_jax.train key=value ...``.

``--help`` lists every key with its default. Bad settings exit with status 2 and a one-line
message; a corrupt checkpoint, a diverged run (NaN) or a run too large for the device's
memory exits with status 1, Ctrl-C with 130, and the run directory keeps everything
finished before.
"""

from __future__ import annotations

import dataclasses
import functools
import os
from typing import Any, Callable

import jax

from admissable_jax.best_policy import BEST_POLICY, best_kept
from admissable_jax.checkpointing import Checkpoints
from admissable_jax.cli import enable_compilation_cache, parse_args, run_from_cli, run_main
from admissable_jax.config import TrainConfig, config_file_of, number_text
from admissable_jax.host_loop import TrainingLoop, init_arguments, make_trainer
from admissable_jax.run_directory import RunDirectory, check_folder_kind
from admissable_jax.training import Trainer, TrainState


@dataclasses.dataclass
class TrainResult:
    """What a run produced. ``scores`` and ``metrics`` are the rows of the JSONL files;
    ``state``, the final training state, is read by ``read_state`` when first asked for: an
    experiment's pair's is its part of the experiment's state, and taking every pair's part
    at the run's end would have copied their replay buffers (GBs) for nobody to read."""

    config: TrainConfig
    trainer: Trainer
    read_state: Callable[[], TrainState]
    scores: list[dict[str, Any]]
    metrics: list[dict[str, Any]]

    @functools.cached_property
    def state(self) -> TrainState:
        """Networks, optimizer states, p_miss, counters, RNG, env states and replay buffer."""
        return self.read_state()

    @property
    def actor_params(self):
        return self.state.sac.actor_params

    @property
    def run_dir(self) -> str:
        return self.config.out

    @property
    def finished(self) -> bool:
        """Whether the run reached its planned steps (False after a ``time_limit`` pause)."""
        return bool(self.scores) and self.scores[-1]["env_steps"] >= self.config.planned_steps

    def __repr__(self) -> str:
        """The run's summary line, not the fields': the state holds the networks and the
        replay buffer (a notebook showing a result printed 5,000 lines for a 1,000-step toy run)."""
        return f"<TrainResult {self.summary() if self.scores else f'of {self.run_dir}, not scored yet'}>"

    def summary(self) -> str:
        """One line: how far the run got, its last min_u a_u (with a pool: the pool's lowest
        a_u, an upper bound on min_u a_u) and clean return, its best scoring's min_u a_u where
        an earlier scoring's policy is kept as the best (``best_policy.npz``), and where it is
        (an adversarial run's l where it is not the paper's 0)."""
        last = self.scores[-1]
        state = "done" if self.finished else f"paused ({self.config.planned_steps} planned; resume=true continues)"
        mode = self.config.missingness
        if mode == "adversarial" and self.config.lower_bound != 0:
            mode += f" (l = {number_text(float(self.config.lower_bound))})"
        worst = f"min_u a_u {last['min_score']:.1f} (u = {last['argmin_set']})"
        if self.config.pool_size:
            worst = (f"lowest a_u of the pool {last['min_score']:.1f} (u = {last['argmin_set']}; "
                     f"{self.config.pool_size} of {self.trainer.num_sets:,} sets scored)")
        best = best_kept(self.run_dir)
        earlier_best = "" if best is None or best[0] == last["env_steps"] else (
            f"; its best {best[1]:.1f} at {best[0]} env steps, kept in {BEST_POLICY}")
        return (f"{state}: {self.config.env} {mode} seed {self.config.seed}, {last['env_steps']} env steps, {worst}, "
                f"clean {last['clean_score']:.1f}{earlier_best}; run in {self.run_dir}")


def train_fn(config: TrainConfig) -> TrainResult:
    """Train SAC against missingness as ``config`` says; returns params and histories.

    The config is validated and resolved here, once (``TrainConfig.resolved``); the core
    reads the :class:`~admissable_jax.run_spec.RunSpec` derived from it."""
    if not isinstance(config, TrainConfig):
        raise TypeError(f"train_fn expects a TrainConfig, got {type(config).__name__}")
    config = config.resolved()
    check_folder_kind(config.out, "train")
    trainer = make_trainer(config)
    checkpoint_dir = os.path.join(config.out, "checkpoints")
    run = RunDirectory(config, checkpoint_dir)
    try:
        checkpoints = Checkpoints(checkpoint_dir, config.keep_checkpoints)
        init = jax.jit(lambda: trainer.init(*init_arguments(config)))
        state = TrainingLoop(trainer, config, [run], checkpoints, init).run()
    finally:
        run.close()
    return TrainResult(config, trainer, lambda: state, run.read("scores.jsonl"), run.read("metrics.jsonl"))


def main(argv: list[str]) -> int:
    config = parse_args(
        TrainConfig, argv, "admissable_jax.train",
        "Train SAC against adversarial (or uniform) missingness on an MJX Gymnasium v5 env.",
        config_file=config_file_of(TrainConfig),
    )
    enable_compilation_cache()
    result, status = run_from_cli(train_fn, config)
    if status:
        return status
    print(result.summary())
    return 0


if __name__ == "__main__":
    run_main(main)
