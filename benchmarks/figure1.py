"""FIGURE1.md: the paper's Figure 1 question answered from the campaign's runs.

    python benchmarks/figure1.py hopper=benchmarks/results/fig1-hopper-1m \\
        walker2d=benchmarks/results/fig1-walker2d-1m ant=benchmarks/results/fig1-ant [window=0] \\
        [out=benchmarks/results/FIGURE1.md] [formats=png,pdf] [per_seed=false]

Each ``ENV=DIR`` is an experiment's folder (its ``<mode>-s<seed>/`` run directories with
``config.yaml`` and ``scores.jsonl``, as ``gpu_campaign.sh`` brings them back). Per env it
draws the figures (``plot_runs``, into a new ``DIR/figures``, with the runs' histories as tidy
tables beside them, ``curves.csv`` and ``scores.csv``; and every env's min_u a_u side by
side, as the paper lays Figure 1 out, into ``figure1.png`` beside the file), and writes: the settings the
runs used; final and AUC min_u a_u, the final mean_u a_u (the average over U) and the
final clean return per mode, mean ± 95% t-interval over seeds, and the set most often worst
at the end (``summary_table``); where runs hold an audit of their final policy
(``<run>/audit-final/audit.json``: benchmarks/README.md, Step 5), its min_u a_u and clean
return per mode beside the training's own final estimate, and adversarial − uniform on it
(in the verdict and the top table too);
adversarial − uniform on each with Welch's 95% interval and p-value, and the probability
that a seed of adversarial training ends above one of uniform (``format_comparison``), and
where mode ``worst`` ran, adversarial − worst the same way;
the verdict those numbers give, in words; mode ``none``'s clean return against the SB3
RL-Zoo SAC at 1M env steps; what the runs cost, from their ``metrics.jsonl`` (seconds per
training chunk and per scoring round), with a 1M-step run projected from it where they
stopped short; and where they were trained (device, physics, versions, commit: their
``invocations.jsonl``). Everything in the file is computed from the runs; what you suspect
or noticed goes under it by hand, in a section headed ``## Noted by hand``, which a later run
keeps at the end of the file it rewrites (as each env's runs come back, the file is written
again with every env so far, and the notes stay).
"""

from __future__ import annotations

import dataclasses
import datetime
import json
import math
import os
import sys
from typing import NamedTuple

import numpy as np

from admissable_jax.cli import fail, parse_args, run_main
from admissable_jax.config import RUN_SETTINGS
from admissable_jax.errors import INTERRUPTED, UnusableDirectory, remove_if_unused
from admissable_jax.method import set_sizes
from admissable_jax.plot import check_formats, new_folder, plot_envs_side_by_side, plot_runs
from admissable_jax.results import (
    IMPROVEMENT_COLUMN, Difference, Run, comparison_header, comparison_title, differing_settings, estimate, find_runs,
    format_comparison, load_run, mean_and_interval, mode_differences, summary_table, trained_on, write_tables,
)
from admissable_jax.run_directory import load_config_yaml
from common import benchmark_commit

# The SB3 RL-Zoo's SAC at 1M env steps (mean ± std over its evaluations; v3 envs): the
# reference the campaign issue names for our clean SAC (mode ``none``).
SB3_ZOO_SAC = {"hopper": (2326.0, 1130.0), "walker2d": (3863.0, 254.0), "ant": (4616.0, 1354.0)}
PAPER_STEPS = 1_000_000
HAND_NOTES = "## Noted by hand"  # the heading of what a person wrote under the computed part, kept on a rewrite
AUDITED_FINAL = "audit-final"  # RUN/audit-final/: the run's final policy audited afresh (benchmarks/README.md, Step 5)
SETTINGS = ("physics", "num_envs", "score_every", "score_episodes", "k", "lower_bound", "epsilon", "learning_starts",
            "batch_size", "buffer_size")


@dataclasses.dataclass
class Figure1Config:
    hopper: str = dataclasses.field(default="", metadata={"help": "Hopper-v5 experiment folder ('' = none)"})
    walker2d: str = dataclasses.field(default="", metadata={"help": "Walker2d-v5 experiment folder ('' = none)"})
    ant: str = dataclasses.field(default="", metadata={"help": "Ant-v5 experiment folder ('' = none)"})
    window: int = dataclasses.field(default=0, metadata={
        "help": "the figures' moving-average window (records); 0: the paper's 40 of 200, scaled to the runs"})
    out: str = dataclasses.field(default="benchmarks/results/FIGURE1.md", metadata={"help": "the file to write"})
    formats: str = dataclasses.field(default="png,pdf", metadata={
        "help": "figure file formats, comma separated (PNG always: the file shows the PNGs)"})
    per_seed: bool = dataclasses.field(default=False, metadata={
        "help": "the figures also draw each seed's smoothed curve, thin (as plot per_seed=true)"})


def _settings(run_dirs: list[str]) -> str:
    """The settings every run shares, and those that differ (listed per value)."""
    configs = [load_config_yaml(os.path.join(path, RUN_SETTINGS)) for path in run_dirs]
    parts = []
    for key in SETTINGS:
        values = sorted({str(config[key]) for config in configs if key in config})
        if values:
            parts.append(f"{key}={'/'.join(values)}")
    return ", ".join(parts)


def _verdict(difference: Difference) -> str:
    """One sentence: the difference, its interval and p, and what they say."""
    baseline = difference.baseline_mode
    interval = difference.interval()
    if interval is None:
        return (f"{difference.metric}: adversarial − {baseline} = {difference.mean:+.1f} (one seed in a mode: no "
                "test).")
    low, high, p = interval
    improvement = f", P(adversarial > {baseline}) = {difference.improvement_text()}"
    words = {"adversarial higher": "adversarial training is higher, and 0 lies outside the 95% interval",
             f"{baseline} higher": f"{baseline} training is higher, and 0 lies outside the 95% interval",
             }.get(difference.reading(), "the seeds cannot tell the modes apart (the 95% interval holds 0)")
    seeds = difference.seeds_needed()
    if seeds:
        words += f"; {seeds} seeds per mode would (80% power at the difference and spread seen)"
    chance = difference.chance_of_order()
    if chance is not None:
        words += (f"; every seed of one mode ends above every seed of the other, an order chance alone gives with "
                  f"p = {chance:.3g} (Mann–Whitney, exact; the bootstrap interval cannot widen past one value then)")
    return (f"{difference.metric}: adversarial − {baseline} = {difference.mean:+.1f} [{low:.1f}, {high:.1f}], "
            f"p = {p:.3g}{improvement}: {words}.")


def _clean_sac_line(env: str, all_runs: list[Run]) -> str:
    """Mode ``none``'s final clean return against the SB3 RL Zoo's SAC at 1M env steps."""
    runs = [run for run in all_runs if run.mode == "none"]
    if not runs:
        return "No mode `none` runs: no clean-SAC check."
    length = min(len(run.clean_score) for run in runs)
    finals = np.array([run.clean_score[length - 1] for run in runs])
    mean, low, high = (float(value[0]) for value in mean_and_interval(finals[:, None]))
    steps = int(runs[0].env_steps[length - 1])
    reference, spread = SB3_ZOO_SAC[env]
    ours = "our 95% interval" if len(runs) > 1 else "our one seed"
    if steps < PAPER_STEPS:
        words = f"not comparable yet (at {steps:,} env steps, not the reference's 1M)"
    elif high < reference - spread:
        words = f"clearly below SB3's ({ours} lies under its mean − 1 sd)"
    elif low > reference + spread:
        words = f"clearly above SB3's ({ours} lies over its mean + 1 sd)"
    else:
        words = f"within SB3's spread ({ours} reaches its mean ± 1 sd)"
    interval = f" [{low:.1f}, {high:.1f}]" if len(runs) > 1 else ""
    return (f"Clean SAC (mode `none`, {len(runs)} seed{'s' if len(runs) > 1 else ''}): final clean return {mean:.1f}"
            f"{interval} against the SB3 RL-Zoo SAC at 1M, {reference:,.0f} ± {spread:,.0f} (v3 envs): {words}.")


class AuditedFinal(NamedTuple):
    """What FIGURE1.md reads of an audit of a run's final policy."""

    episodes: int  # N per set
    min_score: float  # the lowest a_u of the audited sets
    clean_score: float


def _audit_of_final_policy(run: Run) -> AuditedFinal | None:
    """The audit of ``run``'s final policy, ``RUN/audit-final/audit.json`` (``audit
    policy=RUN/exported/policy-step<N>.npz``, N the env step of its last scoring); None where
    it has none, ValueError in one line where it is no audit or audits another policy (an
    earlier lease's)."""
    path = os.path.join(run.path, AUDITED_FINAL, "audit.json")
    if not os.path.isfile(path):
        return None
    try:
        with open(path) as file:
            audit = json.load(file)
        audited = os.path.basename(audit["source"].get("policy", ""))
        by_size = {int(k): [float(entry["score"]) for entry in sets] for k, sets in audit["sets"].items()}
        episodes, clean = int(audit["n_episodes"]), float(audit["clean_score"])
    except (ValueError, KeyError, TypeError, AttributeError) as error:
        raise ValueError(f"{path} is no audit's audit.json ({type(error).__name__}: {error})") from None
    final = f"policy-step{int(run.env_steps[-1])}.npz"
    if audited != final:
        raise ValueError(f"{path} audits {audited or 'no exported policy'}, not the run's final {final}: audit that "
                         f"into {AUDITED_FINAL}/ (benchmarks/README.md, Step 5)")
    config = load_config_yaml(os.path.join(run.path, RUN_SETTINGS))
    sizes = set_sizes(int(config.k), bool(config.get("up_to_k", False)))  # U's, whose minimum training scores
    if not all(by_size.get(size) for size in sizes):
        scored = sorted(size for size, scores in by_size.items() if scores)
        raise ValueError(f"{path} audits sets of size {', '.join(map(str, scored))}, not every size of the "
                         f"run's U ({', '.join(map(str, sizes))}): audit it with its default k")
    return AuditedFinal(episodes, min(min(by_size[size]) for size in sizes), clean)


def _audited_finals(runs: list[Run]) -> tuple[list[str], Difference | None]:
    """Markdown lines: the final policies audited afresh in Gymnasium's own env, per mode
    (mean ± 95% t-interval over the audited seeds) beside the training's own final estimate
    of the same runs, and adversarial − uniform on the audited min_u a_u, which is also
    returned (for the verdict and the top table; None without both modes); no lines where no
    run has an audit of its final policy."""
    audited = [(run, audit) for run in runs if (audit := _audit_of_final_policy(run)) is not None]
    if not audited:
        return [], None
    episodes = " or ".join(map(str, sorted({audit.episodes for _, audit in audited})))
    trained_episodes = " or ".join(map(str, sorted({run.score_episodes for run, _ in audited})))
    lines = [f"**The final policies, audited afresh** ({len(audited)} of {len(runs)} runs, `<run>/{AUDITED_FINAL}/`: "
             f"Gymnasium's own C-MuJoCo env, new start states, {episodes} episodes per set, against the training's "
             f"last scoring of {trained_episodes}; each a minimum over sets of noisy estimates, which tends to read "
             "low, the less so the more episodes):", "",
             "| mode | runs | audited final min_u a_u | training's final min_u a_u | audited clean return |",
             "|---|---|---|---|---|"]
    minimum = {}
    for mode in dict.fromkeys(run.mode for run, _ in audited):
        of_mode = [(run, audit) for run, audit in audited if run.mode == mode]
        minimum[mode] = np.array([audit.min_score for _, audit in of_mode])
        trained = np.array([run.min_score[-1] for run, _ in of_mode])
        clean = np.array([audit.clean_score for _, audit in of_mode])
        lines.append(f"| {mode} | {len(of_mode)} | {estimate(minimum[mode])} | {estimate(trained)} | "
                     f"{estimate(clean)} |")
    difference = None
    if {"adversarial", "uniform"} <= minimum.keys():
        difference = Difference("audited final min_u a_u", minimum["adversarial"], minimum["uniform"])
        lines += ["", *comparison_header("metric"), f"| {difference.metric} | {difference.cells()} |"]
    return lines + [""], difference


def _cost_line(run_dirs: list[str]) -> str:
    """What the runs cost, measured: their program's seconds per training chunk and per
    scoring round (``metrics.jsonl``; the runs of one experiment share one program, so one
    run's rows hold its times), and a 1M-step run projected from them: the remaining
    scorings at the median chunk and the last ten rounds' mean (late rounds run longest)."""
    measured = [path for path in run_dirs if os.path.exists(os.path.join(path, "metrics.jsonl"))]
    if not measured:
        return "Cost: not measured (no `metrics.jsonl`)."
    with open(os.path.join(measured[0], "metrics.jsonl")) as file:
        rows = [json.loads(line) for line in file if line.strip()]
    score_every = int(load_config_yaml(os.path.join(measured[0], RUN_SETTINGS))["score_every"])
    chunks = [score_every / row["env_steps_per_s"] for row in rows]
    rounds = [row["score_seconds"] for row in rows]
    late = rounds[-10:]
    total, chunk = sum(chunks) + sum(rounds), float(np.median(chunks))
    line = (f"Cost (measured, the program of {rows[-1].get('runs_in_program', 1)} runs, compiling not counted): "
            f"{len(rows)} scorings in {total:,.0f} s; a training chunk of {score_every:,} env steps per run "
            f"{chunk:.2f} s (median), a scoring round {np.mean(rounds):.2f} s on average, {np.mean(late):.2f} s over "
            f"the last {len(late)}.")
    remaining = math.ceil(max(0, PAPER_STEPS - rows[-1]["env_steps"]) / score_every)
    if remaining:
        projected = total + remaining * (chunk + float(np.mean(late)))
        line += (f" 1M env steps projected at {projected:,.0f} s ({projected / 60:.1f} min): the remaining "
                 f"{remaining} scorings at the median chunk and the last {len(late)} rounds' mean.")
    return line


def env_section(env: str, folder: str, window: int, out_file: str, formats: tuple[str, ...] = ("png", "pdf"),
                per_seed: bool = False, made: list[str] | None = None) -> tuple[str, list[str]]:
    """(the env's Markdown section, one summary row per Difference for the top table). The
    figures folder it makes is appended to ``made`` first, so that a caller stopped midway
    knows it."""
    run_dirs = find_runs([folder])
    runs = [load_run(path) for path in run_dirs]
    others = sorted({run.env for run in runs} - {env})
    if others:
        raise ValueError(f"{env}={folder} holds runs of {', '.join(others)}")
    differing = differing_settings(runs)
    if differing:
        raise ValueError(f"the runs in {folder} differ in {', '.join(differing)}: Figure 1 compares the modes at one "
                         "setting per env (plot draws each setting as its own curve)")
    steps = min(int(run.env_steps[-1]) for run in runs)
    audited, audited_difference = _audited_finals(runs)  # before anything is drawn: a bad audit stops here
    figures = new_folder(os.path.join(folder, "figures"))
    if made is not None:
        made.append(figures)
    plot_runs(run_dirs, figures, window, formats, per_seed)
    curves_csv, scores_csv = (os.path.relpath(path, os.path.dirname(os.path.abspath(out_file)))
                              for path in write_tables(run_dirs, figures))
    compared, against_worst = mode_differences(run_dirs), mode_differences(run_dirs, "worst")
    differences, worst_differences = compared.get(env, []), against_worst.get(env, [])
    audited_differences = [] if audited_difference is None else [audited_difference]
    partial = "" if steps >= PAPER_STEPS else ", not the paper's 1M"
    figure, by_time = (os.path.relpath(os.path.join(figures, name), os.path.dirname(os.path.abspath(out_file)))
                       for name in ("min_score.png", "min_score_by_time.png"))
    lines = [
        f"## {env}", "",
        f"Runs: `{folder}` ({len(run_dirs)} runs, {steps:,} env steps each{partial}). "
        f"Settings: {_settings(run_dirs)}.", "",
        summary_table(run_dirs), format_comparison(compared) or "Not both adversarial and uniform runs: no comparison.\n",
        *([f"{comparison_title('worst')}:", "", format_comparison(against_worst)]
          if worst_differences else []),
        "**Verdict (computed):**", "",
        *(f"- {_verdict(difference)}" for difference in differences + audited_differences + worst_differences),
        f"- {_clean_sac_line(env, runs)}", "",
        *audited,
        _cost_line(run_dirs), "",
        *([f"![min_u a_u against the wall time of training and scoring]({by_time})", ""]
          if os.path.exists(os.path.join(figures, "min_score_by_time.png")) else []),
        trained_on(run_dirs), "",
        f"![min_u a_u, mean_u a_u and clean return]({figure})", "",
        f"Every scoring of every run, as tidy tables for one's own analysis: `{curves_csv}` (a row per run and "
        f"scoring) and `{scores_csv}` (a row per run, scoring and hidden set).", "",
    ]
    rows = [f"| {env} | {steps:,} | {d.metric} | {d.mean:+.1f} | {d.improvement_text()} | {d.reading()} |"
            for d in differences[:2] + audited_differences]
    return "\n".join(lines), rows


def notes_by_hand(path: str) -> str:
    """The section headed :data:`HAND_NOTES` to the end of the file at ``path`` ('' without one)."""
    if not os.path.isfile(path):
        return ""
    with open(path) as file:
        text = file.read()
    start = text.find(f"\n{HAND_NOTES}")
    return text[start + 1:] if start >= 0 else ""


def main(argv: list[str]) -> int:
    config = parse_args(Figure1Config, argv, "benchmarks/figure1.py ENV=DIR ...", __doc__.splitlines()[0])
    folders = {env: getattr(config, env) for env in SB3_ZOO_SAC if getattr(config, env)}
    if not folders:
        fail("give at least one of hopper=DIR, walker2d=DIR, ant=DIR")
    commit = benchmark_commit()  # before anything is drawn: the code that computes this file
    sections, rows, made = [], [], []
    out_folder = os.path.dirname(os.path.abspath(config.out))
    try:
        formats = check_formats(f"png,{config.formats}")
        for env, folder in folders.items():
            section, env_rows = env_section(env, folder, config.window, config.out, formats, config.per_seed, made)
            sections.append(section)
            rows += env_rows
        # The paper's layout, beside FIGURE1.md: every env's min_u a_u in a panel of its own.
        plot_envs_side_by_side([path for folder in folders.values() for path in find_runs([folder])], out_folder,
                               config.window, formats, config.per_seed)
    except (ValueError, FileNotFoundError, KeyError, UnusableDirectory) as error:
        fail(str(error))
    except KeyboardInterrupt:  # as plot: one line, and no figures folder left empty
        for figures in made:
            remove_if_unused(figures, own_files=())
        drawn = [figures for figures in made if os.path.isdir(figures)]
        where = f"the figures drawn so far are in {', '.join(drawn)}" if drawn else "no figures written"
        print(f"interrupted: {config.out} not written; {where}; the runs are untouched", file=sys.stderr)
        return INTERRUPTED
    command = " ".join(["python", "benchmarks/figure1.py", *argv])
    text = "\n".join([
        "# Figure 1: adversarial against uniform missingness (min_u a_u)", "",
        f"Written by `{command}` on {datetime.date.today()} at commit {commit}, from the runs' `scores.jsonl` "
        "and `config.yaml`. Final: the last scoring; AUC: the mean of min_u a_u over all scorings; ± and [ ]: 95% "
        "t-intervals over seeds; adversarial − uniform by Welch's t (seeds independent across modes); "
        "P(adversarial > uniform): the chance that a seed of adversarial training ends above one of uniform "
        "training (ties half; Agarwal et al. 2021's probability of improvement), with a 95% bootstrap interval "
        "over the seeds.", "",
        f"| env | env steps | metric | adversarial − uniform | {IMPROVEMENT_COLUMN} | reading |",
        "|---|---|---|---|---|---|", *rows, "",
        "![every env's min_u a_u, as the paper's Figure 1 lays it out](figure1.png)", "",
        *sections,
    ])
    notes = notes_by_hand(config.out)
    with open(config.out, "w") as file:
        file.write(text.rstrip("\n") + f"\n\n{notes}" if notes else text)
    print(text)
    print(f"written: {config.out}" + (f" (its section '{HAND_NOTES}' kept at the end)" if notes else ""))
    return 0


if __name__ == "__main__":
    run_main(main)
