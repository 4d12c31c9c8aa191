"""A trained policy as one .npz that NumPy alone runs, without JAX or this trainer.

``python -m admissable_jax.export RUN_DIR [best=true | step=N] [out=FILE.npz]``

The run's deterministic policy (:func:`~admissable_jax.policies.load_policy`: the latest
checkpoint, ``step=``'s, or with ``best=true`` the one the run kept at its best scoring) is
written as plain arrays (:mod:`admissable_jax.exported_policy`), by default to
``RUN_DIR/exported/policy-step<STEP>.npz`` (``policy-best-step<STEP>.npz``). Given an
experiment's folder, each pair's policy goes into its own folder. A file at ``out`` that
is no exported policy, or another policy's (another run's, step's, or best-or-not), is never
written over: the checkpoint it came from may be gone. The same policy's is.
"""

from __future__ import annotations

import dataclasses
import os

from admissable_jax.cli import parse_args, run_from_cli, run_main, setting
from admissable_jax.errors import make_directory
from admissable_jax.exported_policy import ExportedPolicy


@dataclasses.dataclass
class ExportConfig:
    run_dir: str = setting("", "a train run directory, an experiment pair's, or an experiment's (every pair) (may be "
                               "given first, without run_dir=)")
    step: int = setting(-1, "the checkpoint (env step); -1 = the latest")
    best: bool = setting(False, "the policy the run kept at its best scoring (best_policy.npz) instead of a checkpoint")
    out: str = setting("", "the .npz to write (default RUN_DIR/exported/policy-step<STEP>.npz; best=true: "
                           "policy-best-step<STEP>.npz); not for an experiment, whose pairs each get their own")


def check_export_config(config: ExportConfig) -> None:
    if not config.run_dir:
        raise ValueError("give the run directory: python -m admissable_jax.export RUN_DIR [best=true | step=N] "
                         "[out=FILE.npz]")
    if config.best and config.step >= 0:
        raise ValueError(f"best=true exports the policy the run kept at its best scoring: give no step= (got "
                         f"{config.step})")
    if config.out and not config.out.endswith(".npz"):
        raise ValueError(f"out must be an .npz file, got {config.out!r}")


def _pair_dirs(config: ExportConfig) -> list[str]:
    """The run directories to export: the run's own, or each pair's of an experiment."""
    from admissable_jax.run_directory import experiment_pairs, is_experiment  # (with JAX: not before the checks)

    root = config.run_dir
    if not os.path.isdir(root):
        raise FileNotFoundError(f"no run directory {root}")
    if not is_experiment(root):
        return [root]
    if config.out:
        raise ValueError(f"{root} is an experiment: each pair's policy goes into its own folder; give no out=, or "
                         f"export one pair (e.g. {os.path.join(root, 'adversarial-s0')})")
    return experiment_pairs(root)


def _check_free_for(out: str, policy: ExportedPolicy) -> None:
    """FileExistsError in one line where ``out`` holds a file that is no exported policy, or
    the exported policy of another run, step or kind (best or not) than ``policy``: never
    written over. The same policy's is, also from its run moved, linked or copied since."""
    from admissable_jax.run_directory import same_policy_record

    if not os.path.exists(out):
        return
    try:
        earlier = ExportedPolicy.load(out).source
    except (ValueError, FileNotFoundError):
        raise FileExistsError(f"{out} exists and is no exported policy: it is left as it is; give another "
                              "out=") from None
    if not same_policy_record(earlier, policy.source, out):
        kept = "" if earlier.get("best_min_score") is None else ", its best"
        raise FileExistsError(f"{out} holds the exported policy of another run or step ({earlier.get('run')}, env step "
                              f"{earlier.get('env_steps')}{kept}): it is left as it is; give another out=")


def export_policies(config: ExportConfig) -> list[tuple[str, ExportedPolicy]]:
    """Export ``config``'s policy (an experiment's: each pair's); (path written, policy) each."""
    from admissable_jax.policies import load_policy, requested_step

    check_export_config(config)
    written = []
    for run_dir in _pair_dirs(config):
        policy = load_policy(run_dir, requested_step(config.step, config.best)).exported()
        name = f"policy-{'best-' * config.best}step{policy.source['env_steps']}.npz"
        out = config.out or os.path.join(run_dir, "exported", name)
        _check_free_for(out, policy)
        make_directory(os.path.dirname(os.path.abspath(out)), "export folder")
        policy.save(out)
        written.append((out, policy))
    return written


def main(argv: list[str]) -> int:
    config = parse_args(ExportConfig, argv, "admissable_jax.export",
                        "A trained policy as one .npz that NumPy alone runs, without JAX or this trainer.",
                        validate=check_export_config, positional="run_dir")
    written, status = run_from_cli(export_policies, config, interrupted="interrupted: each policy is written whole or not at all")
    if status:
        return status
    for path, policy in written:
        layers = " -> ".join(str(weight.shape[0]) for weight in policy.weights) + f" -> {policy.action_size}"
        print(f"wrote {path}: {policy.source['env']} {policy.source['missingness']} seed {policy.source['seed']} at env "
              f"step {policy.source['env_steps']}, layers {layers}; "
              "ExportedPolicy.load(path) from admissable_jax.exported_policy runs it with NumPy alone")
    return 0


if __name__ == "__main__":
    run_main(main)
