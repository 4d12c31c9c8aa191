"""Figures from run directories: the paper's Figure 1 and what explains it.

``plot_runs(run_dirs, out_dir)`` groups runs by (env, missingness mode) and draws, as PNG
and PDF:

* ``min_score.*`` — the paper's Figure 1: min_u a_u against env steps, one line per mode
  (adversarial blue, uniform red, as in the paper; none grey), the mean over seeds of the
  moving average over ``window`` records, shaded with a 95% t-interval over seeds; a
  second panel shows the clean return (nothing hidden) the same way;
* ``scores_<mode>.*`` — a_u for every feature over time (mean over seeds), a heatmap;
* ``p_miss_<mode>.*`` — the adversary's distribution over time (mean over seeds);
* ``summary.md`` (CLI) — :func:`summary_table`: final and AUC min_u a_u per mode.

``python -m admissable_jax.plot runs/fig1-hopper [window=40] [out=DIR]`` finds every run
directory (one holding ``scores.jsonl``) under the given paths.
"""

from __future__ import annotations

import collections
import dataclasses
import json
import os
import sys

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
from omegaconf import OmegaConf  # noqa: E402
from scipy import stats  # noqa: E402

from admissable_jax.cli import fail, parse_args  # noqa: E402

MODE_COLORS = {"adversarial": "tab:blue", "uniform": "tab:red", "none": "tab:gray"}


@dataclasses.dataclass
class Run:
    path: str
    env: str
    mode: str
    seed: int
    env_steps: np.ndarray  # (T,)
    scores: np.ndarray  # (T, |U|) a_u
    min_score: np.ndarray  # (T,)
    clean_score: np.ndarray  # (T,)
    p_miss: np.ndarray  # (T, |U|)


def load_run(path: str) -> Run:
    """A run directory's config and scoring history."""
    config = OmegaConf.load(os.path.join(path, "config.yaml"))
    with open(os.path.join(path, "scores.jsonl")) as file:
        rows = [json.loads(line) for line in file if line.strip()]
    if not rows:
        raise ValueError(f"{path} has no scoring rows yet")
    column = lambda key: np.asarray([row[key] for row in rows], dtype=float)
    return Run(
        path=path, env=str(config.env), mode=str(config.missingness), seed=int(config.seed),
        env_steps=column("env_steps"), scores=column("scores"), min_score=column("min_score"),
        clean_score=column("clean_score"), p_miss=column("p_miss"),
    )


def find_runs(paths: list[str]) -> list[str]:
    """Every directory at or under ``paths`` that holds a ``scores.jsonl``."""
    found = []
    for path in paths:
        if not os.path.isdir(path):
            raise FileNotFoundError(f"no such directory: {path}")
        for root, _, files in os.walk(path):
            if "scores.jsonl" in files and "config.yaml" in files:
                found.append(root)
    return sorted(found)


def moving_average(values: np.ndarray, window: int) -> np.ndarray:
    """Trailing mean over the last ``window`` records (fewer at the start), along axis -1."""
    cumulative = np.cumsum(values, axis=-1)
    shifted = np.concatenate([np.zeros_like(cumulative[..., :window]), cumulative[..., :-window]], axis=-1)
    counts = np.minimum(np.arange(1, values.shape[-1] + 1), window)
    return (cumulative - shifted[..., : values.shape[-1]]) / counts


def mean_and_interval(curves: np.ndarray, confidence: float = 0.95) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Mean over seeds (axis 0) and a two-sided t-interval; the interval is the mean alone
    for a single seed."""
    mean = curves.mean(axis=0)
    n = curves.shape[0]
    if n < 2:
        return mean, mean, mean
    half = stats.t.ppf(0.5 + confidence / 2, n - 1) * curves.std(axis=0, ddof=1) / np.sqrt(n)
    return mean, mean - half, mean + half


def _aligned(runs: list[Run], attribute: str) -> tuple[np.ndarray, np.ndarray]:
    """(env steps, stacked values) over the records all runs share."""
    length = min(len(run.env_steps) for run in runs)
    return runs[0].env_steps[:length], np.stack([getattr(run, attribute)[:length] for run in runs])


def _save(figure, out_dir: str, name: str) -> list[str]:
    paths = [os.path.join(out_dir, f"{name}.{ext}") for ext in ("png", "pdf")]
    for path in paths:
        figure.savefig(path, dpi=150, bbox_inches="tight")
    plt.close(figure)
    return paths


def plot_runs(run_dirs: list[str], out_dir: str, window: int = 40) -> list[str]:
    """Draw the figures for these runs into ``out_dir``; returns the files written."""
    runs = [load_run(path) for path in run_dirs]
    if not runs:
        raise ValueError("no runs to plot")
    envs = sorted({run.env for run in runs})
    if len(envs) > 1:
        raise ValueError(f"runs of several envs ({', '.join(envs)}): plot one env at a time")
    by_mode: dict[str, list[Run]] = collections.defaultdict(list)
    for run in runs:
        by_mode[run.mode].append(run)
    os.makedirs(out_dir, exist_ok=True)
    written = []

    figure, (ax_min, ax_clean) = plt.subplots(1, 2, figsize=(11, 4))
    for mode, mode_runs in sorted(by_mode.items()):
        for ax, attribute in ((ax_min, "min_score"), (ax_clean, "clean_score")):
            steps, values = _aligned(mode_runs, attribute)
            mean, low, high = mean_and_interval(moving_average(values, window))
            color = MODE_COLORS.get(mode, "black")
            ax.plot(steps, mean, color=color, label=f"{mode} ({len(mode_runs)} seeds)")
            ax.fill_between(steps, low, high, color=color, alpha=0.2, linewidth=0)
    ax_min.set_title(f"{envs[0]}: adversarial performance $\\min_u a_u$")
    ax_clean.set_title(f"{envs[0]}: clean return (nothing hidden)")
    for ax in (ax_min, ax_clean):
        ax.set_xlabel("env steps")
        ax.set_ylabel(f"return (moving average over {window} records)")
        ax.grid(alpha=0.3)
        ax.legend()
    written += _save(figure, out_dir, "min_score")

    for mode, mode_runs in sorted(by_mode.items()):
        for attribute, label, name in (("scores", "$a_u$ (mean over seeds)", "scores"), ("p_miss", "$p_{miss}(u)$ (mean over seeds)", "p_miss")):
            steps, values = _aligned(mode_runs, attribute)
            figure, ax = plt.subplots(figsize=(9, 4))
            image = ax.imshow(
                values.mean(axis=0).T, aspect="auto", origin="lower", interpolation="nearest",
                extent=(steps[0], steps[-1], -0.5, values.shape[-1] - 0.5), cmap="viridis",
            )
            figure.colorbar(image, ax=ax, label=label)
            ax.set_xlabel("env steps")
            ax.set_ylabel("missing feature set u (index)")
            ax.set_title(f"{envs[0]}, {mode} missingness: {label}")
            written += _save(figure, out_dir, f"{name}_{mode}")
    return written


def _estimate(values: np.ndarray) -> str:
    mean, low, _ = mean_and_interval(values[:, None])
    return f"{mean[0]:.1f} ± {mean[0] - low[0]:.1f}" if len(values) > 1 else f"{mean[0]:.1f}"


def summary_table(run_dirs: list[str]) -> str:
    """Markdown table per mode: final and area-under-curve min_u a_u and the final clean
    return, mean ± 95% t-interval half-width over seeds. The AUC is the mean of min_u a_u
    over all records (the area under the curve divided by its length in records)."""
    by_mode: dict[str, list[Run]] = collections.defaultdict(list)
    for run in (load_run(path) for path in run_dirs):
        by_mode[(run.env, run.mode)].append(run)
    lines = [
        "| env | mode | seeds | env steps | final min_u a_u | AUC min_u a_u (mean over records) | final clean return |",
        "|---|---|---|---|---|---|---|",
    ]
    for (env, mode), runs in sorted(by_mode.items()):
        steps, minimum = _aligned(runs, "min_score")
        _, clean = _aligned(runs, "clean_score")
        lines.append(
            f"| {env} | {mode} | {len(runs)} | {int(steps[-1])} | {_estimate(minimum[:, -1])} | "
            f"{_estimate(minimum.mean(axis=1))} | {_estimate(clean[:, -1])} |"
        )
    return "\n".join(lines) + "\n"


@dataclasses.dataclass
class PlotConfig:
    window: int = dataclasses.field(default=40, metadata={"help": "moving-average window (records)"})
    out: str = dataclasses.field(default="", metadata={"help": "output folder ('' = <first path>/figures)"})


def main(argv: list[str]) -> int:
    paths = [arg for arg in argv if "=" not in arg and not arg.startswith("-")]
    options = [arg for arg in argv if arg not in paths]
    config = parse_args(PlotConfig, options, "admissable_jax.plot RUN_DIR [RUN_DIR ...]", __doc__.splitlines()[0])
    if not paths:
        fail("give at least one run directory (or a folder of them)")
    try:
        runs = find_runs(paths)
        out_dir = config.out or os.path.join(paths[0], "figures")
        written = plot_runs(runs, out_dir, config.window)
        table = summary_table(runs)
    except (ValueError, FileNotFoundError, KeyError) as error:
        fail(str(error))
    with open(os.path.join(out_dir, "summary.md"), "w") as file:
        file.write(table)
    print("\n".join([*written, os.path.join(out_dir, "summary.md")]))
    print(table)
    return 0


if __name__ == "__main__":
    raise SystemExit(main(sys.argv[1:]))
