"""What an audit writes: one policy's ``report.md``, ``audit.json`` and figures
(:func:`write_audit`); an experiment's modes side by side (:func:`compare_modes`,
:func:`comparison_chart`); one policy's robustness by checkpoint or by when
its sensors fail (:func:`robustness_table`, :func:`robustness_chart`)."""

from __future__ import annotations

import dataclasses
import json
import math
import os
from typing import Any, Callable, Mapping, NamedTuple

import numpy as np

from admissable_jax.audit.sets import AuditResult, drop_below_clean
from admissable_jax.config import curve_mode, curve_names
from admissable_jax.results import BASELINE_QUESTIONS, Difference, comparison_header, comparison_title, estimate, \
    mean_and_interval, seeds_sentence
from admissable_jax.scoring.attribution import ShapleyAttribution

# What an audited run's source says of its training with sensors failing mid-episode, per
# setting: training's episodes (``fail_at``) and the scoring rounds that set its p_miss.
TRAINING_FAILURES = {"fail_at": "trained with sensors failing at env step",
                     "score_fail_at": "scored in training with sensors failing at env step"}


def training_failure_source(settings: Mapping[str, Any]) -> dict[str, str]:
    """The source entries of a run whose sensors failed mid-episode in training or in its
    scoring rounds, from its settings (its config's fields, or an exported policy's source,
    which holds those that are not 0): the steps, under :data:`TRAINING_FAILURES`' words;
    none for the paper's u, hidden from the start in both."""
    return {words: settings[name] for name, words in TRAINING_FAILURES.items() if settings.get(name, "0") != "0"}


def training_failures_sentence(results: list[AuditResult]) -> str:
    """A comparison's word on how its pairs met failing sensors in training, where they all
    met them alike (an experiment's pairs share their settings); "" for the paper's, and for
    runs that differ in it (their curves name the settings: :func:`pair_curves`)."""
    met = {tuple(result.source.get(words) for words in TRAINING_FAILURES.values()) for result in results}
    if len(met) != 1:
        return ""
    (steps,) = met
    said = [f"{words} {step} (`{name}`)" for (name, words), step in zip(TRAINING_FAILURES.items(), steps) if step]
    return f" The pairs were {' and '.join(said)}." if said else ""



def write_audit(result: AuditResult, out: str, top: int = 10) -> list[str]:
    """report.md, audit.json and the figures into ``out``; returns the paths written."""
    os.makedirs(out, exist_ok=True)
    written = [os.path.join(out, "audit.json"), os.path.join(out, "report.md")]
    record = dataclasses.asdict(result)
    record["gaps_to_worst"] = {k: {"paired": result.same_starts, "episodes_to_separate": result.episodes_to_separate(k),
                                   "gaps": [{"hidden": list(gap.entry.hidden), "gap": gap.gap, "ci95": gap.ci95,
                                             "tied": gap.tied} for gap in result.gaps_to_worst(k)[1:]]}
                               for k in result.sets}
    with open(written[0], "w") as file:
        json.dump(record, file, indent=1)
    if 1 in result.sets:
        written.append(_bar_chart(result, os.path.join(out, "scores_k1.png")))
    if 2 in result.sets and 2 not in result.search:  # a search scores too few pairs for a map
        written.append(_pair_heatmap(result, os.path.join(out, "pairs_k2.png")))
    if result.shapley is not None:
        written.append(_shapley_chart(result, os.path.join(out, "shapley.png")))
    if len(result.sets) > 1:
        written.append(_by_size_chart(result, os.path.join(out, "worst_by_k.png")))
    with open(written[1], "w") as file:
        file.write(_report(result, top, [os.path.basename(path) for path in written[2:]]))
    return written


def _report(result: AuditResult, top: int, figures: list[str]) -> str:
    source = ", ".join(f"{key} {value}" for key, value in result.source.items())
    episodes = ("deterministic episodes from the same N start states" if result.same_starts else
                "episodes of the policy as given, each set's from the vector env's own resets")
    measure = ("the mean undiscounted return of" if result.estimator == "rollout" else
               f"the `{result.estimator}` estimate (the critic's discounted value; admissable_jax.scoring) over")
    lines = [
        f"# Robustness audit: {result.env}", "",
        f"{source}. Every set u of the sizes below was hidden (hidden features read 0, with the 0/1 indicator of "
        f"the paper's masked observation) {hidden_when(result)}; a_u is {measure} "
        f"N = {result.n_episodes} {episodes}, ± the 95% confidence "
        f"interval (Student's t); the drop is relative to the clean case.", "",
        f"**Clean return (nothing hidden): {result.clean_score:.1f} ± {result.clean_ci95:.1f}**", "",
    ]
    if result.fail_at:
        lines += [_failure_sentence(result), ""]
    if result.pilot is not None:
        lines += [_pilot_sentence(result.pilot), ""]
    for k, entries in result.sets.items():
        worst = result.worst(k, top)
        searched = result.search.get(k)
        if searched:
            lines += [f"## k = {k}: the {len(worst)} worst found by beam search", "",
                      f"Beam search of width {searched['beam_width']} ranked {searched['sets_ranked']:,} candidate sets "
                      f"(of all {searched['sets_in_all']:,}) by `{searched['ranker']}`; its {len(entries)} finalists "
                      f"are scored here as every set above. A search may miss the worst set: "
                      f"`search=exact` scores them all.", ""]
        else:
            lines += [f"## k = {k}: the {len(worst)} worst of {len(entries)} sets", "",
                      f"Mean over all {len(entries)} sets (the average case, u drawn uniformly): "
                      f"{result.mean(k):.1f}, {drop_below_clean(result.clean_score, result.mean(k)):.1f}% below clean; "
                      f"the worst: {worst[0].score:.1f}.", ""]
        lines += ["| rank | hidden features | indices | a_u ± 95% CI | drop | above the worst ± 95% CI |",
                  "|---|---|---|---|---|---|"]
        for rank, gap in enumerate(result.gaps_to_worst(k)[:top], 1):
            entry = gap.entry
            lines.append(f"| {rank} | {', '.join(entry.names)} | {', '.join(map(str, entry.hidden))} | "
                         f"{entry.score:.1f} ± {entry.ci95:.1f} | {entry.drop_percent:.1f}% | "
                         f"{'—' if rank == 1 else f'+{_small(gap.gap)} ± {_small(gap.ci95)}'} |")
        lines += ["", _worst_told_apart(result, k), ""]
    if result.shapley is not None:
        lines += _shapley_section(result, result.shapley)
    if result.dropout is not None:
        lines += _dropout_section(result)
    lines += [f"![{name}]({name})" for name in figures]
    lines += ["", "Every number, with each episode's return: `audit.json`."]
    return "\n".join(lines) + "\n"


def hidden_when(result: AuditResult) -> str:
    """When the audit's sets were hidden, in words: for whole episodes (the paper's a_u), or
    from the env step at which their sensors failed (``fail_at``)."""
    return ("for whole episodes" if not result.fail_at else
            f"from env step {result.fail_at} of each episode on, every feature seen before it (a sensor that fails "
            f"mid-episode, `fail_at`; the paper's a_u hides u from the start)")


def _failure_sentence(result: AuditResult) -> str:
    """How many episodes ended before the sensors failed, where they fail mid-episode."""
    ended, total = result.ended_before_failing, len(result.clean_lengths)
    shortest, longest = min(result.clean_lengths), max(result.clean_lengths)
    span = f"the clean episodes last {shortest}{f'–{longest}' if longest > shortest else ''} env steps"
    if not ended:
        return f"The sensors fail at env step {result.fail_at}, and every clean episode ran past it ({span})."
    if not result.same_starts:
        return (f"The sensors fail at env step {result.fail_at}; {ended} of the {total} clean episodes had ended by "
                f"then ({span}). The sets' episodes start elsewhere, so this is a guide only.")
    return (f"The sensors fail at env step {result.fail_at}; {ended} of the {total} clean episodes had ended by then "
            f"({span}). Each set's episode from the same start took the clean one's course, so no sensor failed in "
            f"those" + (": every a_u equals the clean return; give a smaller `fail_at`." if ended == total else "."))


def audit_settings(results: list[AuditResult]) -> str:
    """How several audits (an experiment's pairs, a run's checkpoints) were made, in a few
    words: N, the estimator and, where the sensors failed mid-episode, when."""
    first, times = results[0], {result.fail_at for result in results}
    failing = f", sensors failing at env step {first.fail_at}" if times != {0} and len(times) == 1 else ""
    return f"{episodes_per_set(results)}, `{first.estimator}`{failing}"


def _small(value: float) -> str:
    """One decimal, or two significant digits where one decimal would read 0.0 (a gap of
    0.004 ± 0.001 is told apart; "0.0 ± 0.0" would not say so)."""
    return f"{value:.1f}" if value == 0 or abs(value) >= 0.05 else f"{value:.2g}"


def _pilot_sentence(pilot: dict[str, Any]) -> str:
    """How ``tell_apart`` chose N, in words."""
    needed = ", ".join(f"k = {k}: {'—' if n is None else f'{n:,}'}" for k, n in pilot["needed"].items())
    largest = max([n for n in pilot["needed"].values() if n is not None], default=0)
    capped = (f" The largest, {largest:,}, is more than one audit here takes: capped at {pilot['chosen']:,}."
              if largest > pilot["chosen"] else "")
    return (f"N = {pilot['chosen']:,} was chosen by a pilot audit of {pilot['episodes']} episodes per set (the start "
            f"states of seed {pilot['seed']}; these are seed {pilot['seed'] + 1}'s): about this many episodes per set "
            f"would tell the worst set of each size from the runner-up ({needed}; —: the two did not differ), and "
            f"no fewer than the pilot's.{capped}")


def _worst_told_apart(result: AuditResult, k: int) -> str:
    """In words: is the worst set of size k told apart from the others, and if not, about
    how many episodes would tell it from the runner-up."""
    gaps = result.gaps_to_worst(k)
    if len(gaps) < 2:
        return "One set of this size: nothing to tell the worst apart from."
    how = ("paired episode by episode, as every set's episode i starts from one state" if result.same_starts
           else "Welch's t, as the sets' episodes start from different states")
    tied = [gap for gap in gaps[1:] if gap.tied]
    if not tied:
        return (f"The worst is told apart from every other set: the runner-up, {', '.join(gaps[1].entry.names)}, lies "
                f"{_small(gaps[1].gap)} ± {_small(gaps[1].ci95)} above it (the gap's 95% interval, {how}).")
    named = ", ".join("{" + ", ".join(gap.entry.names) + "}" for gap in tied[:5]) + (", ..." if len(tied) > 5 else "")
    needed = result.episodes_to_separate(k)
    more = ("the runner-up's returns equal the worst's episode by episode" if needed is None else
            f"about {needed:,} episodes per set would tell the worst from the runner-up at the gap and spread "
            f"seen (80% power; `episodes=`)")
    return (f"Not told apart from the worst (the gap's 95% interval holds 0; {how}; each set compared alone): "
            f"{len(tied)} of the other {len(gaps) - 1} sets ({named}). {more[0].upper()}{more[1:]}.")


def shapley_order(attribution: ShapleyAttribution) -> list[int]:
    """Features by Shapley value, largest first."""
    return sorted(range(len(attribution.values)), key=lambda i: -attribution.values[i])


def _shapley_section(result: AuditResult, attribution: ShapleyAttribution) -> list[str]:
    """The report's table of every feature's Shapley value beside the loss of hiding it alone."""
    worth = attribution.full - attribution.blind
    how = (f"Exact: all {attribution.coalitions:,} coalitions valued" if attribution.method == "exact" else
           f"Estimated from M = {attribution.orders} random orders of the features in antithetic pairs "
           f"({attribution.coalitions:,} coalitions valued)")
    interval_orders = "" if attribution.method == "exact" else ", combined with that over the orders' pairs"
    value = "the mean return" if result.estimator == "rollout" else f"the `{result.estimator}` estimate"
    lines = ["## What each feature is worth: Shapley values", "",
             f"A coalition S of visible features is worth v(S), {value} with every other feature hidden. Feature i's "
             f"Shapley value φ_i is its share of what seeing everything is worth: v(all) = {attribution.full:.1f}, "
             f"v(none) = {attribution.blind:.1f}, and the φ_i sum to v(all) − v(none) = {worth:.1f}. Beside it, the "
             f"loss of hiding it alone (clean − a_i), which is all an adversary of k = 1 sees. A feature whose φ_i "
             f"is well above its loss alone carries what other features carry too: hidden alone it costs little, "
             f"hidden with them it costs much. {how}; ± the 95% interval over the N = {result.n_episodes} start "
             f"states (Student's t){interval_orders}. Method: admissable_jax.scoring.attribution.", "",
             "| rank | feature | index | φ_i ± 95% CI | share of v(all) − v(none) | loss hidden alone |",
             "|---|---|---|---|---|---|"]
    for rank, i in enumerate(shapley_order(attribution), 1):
        share = 100 * attribution.values[i] / worth if worth else float("nan")
        lines.append(f"| {rank} | {result.feature_names[i]} | {i} | {attribution.values[i]:.1f} ± "
                     f"{attribution.ci95[i]:.1f} | {share:.1f}% | {attribution.leave_one_out[i]:.1f} |")
    return lines + [""]


def dropout_line(result: AuditResult) -> str:
    """The expected return under random sensor failure at each rate asked, in one line."""
    return "random failure: " + "; ".join(
        f"p = {entry.rate:g}: {entry.score:.1f} ± {entry.ci95:.1f} ({drop_below_clean(result.clean_score, entry.score):.1f}% "
        f"below clean)" for entry in result.dropout)


def _dropout_section(result: AuditResult) -> list[str]:
    """The report's table of the expected return under random sensor failure, per rate."""
    first = result.dropout[0]
    value = "return" if result.estimator == "rollout" else f"`{result.estimator}` estimate"
    lines = ["## Random sensor failure", "",
             f"Each feature failed (read 0, flagged) with probability p, independently of the others, "
             f"{hidden_when(result)}. R(p) is the expected {value} then, from M = {first.masks} masks drawn per rate, "
             f"each valued as a set is (N = {result.n_episodes} episodes), ± the 95% interval over the masks "
             f"(Student's t). The "
             f"worst sets above are what an adversary makes of as many losses. Method: "
             f"admissable_jax.scoring.dropout.", "",
             "| failure rate p | features lost per episode (mean) | R(p) ± 95% CI | drop |", "|---|---|---|---|"]
    for entry in result.dropout:
        lines.append(f"| {entry.rate:g} | {entry.mean_hidden:.1f} | {entry.score:.1f} ± {entry.ci95:.1f} | "
                     f"{drop_below_clean(result.clean_score, entry.score):.1f}% |")
    return lines + [""]


def _figure(*args: Any, **kwargs: Any) -> tuple[Any, Any]:
    """``pyplot.subplots(...)`` on matplotlib's Agg backend (audits run on machines without a
    display), imported when a chart is drawn, not when the report module is."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt.subplots(*args, **kwargs)


def _saved(figure: Any, path: str) -> str:
    """``figure`` written to ``path`` (a PNG of 120 dpi), then closed: pyplot keeps every open figure."""
    import matplotlib.pyplot as plt

    figure.savefig(path, dpi=120, bbox_inches="tight")
    plt.close(figure)
    return path


def _shapley_chart(result: AuditResult, path: str, most: int = 30) -> str:
    """Horizontal bars of φ_i (95% CI), largest first, the loss of hiding each alone beside them."""
    attribution = result.shapley
    shown = shapley_order(attribution)[:most]
    figure, ax = _figure(figsize=(7, max(3, 0.3 * len(shown) + 1)))
    rows = np.arange(len(shown))
    ax.barh(rows, [attribution.values[i] for i in shown], xerr=attribution.ci95[shown], capsize=2,
            color="tab:blue", label="Shapley value φ_i (95% CI)")
    ax.scatter([attribution.leave_one_out[i] for i in shown], rows, marker="D", color="tab:red", zorder=3,
               label="loss when hidden alone (clean − $a_i$)")
    ax.axvline(0, color="black", linewidth=0.8)
    ax.set_yticks(rows, [result.feature_names[i] for i in shown], fontsize=7)
    ax.invert_yaxis()
    measure = "return" if result.estimator == "rollout" else f"{result.estimator} estimate"
    ax.set_xlabel(f"{measure}; the φ_i sum to v(all) − v(none) = {attribution.full - attribution.blind:.0f}")
    d = len(attribution.values)
    largest = f"the {len(shown)} largest of {d}" if len(shown) < d else "every feature"
    ax.set_title(f"{result.env}: what each feature is worth ({largest}; {attribution.method})", fontsize=9)
    ax.legend(fontsize=7)
    return _saved(figure, path)


def _bar_chart(result: AuditResult, path: str) -> str:
    entries = result.sets[1]
    worst = min(range(len(entries)), key=lambda i: entries[i].score)
    figure, ax = _figure(figsize=(max(6, 0.35 * len(entries)), 4))
    ax.bar(range(len(entries)), [e.score for e in entries], yerr=[e.ci95 for e in entries], capsize=2,
           color=["tab:red" if i == worst else "tab:blue" for i in range(len(entries))])
    ax.axhline(result.clean_score, color="black", linestyle="--", label=f"nothing hidden ({result.clean_score:.0f})")
    ax.axhline(result.mean(1), color="gray", linestyle=":", label=f"mean over the {len(entries)} sets ({result.mean(1):.0f})")
    ax.set_xticks(range(len(entries)), [", ".join(e.names) for e in entries], rotation=60, ha="right", fontsize=7)
    ax.set_ylabel(f"$a_u$: mean return of {result.n_episodes} episodes (95% CI)")
    ax.set_title(f"{result.env}: return with one feature hidden (worst in red)")
    ax.legend()
    return _saved(figure, path)


def _by_size_chart(result: AuditResult, path: str) -> str:
    """The return against how many features are hidden: the clean case at 0, then per audited
    k the worst a_u (its 95% interval, its set named) and the mean a_u over the sets (where
    every set was scored): how fast the policy falls as more sensors go."""
    ks = sorted(result.sets)
    worst = [result.worst(k, 1)[0] for k in ks]
    figure, ax = _figure(figsize=(max(5, 1.2 * len(ks) + 3), 4))
    ax.errorbar([0, *ks], [result.clean_score, *(entry.score for entry in worst)],
                yerr=[result.clean_ci95, *(entry.ci95 for entry in worst)], color="tab:red", marker="o", capsize=3,
                label="worst $a_u$ (95% CI)")
    for k, entry in zip(ks, worst):
        ax.annotate(", ".join(entry.names), (k, entry.score), textcoords="offset points", xytext=(6, -10), fontsize=7)
    exhaustive = [k for k in ks if k not in result.search]
    ax.plot([0, *exhaustive], [result.clean_score, *(result.mean(k) for k in exhaustive)], color="gray",
            linestyle=":", marker=".", label="mean $a_u$ over the sets (u drawn uniformly)")
    ax.set_xticks([0, *ks], ["0\n(clean)", *map(str, ks)])
    ax.set_xlim(-0.3, ks[-1] + 0.9)  # room for the last set's names
    ax.set_xlabel("features hidden, k")
    ax.set_ylabel(f"return ({result.n_episodes} episodes per set)")
    ax.set_title(f"{result.env}: the return as more features are hidden", fontsize=10)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8)
    return _saved(figure, path)


def _pair_heatmap(result: AuditResult, path: str) -> str:
    d = len(result.feature_names)
    grid = np.full((d, d), np.nan)
    for entry in result.sets[2]:
        i, j = entry.hidden
        grid[i, j] = grid[j, i] = entry.score
    for entry in result.sets.get(1, []):  # the diagonal: the feature alone, where audited
        grid[entry.hidden[0], entry.hidden[0]] = entry.score
    size = max(5, 0.3 * d)
    figure, ax = _figure(figsize=(size + 1.5, size))
    image = ax.imshow(grid, cmap="viridis")
    figure.colorbar(image, ax=ax, label="$a_{ij}$: mean return with features i and j hidden")
    labels = result.feature_names if d <= 40 else [str(i) for i in range(d)]
    ax.set_xticks(range(d), labels, rotation=90, fontsize=6)
    ax.set_yticks(range(d), labels, fontsize=6)
    ax.set_title(f"{result.env}: pairs hidden (diagonal: one feature, where audited)")
    return _saved(figure, path)


class RobustnessAxis(NamedTuple):
    """What differs between several audits of one policy that a table and a chart set side by
    side: a run's checkpoints (:data:`OVER_TRAINING`), or when the sensors fail
    (:data:`BY_FAILURE_TIME`)."""

    title: str  # the table's heading and the chart's title
    each: str  # what one audit is, as "each ... audited as its folder's report says"
    column: str  # the table's first column
    label: str  # the chart's x axis
    of: Callable[[AuditResult], int]  # the x value
    cell: Callable[[AuditResult], str]  # the first column's cell
    audited: Callable[[AuditResult], str]  # what was audited, for the heading


OVER_TRAINING = RobustnessAxis(
    "Robustness over training", "checkpoint", "env step", "checkpoint (env steps)",
    lambda result: result.source["checkpoint (env step)"], lambda result: str(result.source["checkpoint (env step)"]),
    lambda result: result.source["run"])
BY_FAILURE_TIME = RobustnessAxis(
    "Robustness by when the sensors fail", "failure time", "sensors fail at env step (clean episodes ended by then)",
    "env step at which the sensors fail (0: from the start, the paper's a_u)", lambda result: result.fail_at,
    lambda result: f"{result.fail_at} ({result.ended_before_failing} of {len(result.clean_lengths)})",
    lambda result: ", ".join(f"{key} {value}" for key, value in result.source.items()))


def robustness_table(results: list[AuditResult], axis: RobustnessAxis = OVER_TRAINING) -> str:
    """Markdown: a row per audit (a checkpoint, a failure time: ``axis``); per k the worst a_u
    (its set) and the mean a_u over the sets; with ``shapley=``, the feature worth most then
    and its φ; with ``dropout=``, R(p) per rate."""
    first = results[0]
    ks = list(first.sets)
    attributed = all(result.shapley is not None for result in results)
    rates = [entry.rate for entry in first.dropout] if all(result.dropout is not None for result in results) else []
    lines = [f"# {axis.title}: {first.env}, {axis.audited(first)}", "",
             f"Each {axis.each} audited as its folder's report says ({audit_settings(results)}): per k, the worst a_u "
             "± its 95% interval with its set, and the mean a_u over the "
             "sets (the average case; none for a searched k)" + ("; and the feature worth most, its Shapley value "
                                                                "φ_i of v(all) − v(none)" if attributed else "") + ".", "",
             f"| {axis.column} | clean return | " + " | ".join(f"k={k}: worst a_u (set) | k={k}: mean a_u" for k in ks)
             + (" | worth most: φ_i of v(all) − v(none)" if attributed else "")
             + "".join(f" | R({rate:g}): random failure" for rate in rates) + " |",
             "|---|---|" + "---|---|" * len(ks) + ("---|" if attributed else "") + "---|" * len(rates)]
    for result in results:
        cells = []
        for k in ks:
            (worst,) = result.worst(k, 1)
            mean = result.mean(k)
            cells += [f"{worst.score:.1f} ± {worst.ci95:.1f} ({', '.join(worst.names)})",
                      "—" if math.isnan(mean) else f"{mean:.1f}"]
        if attributed:
            attribution, top = result.shapley, shapley_order(result.shapley)[0]
            cells.append(f"{result.feature_names[top]}: {attribution.values[top]:.1f} ± {attribution.ci95[top]:.1f} "
                         f"of {attribution.full - attribution.blind:.1f}")
        if rates:
            cells += [f"{entry.score:.1f} ± {entry.ci95:.1f}" for entry in result.dropout]
        lines.append(f"| {axis.cell(result)} | {result.clean_score:.1f} ± {result.clean_ci95:.1f} | "
                     + " | ".join(cells) + " |")
    return "\n".join(lines) + "\n"


def robustness_chart(results: list[AuditResult], path: str, axis: RobustnessAxis = OVER_TRAINING) -> str:
    """Per k: the worst a_u (solid, with its 95% interval) and the mean a_u (dashed) by
    ``axis`` (checkpoint, failure time); the clean return in black; with ``dropout=``, R(p) per
    rate in greys. By failure time, beside it, each single feature's a_u at each time, where
    the audit scored them all: which sensor hurts when."""
    xs = [axis.of(result) for result in results]
    singles = axis is BY_FAILURE_TIME and 1 in results[0].sets and 1 not in results[0].search
    figure, axes = _figure(1, 2 if singles else 1, figsize=(15 if singles else 8, 4.5), squeeze=False)
    ax = axes[0, 0]
    ax.plot(xs, [result.clean_score for result in results], "k--", marker="o", label="nothing hidden")
    for index, k in enumerate(results[0].sets):
        color = f"C{index}"
        worst = [result.worst(k, 1)[0] for result in results]
        ax.errorbar(xs, [entry.score for entry in worst], yerr=[entry.ci95 for entry in worst], color=color,
                    marker="o", capsize=3, label=f"k = {k}: worst $a_u$")
        means = [result.mean(k) for result in results]
        if not any(math.isnan(mean) for mean in means):
            ax.plot(xs, means, color=color, linestyle=":", marker=".", label=f"k = {k}: mean $a_u$ over the sets")
    if all(result.dropout is not None for result in results):
        for index, rate in enumerate(entry.rate for entry in results[0].dropout):
            failing = [result.dropout[index] for result in results]
            ax.errorbar(xs, [entry.score for entry in failing], yerr=[entry.ci95 for entry in failing], capsize=2,
                        color=str(0.25 + 0.5 * index / max(1, len(results[0].dropout) - 1)), linestyle="-.",
                        marker="s", markersize=3, label=f"random failure, p = {rate:g}: R(p)")
    from admissable_jax.plot import env_steps_axis

    env_steps_axis(ax, axis.label)
    ax.set_ylabel(f"return ({results[0].n_episodes} episodes per set)")
    ax.set_title(f"{results[0].env}: {axis.title.lower()}", fontsize=10)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8)
    if singles:
        _single_features_by_time(axes[0, 1], results, xs)
    os.makedirs(os.path.dirname(path), exist_ok=True)
    return _saved(figure, path)


def _single_features_by_time(ax, results: list[AuditResult], times: list[int]) -> None:
    """A heatmap of each single feature's a_u (rows) at each failure time (columns), the
    number written in each cell where there are few enough to read."""
    scores = np.array([[entry.score for entry in result.sets[1]] for result in results]).T
    image = ax.imshow(scores, aspect="auto", cmap="viridis")
    ax.figure.colorbar(image, ax=ax, label="$a_u$, one feature hidden")
    names = [", ".join(entry.names) for entry in results[0].sets[1]]
    ax.set_yticks(range(len(names)), names if len(names) <= 40 else [""] * len(names), fontsize=7)
    ax.set_xticks(range(len(times)), [str(time) for time in times])
    ax.set_xlabel("env step at which the sensor fails")
    if scores.size <= 400:
        middle = (scores.min() + scores.max()) / 2
        for (row, column), score in np.ndenumerate(scores):
            ax.text(column, row, f"{score:.0f}", ha="center", va="center", fontsize=6,
                    color="black" if score > middle else "white")
    ax.set_title("which sensor hurts when: $a_u$ of each feature hidden alone", fontsize=10)


def _baselines(results: list[AuditResult], baseline_mode: str = "uniform") -> dict[str, str]:
    """Each adversarial curve's uniform (or ``baseline_mode``'s) curve, where that was audited
    too: an experiment's ``uniform`` (every value of a sweep of l against it), or, for several
    runs, the uniform curve of the same other settings that their source names (``baseline``:
    as ``plot`` pairs them, :attr:`~admissable_jax.results.Run.baseline_variant`), and the
    ``baseline_mode`` curve of those settings."""
    curves = pair_curves(results)
    pairs = {curve: baseline_mode + result.source.get("baseline", "uniform").removeprefix("uniform")
             for result, curve in zip(results, curves) if curve_mode(curve) == "adversarial"}
    return {curve: baseline for curve, baseline in pairs.items() if baseline in curves}


def _compared_as_runs(results: list[AuditResult]) -> bool:
    """Whether the results are several runs audited together, each source naming its curve
    (``audit_runs``), rather than an experiment's pairs."""
    return all("curve" in result.source for result in results)


def pair_curves(results: list[AuditResult]) -> list[str]:
    """The curve of each audited pair of an experiment: its mode, or ``adversarial-l<l>``
    where the experiment's adversarial pairs sweep l (:func:`~admissable_jax.config.curve_names`);
    of several runs audited together, the curve their source names (``audit_runs``)."""
    if _compared_as_runs(results):
        return [result.source["curve"] for result in results]
    return curve_names([(result.source["mode"], result.source.get("lower_bound", 0.0)) for result in results])


def _worst_by_mode(results: list[AuditResult]) -> dict[str, dict[int, np.ndarray]]:
    """Per curve (mode) and k: each pair's worst a_u (the lowest over the sets of that size)."""
    return _per_pair_by_mode(results, lambda result, k: min(entry.score for entry in result.sets[k]))


def _worst_by_time_and_mode(by_time: dict[int, list[AuditResult]]) -> dict[int, dict[str, dict[int, np.ndarray]]]:
    """Per failure step, :func:`_worst_by_mode` of the pairs audited at it."""
    return {time: _worst_by_mode(results) for time, results in sorted(by_time.items())}


def _per_pair_by_mode(results: list[AuditResult], measure) -> dict[str, dict[int, np.ndarray]]:
    """Per curve (mode, :func:`pair_curves`) and k: ``measure(result, k)`` of each pair, in pair order."""
    by_mode: dict[str, dict[int, list[float]]] = {}
    for result, curve in zip(results, pair_curves(results)):
        for k in result.sets:
            by_mode.setdefault(curve, {}).setdefault(k, []).append(measure(result, k))
    return {mode: {k: np.array(values) for k, values in per_k.items()} for mode, per_k in by_mode.items()}


def comparison_chart(results: list[AuditResult], path: str) -> str:
    """Bars per k and mode: the mean of the pairs' worst a_u with its 95% t-interval, and
    each pair's own as a dot."""
    from admissable_jax.plot import curve_colors

    worst = _worst_by_mode(results)
    ks, modes = list(results[0].sets), sorted(worst)
    width = 0.8 / len(modes)
    colors = curve_colors([(curve_mode(mode), mode) for mode in modes])  # a sweep's adversarial-l<l>: shades
    figure, ax = _figure(figsize=(max(5, 1.6 * len(ks) * len(modes)), 4))
    for offset, mode in enumerate(modes):
        x = np.arange(len(ks)) + (offset - (len(modes) - 1) / 2) * width
        bounds = [mean_and_interval(worst[mode][k][:, None]) for k in ks]
        means = np.array([mean[0] for mean, _, _ in bounds])
        errors = np.array([[mean[0] - low[0] for mean, low, _ in bounds], [high[0] - mean[0] for mean, _, high in bounds]])
        color = colors[curve_mode(mode), mode]
        ax.bar(x, means, width, yerr=errors, capsize=3, color=color, alpha=0.6,
               label=f"{mode} ({len(worst[mode][ks[0]])} seeds)")
        for position, k in zip(x, ks):
            ax.plot(np.full(len(worst[mode][k]), position), worst[mode][k], "o", color=color, markersize=3)
    ax.set_xticks(range(len(ks)), [f"k = {k}" for k in ks])
    ax.set_ylabel("worst $a_u$ over the sets of size k")
    ax.set_title(f"{results[0].env}, {audited_policies(results)}: "
                 f"the worst hidden set per pair (bars: mean, 95% CI; dots: pairs)", fontsize=9)
    ax.legend()
    ax.grid(alpha=0.3, axis="y")
    return _saved(figure, path)


def audited_policies(results: list[AuditResult]) -> str:
    """Which policy of each pair was audited: one checkpoint, or each pair's best scoring's
    (``audit best=true``: the pairs' own env steps)."""
    steps = sorted({result.source["checkpoint (env step)"] for result in results})
    listed = ", ".join(f"{step:,}" for step in steps)
    if any("kept as" in result.source for result in results):
        return f"each pair's best scoring (env steps {listed})"
    return f"checkpoint {steps[0]}" if len(steps) == 1 else f"each run's checkpoint (env steps {listed})"


def _audited_together(results: list[AuditResult]) -> str:
    """What a comparison compares: an experiment's pairs, or several runs by curve."""
    return f"{len(results)} runs" if _compared_as_runs(results) else "an experiment"


def compare_modes(results: list[AuditResult]) -> str:
    """Markdown: per k and mode, the pairs' worst a_u, their mean a_u over the sets (the
    average case; not for a searched k) and clean return (mean ± 95% t-interval over seeds)
    and the set most often worst; then adversarial − uniform (and − worst, where audited) per k
    on the worst and the mean (Welch's t: the seeds of one mode are independent of the
    other's), with the seeds per mode that would tell apart what these cannot
    (:func:`~admissable_jax.results.seeds_sentence`); where every pair was audited with
    ``shapley=``, each feature's Shapley value per mode."""
    by_mode: dict[str, list[AuditResult]] = {}
    for result, curve in zip(results, pair_curves(results)):
        by_mode.setdefault(curve, []).append(result)
    first = results[0]
    lines = [f"# Robustness audit of {_audited_together(results)}: {first.env}, {audited_policies(results)}", "",
             f"Each pair audited as its own report says ({audit_settings(results)}); "
             "here, per pair, the worst a_u over the sets of each size and the mean a_u over them (the average case, "
             "u drawn uniformly), then mean ± 95% t-interval over the seeds of a mode. Where a k was searched "
             f"(`search=beam`), the worst found is an upper bound on the worst, and there is no mean."
             f"{training_failures_sentence(results)}", "",
             "| k | mode | seeds | worst a_u | mean a_u over the sets | most often worst | clean return |",
             "|---|---|---|---|---|---|---|"]
    measures = {"worst a_u": _worst_by_mode(results), "mean a_u": _per_pair_by_mode(results, AuditResult.mean)}
    for k in first.sets:
        for mode, group in sorted(by_mode.items()):
            names = [", ".join(result.worst(k, 1)[0].names) for result in group]
            common = max(names, key=names.count)  # ties: the first pair's
            clean = np.array([result.clean_score for result in group])
            average = measures["mean a_u"][mode][k]
            lines.append(f"| {k} | {mode} | {len(group)} | {estimate(measures['worst a_u'][mode][k])} | "
                         f"{'—' if np.isnan(average).any() else estimate(average)} | {common} "
                         f"({names.count(common)} of {len(group)}) | {estimate(clean)} |")
    for baseline_mode in BASELINE_QUESTIONS:
        lines += _mode_comparison(first, measures, _baselines(results, baseline_mode), baseline_mode)
    if all(result.shapley is not None for result in results):
        lines += _shapley_by_mode(by_mode, first.feature_names)
    if all(result.dropout is not None for result in results):
        lines += _dropout_by_mode(by_mode, _baselines(results))
    return "\n".join(lines) + "\n"


def _mode_comparison(first: AuditResult, measures: dict[str, dict[str, dict[int, np.ndarray]]],
                     baselines: dict[str, str], baseline_mode: str) -> list[str]:
    """compare_modes' lines of adversarial − ``baseline_mode`` per k on each of ``measures``
    (Welch's t), each adversarial curve against its curve of that mode in ``baselines`` (several
    in a sweep of l, or of runs' settings), and the seeds that would tell apart what these
    cannot; none without such a pair. Against uniform under the table above; against another
    mode under a line of its own, saying what the comparison asks (:func:`comparison_title`)."""
    if not baselines:
        return []
    swept = lambda curve: f" ({curve})" if curve != "adversarial" else ""
    compared = [(k, name + swept(curve), Difference(f"k={k} {name}{swept(curve)}", per_mode[curve][k],
                                                    per_mode[baseline][k], baseline_mode))
                for curve, baseline in baselines.items() for k in first.sets for name, per_mode in measures.items()
                if not np.isnan(per_mode[curve][k]).any()]
    heading = [] if baseline_mode == "uniform" else ["", f"{comparison_title(baseline_mode)}:"]
    lines = [*heading, "", *comparison_header("k", "measure", baseline_mode=baseline_mode)]
    lines += [f"| {k} | {name} | {difference.cells()} |" for k, name, difference in compared]
    sentence = seeds_sentence([(difference.metric, difference) for _, _, difference in compared])
    return lines + (["", sentence.rstrip()] if sentence else [])


def compare_modes_by_failure_time(by_time: dict[int, list[AuditResult]]) -> str:
    """Markdown: an experiment's pairs audited at several failure steps (``fail_at=0,50,...``):
    per k, failure step and mode, the pairs' worst a_u (mean ± 95% t-interval over the seeds);
    then adversarial − uniform per k and step (Welch's t). Does training against the worst set
    hidden from the start also protect when a sensor fails later?"""
    times, first = sorted(by_time), by_time[min(by_time)][0]
    worst = _worst_by_time_and_mode(by_time)
    modes = sorted(worst[times[0]])
    lines = [f"# Robustness by when the sensors fail, per mode: {first.env}, {audited_policies(by_time[times[0]])}", "",
             f"Each pair audited at each failure step as its report says ({episodes_per_set(by_time[times[0]])}, "
             f"`{first.estimator}`; the step's comparison.md beside it): per k, the pairs' worst a_u over the sets, "
             "mean ± 95% t-interval over the seeds of a mode, with the sets' sensors failing at that env step of each "
             f"episode (0: hidden from the start, the paper's a_u).{training_failures_sentence(by_time[times[0]])}", "",
             "| k | sensors fail at env step | " + " | ".join(modes) + " |", "|---|---|" + "---|" * len(modes)]
    lines += [f"| {k} | {time} | " + " | ".join(estimate(worst[time][mode][k]) for mode in modes) + " |"
              for k in first.sets for time in times]
    baselines = _baselines(by_time[times[0]])
    if baselines:
        lines += ["", "Adversarial − uniform, the worst a_u:", "", *comparison_header("k", "fails at", "curve")]
        lines += [f"| {k} | {time} | {curve} | "
                  f"{Difference(f'k={k} fail_at={time} {curve}', worst[time][curve][k], worst[time][baseline][k]).cells()} |"
                  for k in first.sets for time in times for curve, baseline in baselines.items()]
    return "\n".join(lines) + "\n"


def failure_time_chart_by_mode(by_time: dict[int, list[AuditResult]], path: str) -> str:
    """Per mode, the pairs' worst a_u of the smallest k against the failure step: the mean with
    its 95% t-interval shaded, and each pair's as dots."""
    from admissable_jax.plot import curve_colors, env_steps_axis

    times = sorted(by_time)
    worst = _worst_by_time_and_mode(by_time)
    modes, k = sorted(worst[times[0]]), min(by_time[times[0]][0].sets)
    colors = curve_colors([(curve_mode(mode), mode) for mode in modes])
    figure, ax = _figure(figsize=(8, 4.5))
    for mode in modes:
        per_pair = np.array([worst[time][mode][k] for time in times]).T  # (seeds, times)
        mean, low, high = mean_and_interval(per_pair)
        color = colors[curve_mode(mode), mode]
        ax.plot(times, mean, marker="o", color=color, label=f"{mode} ({len(per_pair)} seeds)")
        ax.fill_between(times, low, high, color=color, alpha=0.2)
        for seed_values in per_pair:
            ax.plot(times, seed_values, ".", color=color, markersize=3)
    env_steps_axis(ax, "env step at which the sensors fail (0: from the start, the paper's a_u)")
    ax.set_ylabel(f"worst $a_u$ over the sets of size {k}")
    ax.set_title(f"{by_time[times[0]][0].env}: the worst set by when its sensors fail, per mode "
                 "(mean, 95% CI; dots: pairs)", fontsize=9)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8)
    os.makedirs(os.path.dirname(path), exist_ok=True)
    return _saved(figure, path)


def episodes_per_set(results: list[AuditResult]) -> str:
    """N of several audits (an experiment's pairs, a run's checkpoints): one number, or their
    range where ``tell_apart`` chose each."""
    low, high = min(result.n_episodes for result in results), max(result.n_episodes for result in results)
    return (f"N = {low} episodes per set" if low == high else
            f"N = {low}–{high} episodes per set, each audit's chosen by its pilot (`tell_apart`)")


def _dropout_by_mode(by_mode: dict[str, list[AuditResult]], baselines: dict[str, str]) -> list[str]:
    """Markdown: the expected return under random sensor failure per rate and mode, mean ±
    95% t-interval over the mode's pairs; then each adversarial curve − its uniform one
    (``baselines``: :func:`_baselines`) per rate (Welch's t)."""
    first = next(iter(by_mode.values()))[0]
    rates = [entry.rate for entry in first.dropout]
    values = {mode: np.array([[entry.score for entry in result.dropout] for result in group])
              for mode, group in sorted(by_mode.items())}
    lines = ["", "## Random sensor failure, per mode", "",
             f"Each pair's R(p) (its report's section), the expected return when each feature fails with probability p "
             f"{hidden_when(first)}, mean ± 95% t-interval over the seeds of a mode.", "",
             "| failure rate p | " + " | ".join(values) + " |", "|---|" + "---|" * len(values)]
    lines += [f"| {rate:g} | " + " | ".join(estimate(per_pair[:, column]) for per_pair in values.values()) + " |"
              for column, rate in enumerate(rates)]
    if baselines:
        lines += ["", *comparison_header("failure rate p", "curve")]
        lines += [f"| {rate:g} | {curve} | "
                  f"{Difference(f'p={rate:g} {curve}', values[curve][:, column], values[baseline][:, column]).cells()} |"
                  for curve, baseline in baselines.items() for column, rate in enumerate(rates)]
    return lines


def _shapley_by_mode(by_mode: dict[str, list[AuditResult]], names: list[str], most: int = 20) -> list[str]:
    """Markdown: each feature's Shapley value per mode, mean ± 95% t-interval over the
    mode's pairs; the ``most`` features of largest mean |φ_i| over every pair, largest φ first."""
    values = {mode: np.array([result.shapley.values for result in group]) for mode, group in sorted(by_mode.items())}
    overall = np.concatenate(list(values.values())).mean(axis=0)
    shown = sorted(sorted(range(len(names)), key=lambda i: -abs(overall[i]))[:most], key=lambda i: -overall[i])
    which = "every feature" if len(shown) == len(names) else f"the {len(shown)} of largest mean |φ_i| of {len(names)}"
    lines = ["", "## What each feature is worth, per mode", "",
             f"Each pair's Shapley values φ_i (its report's last section: the feature's share of v(all) − v(none)), "
             f"mean ± 95% t-interval over the seeds of a mode; {which}, largest mean first.", "",
             "| feature | index | " + " | ".join(values) + " |", "|---|---|" + "---|" * len(values)]
    for i in shown:
        lines.append(f"| {names[i]} | {i} | " + " | ".join(estimate(per_pair[:, i]) for per_pair in values.values()) + " |")
    return lines
