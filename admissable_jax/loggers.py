"""Where a run's rows go besides its JSONL files: TensorBoard and Weights & Biases.

``logger=tensorboard``, ``logger=wandb`` or both (``logger=tensorboard,wandb``). The run
directory's ``scores.jsonl`` and ``metrics.jsonl`` stay the record; a logger only mirrors
each row as it is written, so curves show up where CleanRL and Brax users look. Every number
of a row is a scalar under its file's name (``scores/min_score``, ``metrics/critic_loss``,
...), every a_u a scalar under ``a_u/<set>``, and p_miss a histogram over the set indices,
all at the row's env step. An experiment's pairs log apart, each as its own run.
"""

from __future__ import annotations

import dataclasses
import importlib.util
import os
import uuid
from typing import Any

import numpy as np

WANDB_PROJECT = "admissable_jax"  # when WANDB_PROJECT is not set


def parse_logger_names(names: str) -> tuple[str, ...]:
    """``"tensorboard,wandb"`` → ``("tensorboard", "wandb")``, each once (two TensorBoard
    writers started in one second write one file); ``"none"`` → ``()``. Raises ValueError
    for an unknown name, or for ``wandb`` where its package is not installed (so a run is
    refused before it starts, not after its first scoring)."""
    parsed = tuple(dict.fromkeys(name.strip() for name in names.split(",") if name.strip()))
    unknown = [name for name in parsed if name != "none" and name not in _LOGGER_CLASSES]
    if unknown or not parsed or ("none" in parsed and len(parsed) > 1):
        raise ValueError(f"logger must be none or a comma list of {', '.join(_LOGGER_CLASSES)}, got {names!r}")
    if "wandb" in parsed and importlib.util.find_spec("wandb") is None:
        raise ValueError("logger=wandb needs the wandb package: pip install -e '.[wandb]'")
    return tuple(name for name in parsed if name != "none")


# metrics.jsonl's key for the training state's fingerprint (admissable_jax.fast_forward): a
# hash, not a curve, so the loggers leave it out.
FINGERPRINT = "state_fingerprint"


@dataclasses.dataclass
class FlatRow:
    """One JSONL row as loggers take it: scalars by tag, p_miss (or None), the env step."""

    step: int
    scalars: dict[str, float]
    p_miss: np.ndarray | None


def flatten_row(file_name: str, row: dict[str, Any]) -> FlatRow:
    """The row's numbers under ``<file>/<key>``, each a_u under ``a_u/<set index>``."""
    prefix = file_name.removesuffix(".jsonl")
    scalars = {
        f"{prefix}/{key}": float(value) for key, value in row.items()
        if key not in ("env_steps", FINGERPRINT) and isinstance(value, (int, float)) and not isinstance(value, bool)
    }
    for index, score in enumerate(row.get("scores", ())):
        scalars[f"a_u/{index:03d}"] = float(score)
    p_miss = np.asarray(row["p_miss"], np.float64) if "p_miss" in row else None
    return FlatRow(int(row["env_steps"]), scalars, p_miss)


class TensorBoardLogger:
    """tensorboardX event files in ``<run_dir>/tensorboard`` (``tensorboard --logdir runs``)."""

    def __init__(self, run_dir: str, config: dict[str, Any]):
        from tensorboardX import SummaryWriter  # a dependency (brax brings it too)

        self.directory = os.path.join(run_dir, "tensorboard")
        self._writer = SummaryWriter(self.directory)

    def log(self, file_name: str, row: dict[str, Any]) -> None:
        flat = flatten_row(file_name, row)
        for tag, value in flat.scalars.items():
            self._writer.add_scalar(tag, value, flat.step)
        if flat.p_miss is not None:
            indices = np.arange(len(flat.p_miss))
            self._writer.add_histogram_raw(
                "p_miss", min=0, max=len(flat.p_miss) - 1, num=float(flat.p_miss.sum()),
                sum=float(indices @ flat.p_miss), sum_squares=float((indices**2) @ flat.p_miss),
                bucket_limits=(indices + 0.5).tolist(), bucket_counts=flat.p_miss.tolist(), global_step=flat.step,
            )
        self._writer.flush()

    def close(self) -> None:
        self._writer.close()


class WandbLogger:
    """A W&B run per run directory (the ``wandb`` extra). The project is ``$WANDB_PROJECT``
    (default ``admissable_jax``), the run's name its directory's, its config the run's config;
    ``WANDB_MODE=offline`` logs without an account (``wandb sync`` uploads later). The W&B run
    id is kept in ``<run_dir>/wandb_run_id``, so ``resume=true`` goes on in the same W&B run.
    Rows are logged against ``env_steps`` (W&B's own step only counts calls), so the rows a
    resumed run writes again land on the same x values."""

    def __init__(self, run_dir: str, config: dict[str, Any]):
        import wandb  # the wandb extra; parse_logger_names checked that it is installed

        id_path = os.path.join(run_dir, "wandb_run_id")
        if os.path.exists(id_path):
            with open(id_path) as file:
                run_id = file.read().strip()
        else:
            run_id = uuid.uuid4().hex[:12]  # W&B ids: letters and digits, unique in the project
        self._wandb = wandb
        try:
            self._run = wandb.init(
                project=os.environ.get("WANDB_PROJECT", WANDB_PROJECT), name=os.path.basename(os.path.abspath(run_dir)),
                id=run_id, resume="allow", dir=run_dir, config=config,
            )
        except wandb.errors.Error as error:  # no account, no network: before any training, in one line
            reason = str(error).strip().splitlines()[0] if str(error).strip() else type(error).__name__
            raise ValueError(f"logger=wandb could not start a W&B run ({reason}); log in (wandb login or "
                             f"WANDB_API_KEY), or log offline with WANDB_MODE=offline") from None
        with open(id_path, "w") as file:  # kept once the W&B run exists
            file.write(run_id + "\n")
        self._run.define_metric("env_steps")
        self._run.define_metric("*", step_metric="env_steps")

    def log(self, file_name: str, row: dict[str, Any]) -> None:
        flat = flatten_row(file_name, row)
        values: dict[str, Any] = {"env_steps": flat.step, **flat.scalars}
        if flat.p_miss is not None:  # one bucket per set index, its mass as the count
            edges = np.arange(len(flat.p_miss) + 1) - 0.5
            values["p_miss"] = self._wandb.Histogram(np_histogram=(flat.p_miss.tolist(), edges.tolist()))
        self._run.log(values)

    def close(self) -> None:
        self._run.finish()


_LOGGER_CLASSES = {"tensorboard": TensorBoardLogger, "wandb": WandbLogger}  # logger= names


class Loggers:
    """The loggers ``names`` asks for (:func:`parse_logger_names`), each given every row."""

    def __init__(self, names: str, run_dir: str, config: dict[str, Any]):
        self._loggers = []
        try:
            for name in parse_logger_names(names):
                self._loggers.append(_LOGGER_CLASSES[name](run_dir, config))
        except BaseException:
            self.close()
            raise

    def log(self, file_name: str, row: dict[str, Any]) -> None:
        for logger in self._loggers:
            logger.log(file_name, row)

    def close(self) -> None:
        for logger in self._loggers:
            logger.close()
        self._loggers = []
