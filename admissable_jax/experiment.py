"""Many (seed, mode) training runs in ONE jitted program: the paper's Figure 1 in one command.

    python -m admissable_jax.experiment env=hopper seeds=5 modes=adversarial,uniform \
        total_steps=1000000 out=runs/fig1-hopper

The missingness modes differ only in data (the ``adversarial``, ``masking`` and ``greedy``
flags of the training state), not in code, and so does the adversary's lower bound l, so every pair's
training state is stacked along a leading pair axis and the train chunk and the scoring
round are ``jax.vmap``-ed over it; ``lower_bounds=0,50`` sweeps l in the one program (the
adversarial seeds once per value, ``<out>/adversarial-l<l>-s<seed>``; the other modes,
which never read l, once). That axis
is spread over every device (``devices=N``: the first N), and under ``jax.distributed``
over every process's devices (:mod:`admissable_jax.placement`). Each pair writes its own
run directory ``<out>/<mode>-s<seed>`` in the format of ``train`` (``config.yaml``,
``scores.jsonl``, ``metrics.jsonl``), written by the process that holds it; the experiment
keeps one orbax checkpoint of the whole batch in ``<out>/checkpoints`` and resumes as one
unit, onto the same device count or another. It ends with what the runs found
(:func:`report`): per mode the final and area-under-curve min_u a_u, and adversarial −
uniform (and − worst, where that mode ran) with Welch's interval, as ``plot`` writes them to
its ``summary.md``.
Before anything is allocated the programs are compiled and their memory counted; an
experiment that would not fit stops with a one-line message (``budget_only=true`` prints
the budget and stops there).
"""

from __future__ import annotations

import contextlib
import functools
import os
import sys

import jax
from omegaconf import OmegaConf

from admissable_jax.checkpointing import CheckpointError, Checkpoints
from admissable_jax.cli import enable_compilation_cache, parse_args, run_from_cli, run_main
from admissable_jax.config import EXPERIMENT_SETTINGS, ExperimentConfig, TrainConfig, config_file_of, pair_configs
from admissable_jax.errors import INTERRUPTED, make_directory, remove_if_unused
from admissable_jax.host_loop import TrainingLoop, make_trainer, pairs_init
from admissable_jax.placement import PairPlacement, initialize_distributed
from admissable_jax.results import comparison_sections, summary_table
from admissable_jax.run_directory import RunDirectory, check_folder_kind, load_config, read_jsonl
from admissable_jax.train import TrainResult

def experiment_dir(pairs: list[TrainConfig]) -> str:
    return os.path.dirname(pairs[0].out)


def run_experiment(config: ExperimentConfig) -> list[TrainResult]:
    """Train every pair of ``config`` (seed, mode, and l in a sweep) in one program spread over the devices;
    one result per pair this process holds (every pair, in one process)."""
    if not isinstance(config, ExperimentConfig):
        raise TypeError(f"run_experiment expects an ExperimentConfig, got {type(config).__name__}"
                        + (" (one run: train_fn)" if isinstance(config, TrainConfig) else ""))
    config = config.resolved()
    initialize_distributed()
    pairs = pair_configs(config)
    first = pairs[0]
    root = experiment_dir(pairs)
    check_folder_kind(root, "experiment")
    placement = PairPlacement.over(len(pairs), config.devices)
    trainer = make_trainer(first, num_runs=placement.pairs_per_device)
    experiment_yaml = os.path.join(root, EXPERIMENT_SETTINGS)
    if config.resume:  # checked before anything is created
        if not os.path.isdir(root):
            raise CheckpointError(f"nothing to resume: {root} does not exist")
        check_same_pairs(config, pairs, experiment_yaml)
    root_made_here = not os.path.exists(root)
    make_directory(root, "experiment directory")
    checkpoint_dir = os.path.join(root, "checkpoints")
    local_pairs = placement.local_pairs
    with contextlib.ExitStack() as held:
        if root_made_here:  # after the pairs' folders (last in, first out): gone if they are
            held.callback(remove_if_unused, root, (EXPERIMENT_SETTINGS,))
        runs = []
        for index in local_pairs:  # each pair's directory stays locked until the experiment ends
            runs.append(RunDirectory(pairs[index], checkpoint_dir))
            held.callback(runs[-1].close)
        if jax.process_index() == 0:
            OmegaConf.save(OmegaConf.structured(config), experiment_yaml)

        loop = TrainingLoop(trainer, first, runs, Checkpoints(checkpoint_dir, first.keep_checkpoints),
                            pairs_init(trainer, pairs, placement), placement)
        if config.budget_only:
            print(f"{len(pairs)} pairs x {first.num_envs} envs, {first.env}: {loop.compile().describe()}; "
                  f"{placement.describe()}")
            loop.checkpoints.close()
            return []
        state = loop.run()
    return [
        TrainResult(pairs[index], trainer, functools.partial(placement.pair_state, state, index),
                    run.read("scores.jsonl"), run.read("metrics.jsonl"))
        for index, run in zip(local_pairs, runs)
    ]


def check_same_pairs(config, pairs: list[TrainConfig], experiment_yaml: str) -> None:
    """A resumed experiment must have the pairs, in the order, that its checkpoint holds."""
    if not os.path.exists(experiment_yaml):
        raise CheckpointError(f"nothing to resume: {experiment_yaml} does not exist")
    names = lambda listed: [os.path.basename(pair.out) for pair in listed]  # mode, l in a sweep, seed
    saved = names(pair_configs(load_config(experiment_yaml, ExperimentConfig)))
    if saved != names(pairs):
        raise ValueError(f"cannot resume with other pairs: the experiment in {experiment_dir(pairs)} has "
                         f"{', '.join(saved)}, this one {', '.join(names(pairs))} (keep seeds, first_seed, modes "
                         "and lower_bounds)")


def report(run_dirs: list[str], root: str) -> str:
    """What the pairs found, in the paper's terms: per mode final and area-under-curve
    min_u a_u, mean_u a_u and the clean return (mean ± 95% interval over seeds) and the set
    most often worst at the end; where both adversarial and uniform (or worst) ran, their
    difference with Welch's interval and, if the seeds cannot tell them apart, how many would
    (:mod:`admissable_jax.results`, as ``plot``'s ``summary.md``); then the command that
    draws the figures."""
    comparison = comparison_sections(run_dirs)
    return (summary_table(run_dirs) + (f"\n{comparison}" if comparison else "")
            + f"\nfigures, summary.md and CSV tables: python -m admissable_jax.plot {root}")


def main(argv: list[str]) -> int:
    config = parse_args(
        ExperimentConfig, argv, "admissable_jax.experiment",
        "Train every (seed, mode) pair in one vmapped program: the data for the paper's Figure 1.",
        config_file=config_file_of(ExperimentConfig),
    )
    enable_compilation_cache()
    results, status = run_from_cli(run_experiment, config)
    if status:
        return status
    for result in results:
        print(result.summary())
    pairs = pair_configs(config)
    if not results or jax.process_index() != 0:
        return 0
    root = experiment_dir(pairs)
    reached = results[0].scores[-1]["env_steps"]
    if not all(scored_up_to(pair.out, reached) for pair in pairs):  # other hosts' pairs, on their own disks
        print(f"the other processes' pairs are not here: python -m admissable_jax.plot {root} summarises and draws "
              "them where every pair's folder is")
        return 0
    try:
        print("\n" + report([pair.out for pair in pairs], root))
    except (ValueError, OSError) as error:  # the runs are written; only their summary failed
        print(f"warning: no summary of the pairs ({error}); python -m admissable_jax.plot {root} draws them",
              file=sys.stderr)
    except KeyboardInterrupt:
        print(f"interrupted: the runs are written; python -m admissable_jax.plot {root} summarises them",
              file=sys.stderr)
        return INTERRUPTED
    return 0


def scored_up_to(run_dir: str, env_steps: int) -> bool:
    """Whether ``run_dir`` is here with its scoring at ``env_steps`` written: in a multi-process
    experiment every process writes its own pairs' folders, and process 0 sees the others'
    only on a shared file system (their rows are written before the collective last
    checkpoint that process 0 has passed)."""
    try:
        return read_jsonl(os.path.join(run_dir, "scores.jsonl"))[-1]["env_steps"] == env_steps
    except (OSError, ValueError, IndexError, KeyError):
        return False


if __name__ == "__main__":
    run_main(main)
