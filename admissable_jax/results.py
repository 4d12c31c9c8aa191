"""Finished runs read back and compared: the numbers behind ``plot``'s figures and summary.

A run directory (``train``'s, or one pair of an ``experiment``) holds ``config.yaml`` and
``scores.jsonl``; :func:`load_run` reads them into a :class:`Run`, :func:`label_variants`
names the settings in which runs of one env differ, and :func:`group_curves` groups them into
curves (env, mode, variant), whose runs are the seeds. From those:

* :func:`summary_table` — final and area-under-curve min_u a_u, the final mean_u a_u and
  the final clean return per curve, mean ± 95% t-interval over seeds, and the set most
  often worst at the end;
* :func:`mode_differences` / :class:`Difference` — adversarial − uniform on each (and
  adversarial − worst, where mode worst ran), with Welch's 95% interval, p-value, a reading
  and, where the seeds cannot tell the modes apart, how many seeds per mode would
  (:func:`comparison_sections`);
* :func:`trained_on` — where the runs were trained, from their ``invocations.jsonl``;
* :func:`write_tables` — every run's history as two tidy CSV tables (``curves.csv``: a row
  per run and scoring; ``scores.csv``: a row per run, scoring and hidden set), for analyses
  of one's own in pandas, R or a spreadsheet.

Nothing here draws (no matplotlib): ``plot`` draws the figures from these, and
``experiment`` prints the same comparison when it ends.
"""

from __future__ import annotations

import collections
import csv
import dataclasses
import glob
import math
import os
import re
import sys
from typing import Any

import numpy as np

from admissable_jax.config import RUN_SETTINGS, TrainConfig, number_text
from admissable_jax.envs import observation_names
from admissable_jax.method import candidate_sets, hidden_row, parse_set
from admissable_jax.provenance import INVOCATION_KEYS, INVOCATIONS
from admissable_jax.run_directory import (SCORING_KEYS, TornLine, load_config_yaml, read_jsonl,
                                          recorded_observation_names, run_config_path)
from admissable_jax.scoring.worst_set import samples_to_separate

# Config keys that change neither what a run learns nor how it is scored: runs that differ
# only in these are seeds of one curve (``physics``: both backends pass the same parity
# tests; ``score_envs``: the same scores, tested; ``worlds_per_call``: the same physics in
# pieces). Runs differing in any other key are separate curves, named by it (``label_variants``).
NOT_SETTINGS = frozenset({"env", "missingness", "seed", "out", "resume", "resume_step", "fast_forward", "progress", "logger",
                          "time_limit", "checkpoint_every", "keep_checkpoints", "total_steps", "score_envs",
                          "worlds_per_call", "physics"})
# Settings that only the adversarial mode reads (its p_miss update, paper §3; the pool's
# exploration share): runs of the other modes that differ only in these are seeds of one
# curve, the baseline of every adversarial curve that shares their other settings. Mode
# worst reads the pool's share alone (its p_miss is the argmin's, whatever l and ε).
ADVERSARY_SETTINGS = frozenset({"lower_bound", "epsilon", "pool_explore"})
SETTINGS_READ_BY = {"adversarial": ADVERSARY_SETTINGS, "worst": frozenset({"pool_explore"})}


@dataclasses.dataclass
class Run:
    """One run directory read back (:func:`load_run`): its scoring history, one row per scoring."""

    path: str
    env: str
    mode: str
    seed: int
    env_steps: np.ndarray  # (T,)
    scores: np.ndarray  # (T, |U|) a_u; with a pool (T, d): the lowest a_u of the pool's sets hiding each feature
    min_score: np.ndarray  # (T,)
    mean_score: np.ndarray  # (T,) mean_u a_u over U, the average case; NaN with a pool (it scores only its sets)
    clean_score: np.ndarray  # (T,)
    wall_seconds: np.ndarray  # (T,) training and scoring up to each scoring (interval_seconds); NaN where untimed
    p_miss: np.ndarray  # (T, |U|); with a pool (T, d): the p_miss mass on the pool's sets hiding each feature
    set_names: list[str]  # (|U|,) the hidden features of each candidate set; with a pool each feature's name
    set_members: np.ndarray  # (|U|, d) bool: which features each set hides; with a pool the identity
    features: list[str]  # (d,) the observation's feature names
    worst_sets: list[str]  # (T,) the set of lowest a_u at each scoring, by its features' names
    score_episodes: int  # N: episodes behind each a_u
    pooled: bool = False  # scores and p_miss are per feature (a run with a candidate pool)
    uniform_draws: bool = False  # p_miss stayed uniform at every scoring
    settings: dict[str, str] = dataclasses.field(default_factory=dict)  # config keys but NOT_SETTINGS, as text
    variant: str = ""  # the settings in which it differs from the other runs of its env (label_variants)
    baseline_variant: str = ""  # the variant of the uniform curve it is compared with: variant less ADVERSARY_SETTINGS

    @property
    def curve(self) -> str:
        """The curve this run is a seed of: its mode, and its variant where runs differ."""
        return f"{self.mode}, {self.variant}" if self.variant else self.mode


def set_names(features: list[str], members: np.ndarray) -> list[str]:
    """A name per candidate set u (a row of ``members``, (|U|, d) 0/1, in the runs' order):
    the names of the features it hides."""
    return [" + ".join(features[i] for i in np.flatnonzero(row)) or "nothing hidden" for row in members]


def per_feature_of_sets(values: np.ndarray, members: np.ndarray, attribute: str) -> np.ndarray:
    """(T, |U|) a_u (``attribute`` ``scores``) or p_miss (``p_miss``) of every candidate set
    as (T, d) per feature: the lowest a_u of the sets that hide it (NaN where none does), or
    the p_miss mass on them: for a U too large to draw a row per set (Ant at k = 2: 5,460
    sets), and for a pooled run's rows (:func:`per_feature`)."""
    members = np.asarray(members, bool)
    if attribute == "p_miss":
        return values @ members
    return np.stack([values[:, hiding].min(axis=1) if hiding.any() else np.full(len(values), np.nan)
                     for hiding in members.T], axis=1)


def interval_seconds(row: dict[str, Any], score_every: int) -> float:
    """The wall seconds of one scoring interval, from its ``metrics.jsonl`` row: the training
    chunk (ζ env steps at the row's ``env_steps_per_s``, each run's own) and the scoring
    round. Start-up, the compile before training and checkpoints are in no interval (what
    compiles at its first call inside the first chunk, as Warp's kernels do, is in it)."""
    return score_every / row["env_steps_per_s"] + row["score_seconds"]


def _wall_seconds(path: str, env_steps: np.ndarray, score_every: int) -> np.ndarray:
    """(T,) the wall seconds of training and scoring up to each scoring at ``env_steps``: the
    :func:`interval_seconds` of the run's ``metrics.jsonl`` summed, NaN from the first
    interval it has not timed (no file, a row without the times; an unreadable file: all)."""
    try:
        rows = read_jsonl(os.path.join(path, "metrics.jsonl"), torn="drop", required=("env_steps",))
    except (OSError, ValueError):
        rows = []
    seconds = {int(row["env_steps"]): interval_seconds(row, score_every) for row in rows
               if row.get("env_steps_per_s") and isinstance(row.get("score_seconds"), (int, float))}
    return np.cumsum([seconds.get(int(steps), np.nan) for steps in env_steps])


def load_run(path: str) -> Run:
    """A run directory's config and scoring history."""
    config = load_config_yaml(run_config_path(path))
    scores_path = os.path.join(path, "scores.jsonl")
    try:
        rows = read_jsonl(scores_path, required=SCORING_KEYS)
    except TornLine as torn:
        print(f"warning: {torn}; reading the rows before it", file=sys.stderr)
        rows = read_jsonl(scores_path, torn="drop", required=SCORING_KEYS)
    if not rows:
        raise ValueError(f"{path} has no scoring rows yet")

    def column(key: str) -> np.ndarray:
        try:
            return np.asarray([row[key] for row in rows], dtype=float)
        except (TypeError, ValueError):  # ragged lists, or not numbers
            raise ValueError(f"{scores_path}: the rows' {key!r} are not numbers of one shape; the file is corrupt") from None

    scores, p_miss = column("scores"), column("p_miss")
    uniform_draws = bool(np.allclose(p_miss, 1.0 / p_miss.shape[-1]))
    pooled = "sets" in rows[0]
    features = recorded_observation_names(path) or observation_names(str(config.env))
    if pooled:  # per feature; at each scoring the pool's set of lowest a_u, named
        names, members = features, np.eye(len(features), dtype=bool)
        scores, p_miss = per_feature(rows, len(names))
        mean_score = np.full(len(rows), np.nan)
        worst_sets = [" + ".join(features[i] for i in parse_set(row["sets"][int(np.argmin(row["scores"]))]))
                      for row in rows]
    else:
        up_to_k = bool(config.get("up_to_k", False))  # a config written before the key: exactly k
        members = candidate_sets(len(features), int(config.k), bool(config.include_empty_set), up_to_k).astype(bool)
        names = set_names(features, members)
        if scores.ndim != 2 or scores.shape[1] != len(names) or p_miss.shape != scores.shape:
            raise ValueError(f"{scores_path}: each row must hold {len(names)} scores and p_miss values (one per set "
                             f"of {config.env} with k={config.k}{', up_to_k' * up_to_k}), "
                             f"got {scores.shape[1:]} and {p_miss.shape[1:]}")
        mean_score = scores.mean(axis=1)
        worst_sets = [names[i] for i in np.argmin(scores, axis=1)]
    return Run(
        path=path, env=str(config.env), mode=str(config.missingness), seed=int(config.seed),
        env_steps=column("env_steps"), scores=scores, min_score=column("min_score"), mean_score=mean_score,
        clean_score=column("clean_score"),
        wall_seconds=_wall_seconds(path, column("env_steps"), int(config.score_every)), p_miss=p_miss,
        set_names=names, set_members=members,
        features=list(features), worst_sets=worst_sets,
        score_episodes=int(config.score_episodes), pooled=pooled, uniform_draws=uniform_draws,
        settings={key: setting_text(value) for key, value in {**dataclasses.asdict(TrainConfig()), **config}.items()
                  if key not in NOT_SETTINGS
                  and (key not in ADVERSARY_SETTINGS or key in SETTINGS_READ_BY.get(config.missingness, ()))},
    )


def setting_text(value) -> str:
    """A setting's value as a curve's label shows it: numbers as short as they read back
    (``lower_bound=50``, as the sweep's folder ``adversarial-l50`` names it; ``1e-08``)."""
    return number_text(value) if isinstance(value, float) else str(value)


def differing_settings(runs: list[Run]) -> list[str]:
    """The settings (config keys but ``NOT_SETTINGS``) whose values differ between the runs
    that have them (a uniform run has no ``lower_bound``: :data:`ADVERSARY_SETTINGS`)."""
    keys = set().union(*(run.settings for run in runs))
    return sorted(key for key in keys if len({run.settings[key] for run in runs if key in run.settings}) > 1)


def label_variants(runs: list[Run]) -> list[Run]:
    """The runs, each with its variant named: the settings in which the runs of its env
    differ ("k=2, score_episodes=5"; "" where all agree), of those it has (a uniform run has
    no ``lower_bound``: :data:`ADVERSARY_SETTINGS`). Runs that differ in a setting are
    separate curves, table rows and comparisons, never seeds of one."""
    keys = {env: differing_settings([run for run in runs if run.env == env]) for env in {run.env for run in runs}}
    named = lambda run, names: ", ".join(f"{key}={run.settings[key]}" for key in names if key in run.settings)
    return [dataclasses.replace(run, variant=named(run, keys[run.env]),
                                baseline_variant=named(run, [key for key in keys[run.env] if key not in ADVERSARY_SETTINGS]))
            for run in runs]


def group_curves(runs: list[Run]) -> dict[tuple[str, str, str], list[Run]]:
    """The runs by (env, mode, variant): each group one curve, its runs the seeds; in the
    order of env, mode and the variant's numbers (lower_bound=25 before lower_bound=100)."""
    curves: dict[tuple[str, str, str], list[Run]] = collections.defaultdict(list)
    for run in runs:
        curves[(run.env, run.mode, run.variant)].append(run)
    return dict(sorted(curves.items(), key=lambda item: (item[0][:2], numbers_in_order(item[0][2]))))


def numbers_in_order(text: str) -> list[tuple[int, float | str]]:
    """A sort key under which "l=25" comes before "l=100": the text's numbers as numbers."""
    parts = re.split(r"(-?\d+(?:\.\d+)?(?:e-?\d+)?)", text)
    return [(0, float(part)) if index % 2 else (1, part) for index, part in enumerate(parts)]


def per_feature(rows: list[dict], num_features: int) -> tuple[np.ndarray, np.ndarray]:
    """(T, d) from the rows of a run with a pool: per feature, the lowest a_u of the
    pool's sets that hide it (NaN where none does) and the p_miss mass on those sets
    (:func:`per_feature_of_sets` of each row's own sets)."""
    def of_row(row: dict) -> list[np.ndarray]:
        members = np.stack([hidden_row(parse_set(name), num_features) for name in row["sets"]])
        return [per_feature_of_sets(np.asarray([row[key]], float), members, key)[0] for key in ("scores", "p_miss")]

    scores, p_miss = (np.stack(column) for column in zip(*map(of_row, rows)))
    return scores, p_miss


def find_runs(paths: list[str] | str) -> list[str]:
    """Every directory at or under ``paths`` (folders, or one as a string: :func:`paths_of`)
    that holds a run's ``config.yaml`` and a ``scores.jsonl`` of at least one row. A run
    that has not scored since it started, or since a restart set its rows aside
    (``RunDirectory.set_aside_rows_after``), is left out with a warning, as one not yet
    scored at all is: a folder of runs can be read while one of them starts over. FileNotFoundError for a path that is no directory; ValueError where
    none holds a run, naming an archive beside them to unpack first (``benchmarks/results``
    keeps a campaign's runs packed, ``runs.tar.xz``, beside their figures)."""
    paths = paths_of(paths)
    found, unscored = [], []
    for path in paths:
        check_is_folder(path)
        for root, _, files in os.walk(path):
            if "scores.jsonl" in files and RUN_SETTINGS in files:
                (found if _holds_a_row(os.path.join(root, "scores.jsonl")) else unscored).append(root)
    for root in unscored:
        print(f"warning: {root} has no scoring rows yet: left out", file=sys.stderr)
    if not found and unscored:
        raise ValueError(f"no run under {', '.join(paths)} has scored yet ({len(unscored)} without scoring rows)")
    if not found:
        beside = {folder for path in paths for folder in (path, os.path.normpath(os.path.join(path, os.pardir)))}
        archives = sorted(archive for folder in beside for archive in glob.glob(os.path.join(folder, "*.tar*")))
        unpack = (f"; are they packed in {archives[0]}? unpack it (mkdir DIR && tar -xf {archives[0]} -C DIR) "
                  f"and give DIR" if archives else "")
        raise ValueError(f"no run directories (config.yaml + scores.jsonl) under {', '.join(paths)}{unpack}")
    return sorted(distinct_directories(found))


def check_is_folder(path: str) -> None:
    """FileNotFoundError in one line where ``path``, given as a folder of runs, is none (a
    file: naming its folder)."""
    if os.path.isfile(path):
        raise FileNotFoundError(f"{path} is a file: give a run's folder (or a folder of runs), such as "
                                f"{os.path.dirname(path) or '.'}")
    if not os.path.isdir(path):
        raise FileNotFoundError(f"no such directory: {path}")


def _holds_a_row(path: str) -> bool:
    """Whether the JSONL file ``path`` holds one whole line (a torn first line is none)."""
    with open(path) as file:
        return file.readline().endswith("\n")


def moving_average(values: np.ndarray, window: int) -> np.ndarray:
    """Trailing mean over the last ``window`` records (fewer at the start), along axis -1."""
    cumulative = np.cumsum(values, axis=-1)
    shifted = np.concatenate([np.zeros_like(cumulative[..., :window]), cumulative[..., :-window]], axis=-1)
    counts = np.minimum(np.arange(1, values.shape[-1] + 1), window)
    return (cumulative - shifted[..., : values.shape[-1]]) / counts


def mean_and_interval(curves: np.ndarray, confidence: float = 0.95) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Mean over seeds (axis 0) and a two-sided t-interval; the interval is the mean alone
    for a single seed."""
    from scipy import stats  # here, as in scoring.worst_set: 0.6 s that training's start-up does not need

    mean = curves.mean(axis=0)
    n = curves.shape[0]
    if n < 2:
        return mean, mean, mean
    half = stats.t.ppf(0.5 + confidence / 2, n - 1) * curves.std(axis=0, ddof=1) / np.sqrt(n)
    return mean, mean - half, mean + half


def aligned(runs: list[Run], attribute: str) -> tuple[np.ndarray, np.ndarray]:
    """(env steps, stacked values) over the records all runs share."""
    length = min(len(run.env_steps) for run in runs)
    return runs[0].env_steps[:length], np.stack([getattr(run, attribute)[:length] for run in runs])


def shared_records(runs: list[Run]) -> int:
    """How many records (scorings) the runs share."""
    return min(len(run.env_steps) for run in runs)


def final_scores(curve_runs: list[Run]) -> tuple[int, np.ndarray, np.ndarray, np.ndarray]:
    """One curve's a_u per candidate set (per feature, with a pool) at the last record its
    runs share: (env steps, mean over seeds, 95% t-interval low, high); NaN where a pool
    scored no set hiding the feature."""
    steps, values = aligned(curve_runs, "scores")  # (seeds, records, sets)
    return (int(steps[-1]), *mean_and_interval(values[:, -1, :]))


def wall_time_text(seconds: float, _position: object = None) -> str:
    """A wall time as a figure's axis labels it: 0, 45 s, 12.5 min, 3.2 h (as a matplotlib
    ``FuncFormatter``)."""
    for scale, unit in ((3600, "h"), (60, "min")):
        if abs(seconds) >= scale:
            return f"{seconds / scale:.3g} {unit}"
    return f"{seconds:.3g} s" if seconds else "0"


def steps_text(steps: float, _position: object = None) -> str:
    """An env-step count as a figure's axis labels it: 0, 2.5k, 20k, 250k, 1M, 1.5M (as a
    matplotlib ``FuncFormatter``: a 1M-step run's six-digit ticks crowd a narrow panel)."""
    for scale, suffix in ((1e6, "M"), (1e3, "k")):
        if abs(steps) >= scale:
            return f"{steps / scale:.4g}{suffix}"
    return f"{steps:.4g}"


def estimate(values: np.ndarray) -> str:
    """Per-seed values as text: "mean ± 95% t-interval half-width" (the mean alone for one seed)."""
    mean, low, _ = mean_and_interval(values[:, None])
    return f"{mean[0]:.1f} ± {mean[0] - low[0]:.1f}" if len(values) > 1 else f"{mean[0]:.1f}"


def paths_of(paths: list[str] | str) -> list[str]:
    """``paths`` as a list, one path given as a string being one path (iterated, its
    characters would be taken for paths, an absolute path's first being ``/``)."""
    return [paths] if isinstance(paths, str) else list(paths)


def distinct_directories(paths: list[str]) -> list[str]:
    """``paths`` with each directory once, as first spelt: a run reached twice (``plot runs
    runs/x``, ``runs/x ./runs/x``) is one seed, not two that agree to the last digit."""
    first_spelt: dict[str, str] = {}
    for path in paths:
        first_spelt.setdefault(os.path.realpath(path), path)
    return list(first_spelt.values())


def load_runs(run_dirs: list[str] | str) -> list[Run]:
    """The runs in these directories (one as a string; each directory once:
    :func:`distinct_directories`), each with its variant named (:func:`label_variants`)."""
    return label_variants([load_run(path) for path in distinct_directories(paths_of(run_dirs))])


def curves_of(run_dirs: list[str]) -> dict[tuple[str, str, str], list[Run]]:
    """The runs in these directories by (env, mode, variant)."""
    return group_curves(load_runs(run_dirs))


def summary_table(run_dirs: list[str]) -> str:
    """Markdown table per mode (and variant, where runs differ in settings): final and
    area-under-curve min_u a_u, the final mean_u a_u (the average case; "—" for runs with a
    pool, which score only its sets) and the final clean return, mean ± 95% t-interval
    half-width over seeds; and where the mode is weak at the end: the set most often worst
    at the final record, in how many seeds (ties: the first seed's). The AUC is the mean of
    min_u a_u over all records (the area under the curve divided by its length in records)."""
    lines = [
        "| env | mode | seeds | env steps | final min_u a_u | AUC min_u a_u (mean over records) | final mean_u a_u "
        "| final clean return | final worst u (seeds) |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    for (env, _, _), runs in curves_of(run_dirs).items():
        steps, minimum = aligned(runs, "min_score")
        _, average = aligned(runs, "mean_score")
        _, clean = aligned(runs, "clean_score")
        final_average = "—" if np.isnan(average[:, -1]).any() else estimate(average[:, -1])
        worst = [run.worst_sets[len(steps) - 1] for run in runs]
        common = max(worst, key=worst.count)
        lines.append(
            f"| {env} | {runs[0].curve} | {len(runs)} | {int(steps[-1])} | {estimate(minimum[:, -1])} | "
            f"{estimate(minimum.mean(axis=1))} | {final_average} | {estimate(clean[:, -1])} | "
            f"{common} ({worst.count(common)} of {len(runs)}) |"
        )
    return "\n".join(lines) + "\n"


@dataclasses.dataclass
class Difference:
    """Adversarial minus a baseline mode (uniform, the paper's; or worst) on one per-seed
    quantity, with Welch's 95% t-interval and two-sided p-value (seeds of one mode are
    independent of the other's)."""
    metric: str
    adversarial: np.ndarray  # (seeds,)
    baseline: np.ndarray  # (seeds,) of the baseline mode
    baseline_mode: str = "uniform"

    @property
    def mean(self) -> float:
        return float(self.adversarial.mean() - self.baseline.mean())

    def interval(self, confidence: float = 0.95) -> tuple[float, float, float] | None:
        """(low, high, p), or None with fewer than two seeds in a mode (no variance to test)."""
        from scipy import stats

        if min(len(self.adversarial), len(self.baseline)) < 2:
            return None
        test = stats.ttest_ind(self.adversarial, self.baseline, equal_var=False)
        low, high = test.confidence_interval(confidence)
        return float(low), float(high), float(test.pvalue)

    def reading(self) -> str:
        """The difference in words: which mode is higher, or that seeds cannot tell them apart."""
        interval = self.interval()
        if interval is None:
            return "one seed in a mode: not tested"
        low, high, _ = interval
        if low > 0:
            return "adversarial higher"
        if high < 0:
            return f"{self.baseline_mode} higher"
        return "not distinguishable (95% interval holds 0)"

    def probability_of_improvement(self, confidence: float = 0.95,
                                   resamples: int = 10_000) -> tuple[float, float, float] | None:
        """(P, low, high): P(adversarial > uniform), the chance that a seed of adversarial
        training ends above one of the baseline's (uniform training's), ties counted half (the
        Mann–Whitney statistic over every pair of seeds; the probability of improvement of Agarwal et al.,
        2021, *Deep RL at the Edge of the Statistical Precipice*), with a percentile-bootstrap
        interval that resamples each mode's seeds apart (a fixed seed: the same file twice).
        A rank measure: it needs none of the normal spread Welch's t assumes, which a few
        seeds of RL returns rarely show. None with fewer than two seeds in a mode."""
        if min(len(self.adversarial), len(self.baseline)) < 2:
            return None
        rng = np.random.default_rng(0)
        drawn = [values[rng.integers(0, len(values), (resamples, len(values)))]
                 for values in (self.adversarial, self.baseline)]
        low, high = np.quantile(_wins(*drawn), [(1 - confidence) / 2, (1 + confidence) / 2])
        return float(_wins(self.adversarial, self.baseline)), float(low), float(high)

    def chance_of_order(self) -> float | None:
        """Where every seed of one mode ends above every seed of the other (P(adversarial >
        uniform) 0 or 1, whose bootstrap interval is then that one value, resample as one
        may), how often chance alone orders the seeds so: Mann–Whitney's exact two-sided p,
        2 / C(n + m, n) (2 and 2 seeds: 0.333); None otherwise, or with fewer than two seeds
        in a mode."""
        if min(len(self.adversarial), len(self.baseline)) < 2 or _wins(self.adversarial, self.baseline) not in (0, 1):
            return None
        return min(1.0, 2 / math.comb(len(self.adversarial) + len(self.baseline), len(self.adversarial)))

    def improvement_text(self) -> str:
        """:meth:`probability_of_improvement` as "0.88 [0.60, 1.00]", or "—"."""
        improvement = self.probability_of_improvement()
        return "—" if improvement is None else "{:.2f} [{:.2f}, {:.2f}]".format(*improvement)

    def seeds_to_separate(self) -> int | None:
        """Where these seeds cannot tell the modes apart (the 95% interval holds 0), the seeds
        per mode that would at the difference and spread seen (80% power, two-sided 5% t-test;
        :func:`~admissable_jax.scoring.worst_set.samples_to_separate`); else None, as with
        fewer than 2 seeds in a mode or modes that neither differ nor vary."""
        interval = self.interval()
        if interval is None or not interval[0] <= 0 <= interval[1]:
            return None
        low, high = sorted((self.baseline, self.adversarial), key=np.mean)
        return samples_to_separate(low, high, paired=False)

    def seeds_needed(self) -> str | None:
        """:meth:`seeds_to_separate` in words: "about 4", or "over 1,000" (a difference small
        against the seeds' spread); None where it is None."""
        seeds = self.seeds_to_separate()
        if seeds is None:
            return None
        return f"about {seeds:,}" if seeds <= 1000 else "over 1,000"

    def cells(self) -> str:
        """A markdown table's cells under :func:`comparison_header`'s columns: difference | 95%
        interval | p | P(adversarial > uniform) [95%] | reading."""
        interval = self.interval()
        low_high, p = ("—", "—") if interval is None else (f"[{interval[0]:.1f}, {interval[1]:.1f}]", f"{interval[2]:.3g}")
        return f"{self.mean:+.1f} | {low_high} | {p} | {self.improvement_text()} | {self.reading()}"


def _wins(adversarial: np.ndarray, uniform: np.ndarray) -> np.ndarray:
    """The share of (adversarial, uniform) seed pairs in which adversarial ends higher, ties
    half, over the last axes (the leading ones: bootstrap resamples)."""
    above = adversarial[..., :, None] > uniform[..., None, :]
    tied = adversarial[..., :, None] == uniform[..., None, :]
    return (above + 0.5 * tied).mean(axis=(-2, -1))


def improvement_column(baseline_mode: str = "uniform") -> str:
    """The column of :meth:`Difference.improvement_text`."""
    return f"P(adversarial > {baseline_mode}) [95% bootstrap]"


IMPROVEMENT_COLUMN = improvement_column()


def comparison_header(*leading: str, baseline_mode: str = "uniform") -> list[str]:
    """A Markdown table's header and rule lines: ``leading`` columns, then those of
    :meth:`Difference.cells` against ``baseline_mode``."""
    columns = (*leading, f"adversarial − {baseline_mode}", "95% interval (Welch)", "p (two-sided)",
               improvement_column(baseline_mode), "reading")
    return [f"| {' | '.join(columns)} |", "|" + "---|" * len(columns)]


def mode_differences(run_dirs: list[str], baseline_mode: str = "uniform") -> dict[str, list[Difference]]:
    """Per env (and variant, where runs differ in settings: "hopper, k=2") with both
    adversarial and ``baseline_mode`` runs, each adversarial curve against the baseline's curve
    of its other settings (in a sweep of l, every value against the one baseline curve that l
    does not touch): the paper's comparison (final and AUC min_u a_u), the
    average case (final mean_u a_u; not for runs with a pool) and the price of robustness
    (final clean return), adversarial − uniform. The paper's point is that the first may
    differ where the second does not: a weak spot averaged away. ``baseline_mode="worst"``:
    the paper's stochastic adversary against the deterministic one it decides against (§3)."""
    curves = curves_of(run_dirs)
    differences = {}
    for (env, mode, variant), adversarial in curves.items():
        baseline = curves.get((env, baseline_mode, adversarial[0].baseline_variant))
        if mode != "adversarial" or not baseline:
            continue
        # Both modes over the records all their runs share, so the AUCs cover the same steps.
        _, minimum = aligned(adversarial + baseline, "min_score")
        _, average = aligned(adversarial + baseline, "mean_score")
        _, clean = aligned(adversarial + baseline, "clean_score")
        metrics = [("final min_u a_u", minimum[:, -1]), ("AUC min_u a_u", minimum.mean(axis=1)),
                   ("final mean_u a_u", average[:, -1]), ("final clean return", clean[:, -1])]
        n = len(adversarial)
        differences[f"{env}, {variant}" if variant else env] = [
            Difference(name, values[:n], values[n:], baseline_mode) for name, values in metrics
            if not np.isnan(values).any()]
    return differences


def format_comparison(differences: dict[str, list[Difference]]) -> str:
    """Markdown: :func:`mode_differences`' adversarial − baseline per env and metric (Welch),
    '' without both modes."""
    if not differences:
        return ""
    lines = comparison_header("env", "metric", baseline_mode=_baseline_mode(differences))
    for env, rows in differences.items():
        for difference in rows:
            lines.append(f"| {env} | {difference.metric} | {difference.cells()} |")
    return "\n".join(lines) + "\n"


def seeds_sentence(differences: list[tuple[str, Difference]]) -> str:
    """Sentences under a comparison: for each labelled difference the seeds cannot tell from
    0, the seeds per mode that would (:meth:`Difference.seeds_needed`); for each whose seeds
    never cross, how likely that order is by chance (:meth:`Difference.chance_of_order`: a
    bootstrap interval of one value reads surer than a few seeds are); '' where there is none."""
    needed = [f"{label}: {seeds}" for label, difference in differences if (seeds := difference.seeds_needed())]
    ordered = [f"{label}: {p:.3g} ({len(difference.adversarial)} and {len(difference.baseline)} seeds)"
               for label, difference in differences if (p := difference.chance_of_order()) is not None]
    baseline_mode = differences[0][1].baseline_mode if differences else "uniform"
    return (f"Seeds per mode that would tell adversarial from {baseline_mode} apart where these cannot (80% power "
            f"at the difference and spread seen, two-sided 5% t-test): {'; '.join(needed)}.\n" if needed else "") + (
        "Where every seed of one mode ends above every seed of the other, the bootstrap interval is that one value "
        "whatever the seeds; how often chance alone orders seeds so (Mann–Whitney's exact two-sided p): "
        f"{'; '.join(ordered)}.\n" if ordered else "")


def seeds_note(differences: dict[str, list[Difference]]) -> str:
    """:func:`seeds_sentence` for :func:`format_comparison`'s rows."""
    return seeds_sentence([(f"{env} {difference.metric}", difference)
                           for env, rows in differences.items() for difference in rows])


def _baseline_mode(differences: dict[str, list[Difference]]) -> str:
    return next((row.baseline_mode for rows in differences.values() for row in rows), "uniform")


# What each baseline of the comparisons asks of the adversarial mode.
BASELINE_QUESTIONS = {
    "uniform": "",
    "worst": " (the paper's stochastic adversary against the deterministic one it decides against \"to avoid training "
             "instabilities and forgetting\", §3)",
}


def comparison_title(baseline_mode: str) -> str:
    """The heading of an adversarial − ``baseline_mode`` comparison, with what it asks
    (:data:`BASELINE_QUESTIONS`): "Adversarial − worst (the paper's stochastic adversary ...)"."""
    return f"Adversarial − {baseline_mode}{BASELINE_QUESTIONS[baseline_mode]}"


def comparison_section(differences: dict[str, list[Difference]]) -> str:
    """Markdown: the adversarial − baseline table under its heading and, where seeds cannot
    tell the modes apart, the seeds per mode that would; '' without both modes."""
    comparison = format_comparison(differences)
    if not comparison:
        return ""
    seeds = seeds_note(differences)
    return (f"{comparison_title(_baseline_mode(differences))}, per env (over the records both modes share; seeds "
            "independent, so Welch's t):\n\n" + comparison + (f"\n{seeds}" if seeds else ""))


def comparison_sections(run_dirs: list[str]) -> str:
    """Markdown: :func:`comparison_section` against each baseline mode the runs hold
    (uniform, worst), one after the other; '' where there is none."""
    sections = [comparison_section(mode_differences(run_dirs, baseline)) for baseline in BASELINE_QUESTIONS]
    return "\n".join(section for section in sections if section)


def trained_on(run_dirs: list[str]) -> str:
    """Where the runs were trained, from their ``invocations.jsonl`` (one record per command
    that trained a run): each distinct device, physics, versions and commit, with its count."""
    records = [record for path in run_dirs if os.path.exists(os.path.join(path, INVOCATIONS))
               for record in read_jsonl(os.path.join(path, INVOCATIONS), torn="drop", required=INVOCATION_KEYS)]
    if not records:
        return "Trained on: not recorded (runs written before `invocations.jsonl`)."
    setups = collections.Counter(
        f"{record['device']} × {record['devices']}, {record['physics']} physics, "
        + ", ".join(f"{name} {record['versions'][name]}" for name in ("jax", "mujoco", "mujoco-mjx", "warp-lang")
                    if name in record["versions"])
        + f", commit {record['commit'] or 'unknown'}"
        for record in records)
    return "Trained on (the runs' `invocations.jsonl`): " + "; ".join(
        f"{setup} ({count} of {len(records)} records)" for setup, count in setups.items()) + "."


CURVE_COLUMNS = ("env", "mode", "variant", "seed", "env_steps", "min_score", "mean_score", "clean_score",
                 "worst_set", "score_episodes", "pooled", "wall_seconds", "run")
SET_COLUMNS = ("env", "mode", "variant", "seed", "env_steps", "hidden", "a_u", "p_miss", "pooled", "run")


def tidy_rows(runs: list[Run]) -> tuple[list[dict], list[dict]]:
    """The runs' histories in long form: (a row per run and scoring with min_u a_u, mean_u
    a_u, the clean return, the worst set and the wall seconds of training and scoring so far
    (:attr:`Run.wall_seconds`); a row per run, scoring and candidate set with
    a_u and p_miss). A run with a pool (``pooled``) has a row per feature instead of per
    set: the lowest a_u of the pool's sets that hide it (NaN where none does) and the
    p_miss mass on them, as its heatmaps show."""
    curves, sets = [], []
    for run in runs:
        labels = {"env": run.env, "mode": run.mode, "variant": run.variant, "seed": run.seed}
        # As Python numbers: the csv module writes a NumPy float as its repr, "np.float64(...)".
        minimum, mean, clean, scores, p_miss, seconds = (values.tolist() for values in (
            run.min_score, run.mean_score, run.clean_score, run.scores, run.p_miss, run.wall_seconds))
        for t, env_steps in enumerate(run.env_steps.astype(int).tolist()):
            common = {**labels, "env_steps": env_steps}
            curves.append({**common, "min_score": minimum[t], "mean_score": mean[t], "clean_score": clean[t],
                           "worst_set": run.worst_sets[t], "score_episodes": run.score_episodes,
                           "pooled": run.pooled, "wall_seconds": seconds[t], "run": run.path})
            sets += [{**common, "hidden": name, "a_u": scores[t][i], "p_miss": p_miss[t][i],
                      "pooled": run.pooled, "run": run.path} for i, name in enumerate(run.set_names)]
    return curves, sets


def write_tables(run_dirs: list[str], out_dir: str) -> list[str]:
    """:func:`tidy_rows` of these runs (their variants named, as in the figures) as
    ``curves.csv`` and ``scores.csv`` in ``out_dir`` (made if need be); NaN is an empty cell.
    Returns the paths."""
    curves, sets = tidy_rows(load_runs(run_dirs))
    os.makedirs(out_dir, exist_ok=True)
    written = []
    for name, columns, rows in (("curves.csv", CURVE_COLUMNS, curves), ("scores.csv", SET_COLUMNS, sets)):
        path = os.path.join(out_dir, name)
        with open(path, "w", newline="") as file:
            writer = csv.DictWriter(file, columns)
            writer.writeheader()
            writer.writerows({key: "" if isinstance(value, float) and math.isnan(value) else value
                              for key, value in row.items()} for row in rows)
        written.append(path)
    return written
