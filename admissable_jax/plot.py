"""Figures from run directories: the paper's Figure 1 and what explains it.

``python -m admissable_jax.plot RUN_DIR ... [window=0] [out=DIR] [formats=png,pdf]`` from a shell,
``plot_runs`` from Python; the numbers (runs read back, tables, the modes' comparison) come
from :mod:`admissable_jax.results`.

``plot_runs(run_dirs, out_dir)`` groups runs by env, missingness mode and the settings in
which they differ (:func:`~admissable_jax.results.label_variants`: a run with k = 2 is
never a seed of a k = 1 curve) and draws, as PNG and PDF (``formats``: any matplotlib
writes, e.g. ``png,svg``):

* ``min_score.*`` — the paper's Figure 1: min_u a_u against env steps, one line per mode
  (adversarial blue, uniform red, as in the paper; none grey), the mean over seeds of the
  moving average over ``window`` records, shaded with a 95% t-interval over seeds (cut at
  the axes where it reaches past the seeds' values by more than their range:
  :func:`keep_to_seeds`); beside
  it, on the same scale, mean_u a_u (the average case: where the paper warns a weak spot
  hides) and the clean return (nothing hidden) the same way;
* ``min_score_by_time.*`` — min_u a_u the same way against the wall time of training and
  scoring, as the runs' ``metrics.jsonl`` timed each interval (start-up and the compile
  before training not counted): how soon each curve gets robust in time (a cheaper score
  estimator, another backend or device); drawn where every run timed every interval;
* ``scores_<mode>.*`` — a_u for every missing set over time (mean over seeds), a heatmap
  whose rows are named after Gymnasium's observation entries ("torso z", ...) and whose
  cells are centred on their scoring steps;
* ``p_miss_<mode>.*`` — the adversary's distribution over time (mean over seeds), or a
  note that it stayed uniform (none for mode ``none``, which hides nothing in training); for
  a run with a candidate pool (``pool_size`` > 0), whose
  scored sets change every round, both heatmaps have a row per feature instead: the lowest
  a_u of the pool's sets that hide it (blank where none does) and the p_miss mass on them,
  and so does a U of more than ``MOST_ROWS`` sets (Ant at k = 2), over all its sets;
* ``final_scores.*`` — where each mode is weak at the end: the last scoring's a_u per hidden
  set (per feature with a pool; of a U of more than ``MOST_ROWS`` sets the ``LOWEST_BARS``
  lowest), the modes' bars side by side, mean over seeds with 95% t-intervals
  (:func:`~admissable_jax.results.final_scores`);
* ``summary.md`` (CLI) — :func:`~admissable_jax.results.summary_table`: final and AUC
  min_u a_u, final mean_u a_u (the average over U), clean return and the set most often
  worst at the end per mode, and
  :func:`~admissable_jax.results.comparison_sections`: adversarial − uniform on each with
  Welch's 95% interval and p-value (and adversarial − worst, where mode worst ran);
* ``curves.csv`` and ``scores.csv`` (CLI) — the same histories as tidy tables for one's own
  analysis (:func:`~admissable_jax.results.write_tables`): a row per run and scoring, and
  a row per run, scoring and hidden set.

The default ``window=0`` smooths as the paper's Figure 1 does (40 of its 200 records), and
a shorter run over the same fifth of its records; a window longer than the runs' records is
shortened to their length; the figures and the summary say which. ``python -m
admissable_jax.plot runs/fig1-hopper [window=0] [out=DIR]``
finds every run directory (one holding ``scores.jsonl``) under the given paths and writes
into a new folder (``<first path>/figures``, or ``figures-2``, ... if that exists); runs of
several envs get a subfolder of figures each, one summary, and ``figure1.png``: every env's
min_u a_u side by side as the paper lays its Figure 1 out (:func:`plot_envs_side_by_side`).
"""

from __future__ import annotations

import collections
import dataclasses
import os
import re
import sys
import textwrap
from typing import Any, Sequence

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
from matplotlib.backend_bases import FigureCanvasBase  # noqa: E402
from matplotlib.ticker import FuncFormatter, MultipleLocator  # noqa: E402
import numpy as np  # noqa: E402

from admissable_jax.cli import fail, parse_args, run_main  # noqa: E402
from admissable_jax.envs import ENV_SPECS  # noqa: E402
from admissable_jax.errors import INTERRUPTED, UnusableDirectory, make_directory, remove_if_unused  # noqa: E402
from admissable_jax.results import (  # noqa: E402
    ADVERSARY_SETTINGS, Run, aligned, comparison_sections, differing_settings, final_scores, find_runs, group_curves,
    load_run, load_runs, mean_and_interval, moving_average, numbers_in_order, per_feature_of_sets,
    shared_records, steps_text, summary_table, trained_on, wall_time_text, write_tables,
)

MODE_COLORS = {"adversarial": "tab:blue", "uniform": "tab:red", "none": "tab:gray", "worst": "tab:green"}
# a mode's several curves: its shades
MODE_COLORMAPS = {"adversarial": "Blues", "uniform": "Reds", "none": "Greys", "worst": "Greens"}
# Figure 1's smoothing: "a moving average over 40 records" of a 1M-step run scored every ζ = 5000.
PAPER_WINDOW, PAPER_RECORDS = 40, 200
LINE_STYLES = ("-", "--", ":", "-.")
# A heatmap row (and a bar) per candidate set up to this many sets (Ant's 105 at k = 1); a
# larger U (Ant at k = 2: 5,460) is drawn per feature, as a pool is, and its bars are the
# LOWEST_BARS sets of lowest a_u.
MOST_ROWS, LOWEST_BARS = 120, 40
CAPTION_WIDTH = 110  # characters a one-panel figure's caption line holds


def curve_colors(curves: list[tuple[str, str]]) -> dict[tuple[str, str], Any]:
    """A colour per (mode, variant) curve: its mode's (``MODE_COLORS``), or where a mode has
    several curves (a sweep of l, runs that differ in k) shades of it, light to dark as the
    variants' numbers grow (l = 0, 25, 100), so that they stay apart without reading the
    line styles."""
    colors = {}
    for mode in dict.fromkeys(mode for mode, _ in curves):
        variants = sorted({variant for of, variant in curves if of == mode}, key=numbers_in_order)
        if len(variants) == 1 or mode not in MODE_COLORMAPS:
            colors.update({(mode, variant): MODE_COLORS.get(mode, "black") for variant in variants})
        else:
            shades = matplotlib.colormaps[MODE_COLORMAPS[mode]](np.linspace(0.5, 0.95, len(variants)))
            colors.update({(mode, variant): shade for variant, shade in zip(variants, shades)})
    return colors


def effective_window(runs: list[Run], window: int) -> int:
    """The moving-average window the figures use. ``window=0``: the paper's, 40 records of
    the 200 a 1M-step run scores at ζ = 5000 (Figure 1's caption), and for runs with fewer
    records the same fifth of theirs (at least 1), so a partial run is smoothed as the
    paper's whole one is, not flattened into a running mean. ``window`` >= 1: that many
    records, shortened to the records the runs share (a longer one would silently be a
    running mean)."""
    if not isinstance(window, int) or isinstance(window, bool) or window < 0:
        raise ValueError(f"window must be an int >= 0 (0: the paper's 40 of 200 records, scaled to the runs), "
                         f"got {window!r}")
    records = shared_records(runs)
    if window == 0:
        return max(1, min(PAPER_WINDOW, records * PAPER_WINDOW // PAPER_RECORDS))
    return min(window, records)


def _window_note(runs: list[Run], window: int) -> str:
    used, records = effective_window(runs, window), shared_records(runs)
    average = f"moving average over {used} record{'s' if used > 1 else ''}"
    if window == 0 and records < PAPER_RECORDS:
        return f"{average} (the paper's 40 of 200, scaled to the runs' {records})"
    if window == 0:
        return f"{average} (the paper's)"
    if used == window:
        return average
    return f"{average} (window={window} shortened: the runs have {used})"


def _has_interval(runs: list[Run]) -> bool:
    """Whether some curve of these runs (of one env) has several seeds: a curve of one seed
    has no t-interval to draw, and a caption should not promise one."""
    return max(collections.Counter(run.curve for run in runs).values()) > 1


def _figure_caption(runs: list[Run], window: int, per_seed: bool = False, cut: bool = False) -> str:
    """What Figure 1 shows, in words under it: a_u, the smoothing, the dots, the band (and
    the seeds' own lines; ``cut``: a band cut at the axes, :func:`keep_to_seeds`)."""
    episodes = sorted({run.score_episodes for run in runs})
    average = ("" if any(run.pooled for run in runs) else
               "; $\\mathrm{mean}_u\\, a_u$: the mean over all u (the average case, u drawn uniformly)")
    shaded = "; shaded: 95% t-interval over seeds" + CUT_BANDS * cut if _has_interval(runs) else ""
    thin = "; thin lines: each seed, smoothed alike" if per_seed else ""
    return (f"$a_u$: mean undiscounted return of N = {'/'.join(map(str, episodes))} deterministic episodes with the "
            f"features u hidden; $\\mathrm{{min}}_u\\, a_u$: the worst u at each scoring{average}.\n"
            f"Lines: mean over seeds of the trailing {_window_note(runs, window)}{shaded}{thin}; dots: each record "
            f"unsmoothed (the summary's 'final' is the last dot).")


def _wrapped(text: str, width: int) -> str:
    """``text``'s lines wrapped at ``width`` characters, never inside ``$...$`` (matplotlib's
    mathtext, which a line break would leave unrendered)."""
    kept = re.sub(r"\$[^$]*\$", lambda math: math.group(0).replace(" ", "\0"), text)
    return "\n".join(textwrap.fill(line, width) for line in kept.splitlines()).replace("\0", " ")


def _seeds(n: int) -> str:
    return f"{n} seed" if n == 1 else f"{n} seeds"


def _cell_edges(steps: np.ndarray) -> np.ndarray:
    """Edges of heatmap cells centred on each scoring step."""
    if len(steps) == 1:
        return np.array([steps[0] - 0.5, steps[0] + 0.5])
    middles = (steps[1:] + steps[:-1]) / 2
    return np.concatenate([[2 * steps[0] - middles[0]], middles, [2 * steps[-1] - middles[-1]]])


def env_steps_axis(ax, label: str = "env steps") -> None:
    """Label ``ax``'s x axis as env steps, its ticks short (:func:`~admissable_jax.results.steps_text`)."""
    ax.set_xlabel(label)
    ax.xaxis.set_major_formatter(FuncFormatter(steps_text))


# Tick spacings a wall-time axis takes (seconds): whole seconds, minutes, hours, days.
TIME_TICKS = (1, 2, 5, 10, 15, 30, 60, 120, 300, 600, 900, 1800, 3600, 7200, 10800, 21600, 43200, 86400)


def wall_time_axis(ax, most_ticks: int = 8) -> None:
    """Label ``ax``'s x axis (drawn) as the wall time of training and scoring, ticked at the
    first of :data:`TIME_TICKS` that gives at most ``most_ticks`` (``2 min``, ``4 min``, ...;
    :func:`~admissable_jax.results.wall_time_text`)."""
    span = max(ax.get_xlim()[1], 1.0)
    ax.xaxis.set_major_locator(MultipleLocator(next((tick for tick in TIME_TICKS if span / tick <= most_ticks),
                                                    TIME_TICKS[-1])))
    ax.xaxis.set_major_formatter(FuncFormatter(wall_time_text))
    ax.set_xlabel("wall time of training and scoring")


FEW_COLUMNS = 10  # scorings a heatmap's x axis can label one by one


def _heatmap(ax, figure, steps: np.ndarray, values: np.ndarray, names: list[str], label: str) -> None:
    """Sets (rows, named) × scoring steps (columns, centred on their steps). A run of few
    scorings has a tick at each column (a round 2k ... 6k read as a run longer than its 5k)."""
    image = ax.pcolormesh(_cell_edges(steps), np.arange(len(names) + 1) - 0.5, values.T, cmap="viridis", shading="flat")
    if len(steps) <= FEW_COLUMNS:
        ax.set_xticks(steps)
    figure.colorbar(image, ax=ax, label=label)
    # Every row named: a row is 0.12 inch high (plot_runs), room for a 6-point label.
    ax.set_yticks(np.arange(len(names)), names, fontsize=8 if len(names) <= 40 else 6)
    ax.set_ylim(len(names) - 0.5, -0.5)  # the first row on top, as the observation lists it


DEFAULT_FORMATS = ("png", "pdf")


def check_formats(formats: Sequence[str] | str) -> tuple[str, ...]:
    """``formats``, a sequence or a comma list as the command line gives them (``"png,SVG"``),
    as a tuple, each once and in lower case (``("png", "svg")``), if matplotlib writes every
    one of them (and there is one); ValueError naming the formats it writes otherwise."""
    names = formats.split(",") if isinstance(formats, str) else formats
    formats = tuple(dict.fromkeys(name.strip().lower() for name in names if name.strip()))
    writable = FigureCanvasBase.get_supported_filetypes()
    unknown = [name for name in formats if name not in writable]
    if unknown or not formats:
        raise ValueError(f"formats: {', '.join(map(repr, unknown)) or 'none given'}: give formats matplotlib writes, "
                         f"comma separated ({', '.join(sorted(writable))})")
    return formats


def _save(figure, out_dir: str, name: str, formats: tuple[str, ...]) -> list[str]:
    paths = [os.path.join(out_dir, f"{name}.{ext}") for ext in formats]
    try:
        for path in paths:
            figure.savefig(path, dpi=150, bbox_inches="tight")
    except (RuntimeError, OSError) as error:  # pgf without LaTeX, a full disk: one line, figures so far kept
        raise ValueError(f"cannot write {path}: {str(error).splitlines()[0]}") from error
    finally:
        plt.close(figure)
    return paths


def draw_curves(ax, runs: list[Run], attribute: str, window: int, per_seed: bool = False,
                against: str = "env_steps") -> tuple[float, float]:
    """One panel: ``attribute`` (``min_score``, ``mean_score``, ``clean_score``) of each curve
    of these labelled runs of one env against env steps: the mean over seeds of the trailing
    moving average (mode's colour, variant's line style), its 95% t-band, and the unsmoothed
    mean of each record as dots; with ``per_seed``, each seed's own moving average as a thin
    line (is one seed the outlier behind a wide band?). ``against="wall_seconds"``: against
    the wall time of training and scoring instead, each curve's scorings at its seeds' mean
    time (:attr:`~admissable_jax.results.Run.wall_seconds`). Returns the lowest and highest
    value the seeds took (each record and each seed's moving average), for
    :func:`keep_to_seeds`."""
    used = effective_window(runs, window)
    seen = []
    variants = sorted({run.variant for run in runs})
    curves = group_curves(runs)
    colors = curve_colors([(mode, variant) for _, mode, variant in curves])
    for (_, mode, variant), curve_runs in curves.items():
        steps, values = aligned(curve_runs, attribute)
        if against == "wall_seconds":
            steps = aligned(curve_runs, "wall_seconds")[1].mean(axis=0)
        smoothed = moving_average(values, used)
        mean, low, high = mean_and_interval(smoothed)
        color = colors[mode, variant]
        style = LINE_STYLES[variants.index(variant) % len(LINE_STYLES)]
        ax.plot(steps, mean, color=color, linestyle=style, label=f"{curve_runs[0].curve} ({_seeds(len(curve_runs))})")
        for seed_curve in smoothed if per_seed else ():
            ax.plot(steps, seed_curve, color=color, linestyle=style, linewidth=0.6, alpha=0.45)
        ax.fill_between(steps, low, high, color=color, alpha=0.2, linewidth=0)
        ax.plot(steps, values.mean(axis=0), ".", color=color, alpha=0.35, markersize=3)
        seen += [values, smoothed]
    if against == "wall_seconds":
        wall_time_axis(ax)
    else:
        env_steps_axis(ax)
    ax.grid(alpha=0.3)
    ax.legend()
    return _extent(seen)


def _extent(arrays: list[np.ndarray]) -> tuple[float, float]:
    """The lowest and highest finite value of ``arrays``."""
    finite = np.concatenate([np.ravel(array) for array in arrays])
    finite = finite[np.isfinite(finite)]
    return (float(finite.min()), float(finite.max())) if finite.size else (np.nan, np.nan)


CUT_BANDS = " (where it reaches past the seeds' values by more than their range, cut at the axes)"


def keep_to_seeds(ax, low: float, high: float) -> bool:
    """Limit ``ax``'s y axis to the seeds' values ``low`` to ``high`` and their range
    beyond on each side, where the 95% intervals reach farther: with 2 seeds a t-interval
    is 6.4 times their difference on each side of their mean, and a y axis drawn to hold it
    flattens every curve. Whether it cut one (the caption then says :data:`CUT_BANDS`)."""
    if not np.isfinite([low, high]).all():
        return False
    margin = high - low if high > low else max(abs(high), 1.0)
    bottom, top = ax.get_ylim()
    kept = (max(bottom, low - margin), min(top, high + margin))
    cut = kept != (bottom, top)
    if cut:
        ax.set_ylim(*kept)
    return cut


def plot_envs_side_by_side(run_dirs: list[str], out_dir: str, window: int = 0,
                           formats: Sequence[str] | str = DEFAULT_FORMATS, per_seed: bool = False) -> list[str]:
    """The paper's Figure 1 as it lays it out: min_u a_u of each env's runs in a panel of its
    own, side by side (Hopper-v5, Walker2d-v5, Ant-v5 first), as ``figure1.png``/``.pdf`` (or
    ``formats``) in ``out_dir``; each env smoothed by its own records (:func:`effective_window`);
    ``per_seed`` as in :func:`draw_curves`."""
    formats = check_formats(formats)
    runs = load_runs(run_dirs)
    if not runs:
        raise ValueError("no runs to plot")
    order = list(ENV_SPECS)
    envs = sorted({run.env for run in runs}, key=lambda env: (order.index(env) if env in order else len(order), env))
    figure, axes = plt.subplots(1, len(envs), figsize=(5 * len(envs), 4), squeeze=False)
    notes, shaded, cut = [], False, False
    for ax, env in zip(axes[0], envs):
        env_runs = [run for run in runs if run.env == env]
        cut = keep_to_seeds(ax, *draw_curves(ax, env_runs, "min_score", window, per_seed)) or cut
        ax.set_title(getattr(ENV_SPECS.get(env), "gymnasium_id", None) or env)
        notes.append(f"{env}: {_window_note(env_runs, window)}")
        shaded = shaded or _has_interval(env_runs)
    axes[0][0].set_ylabel("adversarial performance $\\mathrm{min}_u\\, a_u$")
    figure.suptitle(f"Performance under adversarial missingness: $\\mathrm{{min}}_u\\, a_u$ at every scoring. Lines: "
                    f"mean over seeds, smoothed per env ({'; '.join(notes)})"
                    + ("; shaded: 95% t-interval over seeds" + CUT_BANDS * cut if shaded else "")
                    + ("; thin lines: each seed" if per_seed else ""),
                    fontsize=8, y=-0.02, va="top", wrap=True)
    make_directory(out_dir, "figures folder")
    return _save(figure, out_dir, "figure1", formats)


def plot_runs(run_dirs: list[str] | str, out_dir: str, window: int = 0,
              formats: Sequence[str] | str = DEFAULT_FORMATS, per_seed: bool = False) -> list[str]:
    """Draw the figures for these runs into ``out_dir``, each in every one of ``formats``;
    returns the files written. ``run_dirs``: run directories (one as a string; the runs
    under a folder: :func:`~admissable_jax.results.find_runs`). ``window``: records in the
    moving average (0: the paper's, :func:`effective_window`); ``per_seed``: each seed's curve
    too, thin (:func:`draw_curves`)."""
    formats = check_formats(formats)
    runs = load_runs(run_dirs)
    if not runs:
        raise ValueError("no runs to plot")
    envs = sorted({run.env for run in runs})
    if len(envs) > 1:
        raise ValueError(f"runs of several envs ({', '.join(envs)}): plot one env at a time")
    effective_window(runs, window)  # a bad window is refused before anything is written
    curves = group_curves(runs)
    for curve_runs in curves.values():
        seeds = [run.seed for run in curve_runs]
        for seed in sorted({seed for seed in seeds if seeds.count(seed) > 1}):
            print(f"warning: {curve_runs[0].curve} seed {seed} is in {seeds.count(seed)} runs "
                  f"({', '.join(run.path for run in curve_runs if run.seed == seed)}); each counts as a seed",
                  file=sys.stderr)
    make_directory(out_dir, "figures folder")
    written = []

    # The worst case (Figure 1), the average case where all of U was scored, and the clean
    # return, on one y scale: the gaps between them are what the modes trade.
    panels = [("min_score", "adversarial performance $\\mathrm{min}_u\\, a_u$")]
    if not any(run.pooled for run in runs):
        panels.append(("mean_score", "average over hidden sets $\\mathrm{mean}_u\\, a_u$"))
    panels.append(("clean_score", "clean return (nothing hidden)"))
    figure, axes = plt.subplots(1, len(panels), figsize=(5.5 * len(panels), 4), sharey=True)
    extents = []
    for ax, (attribute, title) in zip(axes, panels):
        extents.append(draw_curves(ax, runs, attribute, window, per_seed))
        ax.set_title(f"{envs[0]}: {title}", fontsize=10)
    axes[0].set_ylabel("return")
    cut = keep_to_seeds(axes[0], *_extent([np.array(extents)]))  # one y scale: the panels share it
    width = int(15 * 5.5 * len(panels))  # characters: 15 an inch
    caption = _wrapped(_figure_caption(runs, window, per_seed, cut), width)
    figure.suptitle(caption, fontsize=9, y=-0.02, va="top")
    written += _save(figure, out_dir, "min_score", formats)
    if all(np.isfinite(run.wall_seconds).all() for run in runs):
        # How soon each curve gets robust, in time: what a cheaper score estimator, another
        # backend or device buys (the runs' own timings of their intervals).
        _warn_of_unlike_times(curves)
        figure, ax = plt.subplots(figsize=(6.5, 4))
        cut = keep_to_seeds(ax, *draw_curves(ax, runs, "min_score", window, per_seed, against="wall_seconds"))
        ax.set_title(f"{envs[0]}: adversarial performance $\\mathrm{{min}}_u\\, a_u$ against wall time", fontsize=10)
        ax.set_ylabel("return")
        caption = (f"{_figure_caption(runs, window, per_seed, cut)}\nWall time: each interval's training and scoring "
                   "as the run's metrics.jsonl timed them, summed (start-up, the compile before training and "
                   "checkpoints not counted; what compiles within the first interval, as Warp's kernels do, is in it; "
                   "an experiment's pairs share one program's); each curve at its seeds' mean.")
        figure.suptitle(_wrapped(caption, CAPTION_WIDTH), fontsize=8, y=-0.02, va="top")
        written += _save(figure, out_dir, "min_score_by_time", formats)

    for (_, mode, variant), mode_runs in curves.items():
        run = mode_runs[0]
        by_feature = run.pooled or len(run.set_names) > MOST_ROWS  # a pool's rows are its features (members: the identity)
        names = run.features if by_feature else run.set_names
        height = max(4.0, 0.12 * len(names) + 1.5)
        sets = "the pool's sets" if run.pooled else f"the {len(run.set_names):,} sets"
        labels = ((f"lowest $a_u$ of {sets} hiding it", "$p_{miss}$ mass on them") if by_feature
                  else ("$a_u$", "$p_{miss}(u)$"))
        over_seeds = " (mean over seeds)" if len(mode_runs) > 1 else ""
        for attribute, label, name in zip(("scores", "p_miss"), (f"{text}{over_seeds}" for text in labels),
                                          ("scores", "p_miss")):
            if attribute == "p_miss" and mode == "none":
                continue  # mode none hides nothing in training: its recorded p_miss is never drawn from
            steps, values = aligned(mode_runs, attribute)
            values = values.mean(axis=0)
            if by_feature:
                values = per_feature_of_sets(values, run.set_members, attribute)
            figure, ax = plt.subplots(figsize=(10, height))
            ax.set_title(f"{envs[0]}, {mode} missingness{f', {variant}' if variant else ''} "
                         f"({_seeds(len(mode_runs))}): {label}")
            if attribute == "p_miss" and all(seed_run.uniform_draws for seed_run in mode_runs):
                every = ("every set of U drawn alike" if run.pooled else
                         f"1/{len(run.set_names)} = {1.0 / len(run.set_names):.4f} for every u")
                ax.text(0.5, 0.5, f"$p_{{miss}}$ stayed uniform: {every},\nat all {len(steps)} scorings "
                        f"({steps_text(steps[0])} to {steps_text(steps[-1])} env steps)",
                        ha="center", va="center", transform=ax.transAxes, fontsize=12)
                ax.set_axis_off()
                figure.set_size_inches(10, 2.5)
            else:
                _heatmap(ax, figure, steps, values, names, label)
                env_steps_axis(ax, "env steps (each column one scoring)")
                ax.set_ylabel(f"feature (over {sets} hiding it)" if by_feature else "hidden features u")
            written += _save(figure, out_dir, f"{name}_{mode}" + (f"_{_file_name(variant)}" if variant else ""), formats)

    # Where each mode is weak at the end: a_u per hidden set, the modes' bars side by side
    # (one figure per candidate-set list: runs of another k have other sets).
    groups: dict[tuple[str, ...], list[list[Run]]] = collections.defaultdict(list)
    for curve_runs in curves.values():
        groups[tuple(curve_runs[0].set_names)].append(curve_runs)
    for names, group in groups.items():
        variant = group[0][0].variant
        name = "final_scores" + (f"_{_file_name(variant)}" if len(groups) > 1 and variant else "")
        written += _save(_final_scores_figure(envs[0], list(names), group), out_dir, name, formats)
    return written


UNLIKE_TIMES = 1.5  # a curve's seeds whose times differ by more than this factor ran unlike


def _warn_of_unlike_times(curves: dict[tuple[str, str, str], list[Run]]) -> None:
    """One line per curve whose seeds took times apart by more than :data:`UNLIKE_TIMES` to
    their last shared scoring: seeds of one curve may have run on other devices or physics
    (which the curve does not split), and its time axis is their mean."""
    for curve_runs in curves.values():
        last = shared_records(curve_runs) - 1
        times = [run.wall_seconds[last] for run in curve_runs]
        if max(times) > UNLIKE_TIMES * min(times):
            print(f"warning: min_score_by_time: the seeds of {curve_runs[0].curve} took {wall_time_text(min(times))} to "
                  f"{wall_time_text(max(times))} (other devices or physics?); its time axis is their mean",
                  file=sys.stderr)


def _final_scores_figure(env: str, names: list[str], group: list[list[Run]]):
    """Bars per hidden set (x) and curve (side by side, the mode's colour): the last record's
    a_u; with a pool only the features some pooled set hides; of a U of more than
    ``MOST_ROWS`` sets the ``LOWEST_BARS`` whose lowest a_u over the curves is lowest, lowest
    first. A dashed line per curve at its clean return of that record: what hiding each set
    costs."""
    finals = [final_scores(curve_runs) for curve_runs in group]
    means = np.stack([mean for _, mean, _, _ in finals])
    shown = np.flatnonzero(np.isfinite(means).any(axis=0))
    lowest = ""
    if len(shown) > MOST_ROWS:
        lowest = f"the {LOWEST_BARS} lowest of {len(shown):,} {'features' if group[0][0].pooled else 'sets'}; "
        shown = shown[np.argsort(np.nanmin(means[:, shown], axis=0), kind="stable")[:LOWEST_BARS]]
    names = [names[i] for i in shown]
    x, width = np.arange(len(names)), 0.8 / len(group)
    variants = sorted({curve_runs[0].variant for curve_runs in group})
    colors = curve_colors([(curve_runs[0].mode, curve_runs[0].variant) for curve_runs in group])
    seeded = _has_interval([run for curve_runs in group for run in curve_runs])
    figure, ax = plt.subplots(figsize=(min(30.0, max(8.0, 0.25 * len(names) * len(group))), 4.5))
    seen = [np.zeros(1)]  # the bars' foot, each seed's a_u and clean return: what the y axis keeps to
    for index, (curve_runs, (steps, mean, low, high)) in enumerate(zip(group, finals)):
        mean, low, high = mean[shown], low[shown], high[shown]
        run = curve_runs[0]
        ax.bar(x + (index - (len(group) - 1) / 2) * width, mean, width, yerr=[mean - low, high - mean] if seeded else None,
               capsize=1.5 if len(names) <= 40 else 0, color=colors[run.mode, run.variant], alpha=0.75,
               hatch=("", "//", "..", "xx")[variants.index(run.variant) % 4],
               label=f"{run.curve} ({_seeds(len(curve_runs))}, {steps_text(steps)} env steps)")
        clean = aligned(curve_runs, "clean_score")[1][:, -1]  # each seed's, at the bars' record
        seen += [aligned(curve_runs, "scores")[1][:, -1, shown], clean]
        if np.isfinite(clean).all():
            ax.axhline(clean.mean(), color=colors[run.mode, run.variant], linestyle="--", linewidth=1,
                       label=f"{run.curve}: clean return {clean.mean():.1f} (nothing hidden)")
    ax.set_xticks(x, names, rotation=60, ha="right", fontsize=7 if len(names) <= 40 else 5)
    ax.set_xlim(-0.6, len(names) - 0.4)
    cut = keep_to_seeds(ax, *_extent(seen))
    ax.set_ylabel("lowest $a_u$ of the pool's sets hiding it" if group[0][0].pooled else "$a_u$")
    ax.set_title(f"{env}: the last scoring's $a_u$ per hidden {'feature' if group[0][0].pooled else 'set'} "
                 f"({lowest}{'mean over seeds; bars: 95% t-interval' if seeded else 'one seed per curve: no interval'})"
                 + "\n(bars reaching past the seeds' values by more than their range are cut at the axes)" * cut,
                 fontsize=10)
    ax.grid(alpha=0.3, axis="y")
    ax.legend(fontsize=8)
    return figure


def _differing_note(env: str, keys: list[str]) -> str:
    """summary.md's line for an env whose runs differ in the settings ``keys``."""
    adversary_only = sorted(ADVERSARY_SETTINGS & set(keys))
    baseline = (f"; the uniform and none runs never read {', '.join(adversary_only)}, so each adversarial curve is "
                "compared with the uniform curve of its other settings" if adversary_only else "")
    return f"\n{env} runs differ in {', '.join(keys)}: each setting is its own curve and row, never seeds of one{baseline}.\n"


def _file_name(variant: str) -> str:
    """A variant as part of a file name: "k=2, utd=0.5" -> "k=2_utd=0.5"."""
    return re.sub(r"[^A-Za-z0-9.=+-]+", "_", variant).strip("_")


@dataclasses.dataclass
class PlotConfig:
    window: int = dataclasses.field(default=0, metadata={
        "help": "moving-average window (records); 0: the paper's 40 of 200 records, a fifth of a shorter run's"})
    out: str = dataclasses.field(default="", metadata={"help": "output folder ('' = a new <first path>/figures, figures-2, ...)"})
    formats: str = dataclasses.field(default=",".join(DEFAULT_FORMATS), metadata={
        "help": "figure file formats, comma separated: any matplotlib writes (png, pdf, svg, eps, ...)"})
    per_seed: bool = dataclasses.field(default=False, metadata={
        "help": "also draw each seed's smoothed curve, thin, beside the mean and its band"})


def new_folder(path: str) -> str:
    """``path`` if it does not exist yet, else the first free ``path-2``, ``path-3``, ..."""
    candidate, number = path, 1
    while os.path.exists(candidate):
        number += 1
        candidate = f"{path}-{number}"
    return candidate


def main(argv: list[str]) -> int:
    paths = [arg for arg in argv if "=" not in arg and not arg.startswith("-")]
    options = [arg for arg in argv if arg not in paths]
    config = parse_args(PlotConfig, options, "admissable_jax.plot RUN_DIR [RUN_DIR ...]", __doc__.splitlines()[0])
    if not paths:
        fail("give at least one run directory (or a folder of them)")
    out_dir, made_out_dir = None, False
    try:
        formats = check_formats(config.formats)
        runs = find_runs(paths)
        by_env: dict[str, list[Run]] = collections.defaultdict(list)
        for path in runs:
            run = load_run(path)
            by_env[run.env].append(run)
        notes = {env: _window_note(env_runs, config.window) for env, env_runs in sorted(by_env.items())}
        smoothing = (f"mean over seeds of the {next(iter(notes.values()))}" if len(notes) == 1 else
                     "mean over seeds, smoothed per env (" + "; ".join(f"{env}: {note}" for env, note in notes.items()) + ")")
        variants = "".join(_differing_note(env, keys) for env, keys in
                           ((env, differing_settings(env_runs)) for env, env_runs in sorted(by_env.items())) if keys)
        out_dir = config.out or new_folder(os.path.join(paths[0], "figures"))
        made_out_dir = not os.path.exists(out_dir)
        written = []  # one env's figures in out_dir, several envs' each in out_dir/<env>
        for env, env_runs in sorted(by_env.items()):
            written += plot_runs([run.path for run in env_runs], out_dir if len(by_env) == 1 else os.path.join(out_dir, env),
                                 config.window, formats, config.per_seed)
        if len(by_env) > 1:  # the paper's layout: every env's min_u a_u side by side
            written += plot_envs_side_by_side(runs, out_dir, config.window, formats, config.per_seed)
        written += write_tables(runs, out_dir)
        table = summary_table(runs)
        comparison = comparison_sections(runs)
        provenance = trained_on(runs)
    except (ValueError, FileNotFoundError, KeyError, UnusableDirectory) as error:
        fail(str(error))
    except KeyboardInterrupt:
        if made_out_dir:  # left only if it holds a figure
            remove_if_unused(out_dir, own_files=())
        drawn = f"the figures drawn so far are in {out_dir}" if out_dir and os.path.isdir(out_dir) else "nothing written"
        print(f"interrupted: {drawn}; the runs are untouched", file=sys.stderr)
        return INTERRUPTED
    table += (f"\nFigures: {smoothing}. Table: the last "
              f"record itself (final) and the mean over all records (AUC), unsmoothed.\n{variants}"
              f"\n{provenance}\n" + (f"\n{comparison}" if comparison else ""))
    with open(os.path.join(out_dir, "summary.md"), "w") as file:
        file.write(table)
    print(table)
    print(f"figures, summary.md and CSV tables written to {out_dir}/:")
    print("\n".join(f"  {os.path.relpath(path, out_dir)}" for path in [*written, os.path.join(out_dir, "summary.md")]))
    return 0


if __name__ == "__main__":
    run_main(main)
