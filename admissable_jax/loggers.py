"""Where a run's rows go besides its JSONL files: TensorBoard (``logger=tensorboard``).

The run directory's ``scores.jsonl`` and ``metrics.jsonl`` stay the record; a logger only
mirrors each row as it is written, so curves show up where CleanRL and Brax users look.
Every number of a row is a scalar under its file's name (``scores/min_score``,
``metrics/critic_loss``, ...), every a_u a scalar under ``a_u/<set>``, and p_miss a
histogram over the set indices. An experiment's pairs log apart, each in its own
``<pair dir>/tensorboard``.
"""

from __future__ import annotations

import os
from typing import Any

import numpy as np

LOGGERS = ("none", "tensorboard")


class TensorBoardLogger:
    """tensorboardX event files in ``<run_dir>/tensorboard`` (``tensorboard --logdir runs``)."""

    def __init__(self, run_dir: str):
        from tensorboardX import SummaryWriter  # installed with brax

        self.directory = os.path.join(run_dir, "tensorboard")
        self._writer = SummaryWriter(self.directory)

    def log(self, file_name: str, row: dict[str, Any]) -> None:
        step = int(row["env_steps"])
        prefix = file_name.removesuffix(".jsonl")
        for key, value in row.items():
            if key != "env_steps" and isinstance(value, (int, float)) and not isinstance(value, bool):
                self._writer.add_scalar(f"{prefix}/{key}", value, step)
        if "scores" in row:
            for index, score in enumerate(row["scores"]):
                self._writer.add_scalar(f"a_u/{index:03d}", score, step)
        if "p_miss" in row:
            p_miss = np.asarray(row["p_miss"], np.float64)
            indices = np.arange(len(p_miss))
            self._writer.add_histogram_raw(
                "p_miss", min=0, max=len(p_miss) - 1, num=float(p_miss.sum()), sum=float(indices @ p_miss),
                sum_squares=float((indices**2) @ p_miss), bucket_limits=(indices + 0.5).tolist(),
                bucket_counts=p_miss.tolist(), global_step=step,
            )
        self._writer.flush()

    def close(self) -> None:
        self._writer.close()


def make_logger(name: str, run_dir: str) -> TensorBoardLogger | None:
    """The logger ``name`` (one of :data:`LOGGERS`, checked by the config) for the run in
    ``run_dir``; None for ``none``."""
    return TensorBoardLogger(run_dir) if name == "tensorboard" else None
