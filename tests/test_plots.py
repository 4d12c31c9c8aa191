"""Figures from run directories (synthetic histories; no training)."""

import csv
import json
import os
import shutil
import tarfile

import numpy as np
import pytest
from matplotlib.colors import to_rgb
from matplotlib.image import imread
from omegaconf import OmegaConf

from admissable_jax.config import TrainConfig
from admissable_jax.envs import observation_names
from admissable_jax.method import candidate_sets
from admissable_jax.plot import CUT_BANDS, LOWEST_BARS, _cell_edges, _final_scores_figure, _heatmap, _seeds, \
    check_formats, curve_colors, draw_curves, effective_window, env_steps_axis, keep_to_seeds, main, \
    plot_envs_side_by_side, plot_runs
from admissable_jax.results import (
    Difference, final_scores, find_runs, format_comparison, load_run, load_runs, mean_and_interval, mode_differences,
    moving_average, per_feature_of_sets, set_names, steps_text, summary_table, wall_time_text, write_tables,
)


def _names(env, k=1, include_empty=False):
    """The names a run of ``env`` gives its candidate sets."""
    features = observation_names(env)
    return set_names(features, candidate_sets(len(features), k, include_empty))


def _fake_run(root, mode, seed, records=12, sets=11, env="hopper", timed=None, **settings):
    """A run folder with ``records`` scorings of made-up a_u; ``timed``: (env steps/s, scoring
    seconds) of every interval, written as its metrics.jsonl rows."""
    path = os.path.join(root, f"{mode}-s{seed}")
    os.makedirs(path)
    config = TrainConfig(env=env, missingness=mode, seed=seed, **settings)
    OmegaConf.save(OmegaConf.structured(config), os.path.join(path, "config.yaml"))
    rng = np.random.default_rng(seed)
    with open(os.path.join(path, "scores.jsonl"), "w") as file:
        for t in range(records):
            scores = (rng.uniform(0, 100, sets) + 10 * t).tolist()
            inverse = 1 / np.asarray(scores)
            p_miss = (inverse / inverse.sum() if mode == "adversarial" else np.ones(sets) / sets).tolist()
            file.write(json.dumps({"env_steps": 5000 * (t + 1), "scores": scores, "min_score": min(scores),
                                   "clean_score": max(scores) + 5, "p_miss": p_miss}) + "\n")
    if timed is not None:
        with open(os.path.join(path, "metrics.jsonl"), "w") as file:
            file.writelines(json.dumps({"env_steps": 5000 * (t + 1), "env_steps_per_s": timed[0],
                                        "score_seconds": timed[1]}) + "\n" for t in range(records))
    return path


def _captions(monkeypatch) -> dict[str, tuple[str, bool]]:
    """What the figures drawn from here on would be saved with, by name: the caption in one
    line, and whether a band reaches past the axes (so the caption must say it is cut)."""
    def band_cut(figure) -> bool:
        return any(band.get_paths()[0].vertices[:, 1].min() < ax.get_ylim()[0]
                   or band.get_paths()[0].vertices[:, 1].max() > ax.get_ylim()[1]
                   for ax in figure.axes for band in ax.collections)

    def save(figure, _, name: str, *__) -> list[str]:
        import matplotlib.pyplot as plt

        captions[name] = " ".join(figure._suptitle.get_text().split()) if figure._suptitle else "", band_cut(figure)
        plt.close(figure)
        return []

    captions = {}
    monkeypatch.setattr("admissable_jax.plot._save", save)
    return captions


def _edit_rows(run_dir, change):
    """Rewrite ``run_dir``'s scores.jsonl, each row as ``change(t, row)`` gives it (t: its index)."""
    path = os.path.join(run_dir, "scores.jsonl")
    with open(path) as file:
        rows = [json.loads(line) for line in file]
    with open(path, "w") as file:
        file.writelines(json.dumps(change(t, row)) + "\n" for t, row in enumerate(rows))


def test_smoothing_and_interval():
    np.testing.assert_allclose(moving_average(np.array([1.0, 3.0, 5.0, 7.0]), 2), [1.0, 2.0, 4.0, 6.0])
    np.testing.assert_allclose(moving_average(np.array([[2.0, 4.0, 6.0]]), 10), [[2.0, 3.0, 4.0]])
    curves = np.array([[1.0, 2.0], [3.0, 4.0], [5.0, 6.0]])
    mean, low, high = mean_and_interval(curves)
    np.testing.assert_allclose(mean, [3.0, 4.0])
    # t(0.975, 2) = 4.303, std 2, n 3: half-width 4.969.
    np.testing.assert_allclose(high - mean, [4.969, 4.969], atol=1e-3)
    np.testing.assert_allclose(mean - low, high - mean)


def test_plot_runs_writes_every_figure(tmp_path, capsys):
    for mode in ("adversarial", "uniform"):
        for seed in range(3):
            _fake_run(str(tmp_path / "runs"), mode, seed)
    runs = find_runs([str(tmp_path / "runs")])
    assert len(runs) == 6
    # A run reached twice (a folder and a run in it, another spelling) is one seed, not two.
    assert find_runs([str(tmp_path / "runs"), runs[0], f"{tmp_path}/runs/./adversarial-s1"]) == runs
    assert [run.path for run in load_runs([runs[0], f"{runs[0]}/", runs[1]])] == runs[:2]
    written = plot_runs(runs, str(tmp_path / "figures"), window=4)
    names = sorted(os.path.basename(p) for p in written)
    assert names == sorted(
        f"{stem}.{ext}" for stem in ("min_score", "scores_adversarial", "scores_uniform", "p_miss_adversarial", "p_miss_uniform",
                                      "final_scores")
        for ext in ("png", "pdf")
    )
    # A p_miss that never left uniform is said in words (a short figure), not drawn as a
    # flat colour block; the adversary's is a heatmap with a row per feature.
    height = lambda name, folder="figures": imread(os.path.join(tmp_path, folder, f"{name}.png")).shape[0]
    assert height("p_miss_uniform") < 450 < height("p_miss_adversarial")
    # In words only where every seed's stayed uniform: an adversarial seed whose a_u all sat at
    # l (p_miss ∝ 1/ε alike) beside one whose adversary moved is still a heatmap.
    stuck = _fake_run(str(tmp_path / "mixed"), "adversarial", 7)
    _edit_rows(stuck, lambda t, row: {**row, "p_miss": [1 / 11] * 11})
    shutil.copytree(tmp_path / "runs" / "adversarial-s0", tmp_path / "mixed" / "adversarial-s0")
    written = plot_runs(find_runs([str(tmp_path / "mixed")]), str(tmp_path / "mixed_figures"), window=4, formats="PNG")
    assert height("p_miss_adversarial", "mixed_figures") > 450
    # Mode none hides nothing in training, so nothing was drawn from its recorded p_miss: no
    # p_miss figure (it read "stayed uniform", as if uniform missingness had been trained on).
    _fake_run(str(tmp_path / "clean"), "none", 0)
    written = plot_runs(find_runs([str(tmp_path / "clean")]), str(tmp_path / "clean_figures"), window=4, formats="png")
    assert sorted(os.path.basename(path) for path in written) == ["final_scores.png", "min_score.png",
                                                                   "scores_none.png"]
    assert {os.path.splitext(path)[1] for path in written} == {".png"}  # one format as a string ("png,svg" too), not
    assert check_formats(" png, SVG,png") == ("png", "svg")  # its letters ('formats: 'p', 'n', 'g': give formats ...')
    with pytest.raises(FileNotFoundError, match=f"no such directory: {tmp_path / 'missing'}$"):
        find_runs([str(tmp_path / "missing")])
    with pytest.raises(FileNotFoundError, match=f"^{runs[0]}/scores.jsonl is a file: give a run's folder \\(or a "
                                                f"folder of runs\\), such as {runs[0]}$"):
        find_runs(f"{runs[0]}/scores.jsonl")  # (it said "no such directory")
    # Runs of several envs from the command line: a figures subfolder per env, one summary;
    # the figures in the formats asked for, a format matplotlib cannot write refused first.
    walker = _fake_run(str(tmp_path / "runs" / "walker"), "uniform", 0, sets=17, env="walker2d")
    with pytest.raises(ValueError, match=r"^runs of several envs \(hopper, walker2d\): plot one env at a time$"):
        plot_runs([*runs, walker], str(tmp_path / "never"))  # the library's figures: one env's runs
    with pytest.raises(SystemExit) as refused:
        main([str(tmp_path / "runs"), f"out={tmp_path / 'never'}", "formats=png,docx"])
    error = capsys.readouterr().err.strip()
    assert refused.value.code == 2 and error.startswith("error: formats: 'docx': give formats matplotlib writes") \
        and "svg" in error and "\n" not in error and not (tmp_path / "never").exists()
    # A run that starts over (resume set its rows aside: an empty scores.jsonl) is left out, said
    # in one line, and the rest are drawn; a folder of such runs alone is refused in one line.
    # So is one whose only row was cut off mid-write (a crash at its first scoring).
    restarted = _fake_run(str(tmp_path / "runs" / "restarted"), "uniform", 9)
    open(os.path.join(restarted, "scores.jsonl"), "w").close()
    torn = _fake_run(str(tmp_path / "runs" / "torn"), "uniform", 8)
    with open(os.path.join(torn, "scores.jsonl"), "r+") as file:
        file.truncate(len(file.readline()) // 2)
    assert main([str(tmp_path / "runs"), f"out={tmp_path / 'both'}", "formats=png,SVG"]) == 0
    warnings = capsys.readouterr().err
    assert all(f"warning: {run} has no scoring rows yet: left out\n" in warnings for run in (restarted, torn))
    with pytest.raises(SystemExit) as refused:
        main([str(tmp_path / "runs" / "restarted"), f"out={tmp_path / 'never'}"])
    assert refused.value.code == 2 and capsys.readouterr().err.endswith(
        f"error: no run under {tmp_path / 'runs' / 'restarted'} has scored yet (1 without scoring rows)\n")
    assert sorted(os.listdir(tmp_path / "both")) == [
        "curves.csv", "figure1.png", "figure1.svg", "hopper", "scores.csv", "summary.md", "walker2d"]
    _check_tables(tmp_path / "both", runs + find_runs([str(tmp_path / "runs" / "walker")]))
    height, width, _ = imread(os.path.join(tmp_path, "both", "figure1.png")).shape
    assert width > 2 * height  # the paper's layout: a panel per env, side by side
    assert sorted(os.listdir(tmp_path / "both" / "walker2d")) == [
        f"{stem}.{ext}" for stem in ("final_scores", "min_score", "p_miss_uniform", "scores_uniform") for ext in ("png", "svg")]
    summary = (tmp_path / "both" / "summary.md").read_text()
    assert "| walker2d | uniform | 1 |" in summary and "| hopper | adversarial | 3 |" in summary
    assert "hopper: moving average over 2 records (the paper's 40 of 200, scaled to the runs' 12)" in summary
    assert "Trained on: not recorded (runs written before `invocations.jsonl`)." in summary


def _check_tables(folder, run_dirs):
    """``curves.csv`` and ``scores.csv`` hold every run's scoring rows, as its scores.jsonl
    has them (read here directly), a_u named by the hidden set."""
    with open(folder / "curves.csv") as file:
        curves = list(csv.DictReader(file))
    with open(folder / "scores.csv") as file:
        sets = list(csv.DictReader(file))
    expected_curves, expected_sets = [], []
    for path in sorted(run_dirs):
        config = OmegaConf.load(os.path.join(path, "config.yaml"))
        names = _names(config.env)
        with open(os.path.join(path, "scores.jsonl")) as file:
            for row in map(json.loads, file):
                key = (config.env, config.missingness, str(config.seed), str(row["env_steps"]))
                expected_curves.append((*key, row["min_score"], round(float(np.mean(row["scores"])), 9),
                                        row["clean_score"], names[int(np.argmin(row["scores"]))], path))
                expected_sets += [(*key, name, a_u, p) for name, a_u, p in zip(names, row["scores"], row["p_miss"])]
    got_curves = [(row["env"], row["mode"], row["seed"], row["env_steps"], float(row["min_score"]),
                   round(float(row["mean_score"]), 9), float(row["clean_score"]), row["worst_set"], row["run"])
                  for row in curves]
    got_sets = [(row["env"], row["mode"], row["seed"], row["env_steps"], row["hidden"], float(row["a_u"]),
                 float(row["p_miss"])) for row in sets]
    assert sorted(got_curves) == sorted(expected_curves)
    assert sorted(got_sets) == sorted(expected_sets)


def test_min_score_against_the_wall_time_the_runs_timed(tmp_path, capsys, monkeypatch):
    """min_score_by_time: each curve's scorings at its seeds' mean wall time of training and
    scoring so far, summed from metrics.jsonl (ζ / env_steps_per_s + score_seconds per
    interval; here a cheap-scoring curve beside a slow one), in curves.csv too; seeds of a
    curve whose times differ by over 1.5x are warned of (other devices?); not drawn where a
    run has not timed every interval (its times NaN from there)."""
    import matplotlib.pyplot as plt
    timings = {("adversarial", 0): (500.0, 2.0), ("adversarial", 1): (250.0, 4.0), ("uniform", 0): (1000.0, 1.0)}
    runs = [_fake_run(str(tmp_path / "runs"), mode, seed, timed=timed) for (mode, seed), timed in timings.items()]
    written = plot_runs(runs, str(tmp_path / "figures"), window=1, formats="png")
    assert os.path.join(tmp_path, "figures", "min_score_by_time.png") in written
    assert capsys.readouterr().err == ("warning: min_score_by_time: the seeds of adversarial took 2.4 min to 4.8 min "
                                       "(other devices or physics?); its time axis is their mean\n")
    per_interval = {key: 5000 / sps + seconds for key, (sps, seconds) in timings.items()}  # 12, 24 and 6 s
    np.testing.assert_allclose(load_run(runs[1]).wall_seconds, 24.0 * np.arange(1, 13))
    figure, ax = plt.subplots()
    draw_curves(ax, [load_run(run) for run in runs], "min_score", 1, against="wall_seconds")
    lines = {line.get_label(): line.get_xdata() for line in ax.get_lines() if not line.get_label().startswith("_")}
    np.testing.assert_allclose(lines["adversarial (2 seeds)"], 18.0 * np.arange(1, 13))  # (12 + 24) / 2 per interval
    np.testing.assert_allclose(lines["uniform (1 seed)"], per_interval["uniform", 0] * np.arange(1, 13))
    figure.canvas.draw()
    labels = [tick.get_text() for tick in ax.get_xticklabels()]  # (218 s wide: a tick every 30 s)
    assert labels[labels.index("0"):][:4] == ["0", "30 s", "1 min", "1.5 min"]
    plt.close(figure)
    assert [wall_time_text(seconds) for seconds in (0, 45, 750, 11520)] == ["0", "45 s", "12.5 min", "3.2 h"]
    write_tables(runs, str(tmp_path / "tables"))
    with open(tmp_path / "tables" / "curves.csv") as file:
        first = [row for row in csv.DictReader(file) if row["mode"] == "uniform"]
    assert [float(row["wall_seconds"]) for row in first] == pytest.approx(6.0 * np.arange(1, 13))
    # A run that did not time its fourth interval: NaN from there, an empty cell, no figure.
    with open(os.path.join(runs[2], "metrics.jsonl")) as file:
        rows = file.readlines()
    with open(os.path.join(runs[2], "metrics.jsonl"), "w") as file:
        file.writelines(rows[:3] + [json.dumps({"env_steps": 20000}) + "\n"] + rows[4:])
    assert np.isnan(load_run(runs[2]).wall_seconds[3:]).all() and load_run(runs[2]).wall_seconds[2] == 18.0
    written = plot_runs(runs, str(tmp_path / "untimed"), window=1, formats="png")
    assert not any(path.endswith("min_score_by_time.png") for path in written)
    # Its caption, and min_score's, say where a band is cut at the axes: 2 seeds 10 apart at every
    # scoring, rising by 1 a scoring (their band reaches 64 past their mean), but not 5 seeds of the made-up a_u.
    captions = _captions(monkeypatch)
    for seeds in (2, 5):
        like = [_fake_run(str(tmp_path / f"seeds{seeds}"), "adversarial", seed, timed=(500.0, 2.0))
                for seed in range(seeds)]
        for seed, path in enumerate(like if seeds == 2 else ()):
            _edit_rows(path, lambda t, row, seed=seed: {**row, "scores": [100.0 + t + 10 * seed] * 11,
                                                        "min_score": 100.0 + t + 10 * seed,
                                                        "clean_score": 105.0 + t + 10 * seed})
        plot_runs(like, str(tmp_path / f"figures{seeds}"), window=1)
        for name in ("min_score", "min_score_by_time"):
            caption, cut = captions[name]
            assert (CUT_BANDS in caption) == cut == (seeds == 2), (name, caption)


def test_runs_that_differ_in_settings_are_separate_curves(tmp_path, capsys):
    """Runs of one mode with other settings (k = 1 and k = 2 here) are separate curves, rows
    and comparisons, named by the settings that differ, never seeds of one; settings that
    change nothing learned or scored (physics, total_steps, ...) do not split them; a seed
    twice in one curve is warned about."""
    root = tmp_path / "runs"
    for mode in ("adversarial", "uniform"):
        for seed in range(2):
            _fake_run(str(root / "k1"), mode, seed, physics="jax" if seed else "warp", total_steps=5000 * (seed + 1))
    _fake_run(str(root / "k2"), "adversarial", 0, sets=55, k=2)
    assert main([str(root), f"out={tmp_path / 'figures'}", "formats=png"]) == 0
    summary = (tmp_path / "figures" / "summary.md").read_text()
    assert [line.split(" | ")[1:3] for line in summary.splitlines() if line.startswith("| hopper | ")][:3] == [
        ["adversarial, k=1", "2"], ["adversarial, k=2", "1"], ["uniform, k=1", "2"]]
    compared = [line.split(" | ")[0] for line in summary.split("Welch's t):")[1].splitlines() if line.startswith("| ")]
    assert set(compared[2:]) == {"| hopper, k=1"}  # k = 2 has no uniform runs to compare with
    assert "hopper runs differ in k: each setting is its own curve and row, never seeds of one." in summary
    assert {"scores_adversarial_k=1.png", "scores_adversarial_k=2.png", "p_miss_uniform_k=1.png"} <= set(
        os.listdir(tmp_path / "figures"))
    assert capsys.readouterr().err == ""
    shutil.copytree(root / "k1" / "uniform-s1", root / "copy")
    assert main([str(root), f"out={tmp_path / 'again'}", "formats=png"]) == 0
    assert (f"warning: uniform, k=1 seed 1 is in 2 runs ({root / 'copy'}, {root / 'k1' / 'uniform-s1'}); "
            "each counts as a seed") in capsys.readouterr().err


def test_a_sweep_of_l_sets_every_value_against_the_uniform_runs_which_l_does_not_touch(tmp_path):
    """Adversarial runs with l = 0, 25 and 100 are three curves, in that order and shaded
    light to dark as l grows (one config.yaml writes 25 as an integer: still a seed of l = 25);
    uniform runs never read l, so two saved with other l are seeds of one curve, the baseline
    of all three comparisons; so are two of mode worst, whose p_miss is the argmin's."""
    root = tmp_path / "runs"
    for bound in (0.0, 25.0, 100.0):
        for seed in range(2):
            _fake_run(str(root / f"l{bound:g}"), "adversarial", seed, lower_bound=bound)
    for seed, bound in ((0, 0.0), (1, 50.0)):
        _fake_run(str(root / f"u{seed}"), "uniform", seed, lower_bound=bound)
        _fake_run(str(root / f"w{seed}"), "worst", seed, lower_bound=bound)
    written_by_hand = root / "l25" / "adversarial-s1" / "config.yaml"  # l as an integer: the same l
    written_by_hand.write_text(written_by_hand.read_text().replace("lower_bound: 25.0", "lower_bound: 25"))
    assert main([str(root), f"out={tmp_path / 'figures'}", "formats=png"]) == 0
    summary = (tmp_path / "figures" / "summary.md").read_text()
    assert [line.split(" | ")[1:3] for line in summary.splitlines() if line.startswith("| hopper | ")][:5] == [
        ["adversarial, lower_bound=0", "2"], ["adversarial, lower_bound=25", "2"],
        ["adversarial, lower_bound=100", "2"], ["uniform", "2"], ["worst", "2"]]
    assert ("the uniform and none runs never read lower_bound, so each adversarial curve is compared with the "
            "uniform curve of its other settings") in summary
    differences = mode_differences(find_runs([str(root)]))
    assert list(differences) == [f"hopper, lower_bound={bound}" for bound in ("0", "25", "100")]
    uniform = [load_run(str(root / f"u{seed}" / f"uniform-s{seed}")).min_score[-1] for seed in range(2)]
    for rows in differences.values():
        np.testing.assert_allclose(rows[0].baseline, uniform)
    colors = curve_colors([("adversarial", f"lower_bound={bound}") for bound in ("100", "0", "25")]
                          + [("uniform", "")])
    lightness = [sum(to_rgb(colors["adversarial", f"lower_bound={bound}"])) for bound in ("0", "25", "100")]
    assert lightness[0] > lightness[1] > lightness[2] and colors["uniform", ""] == "tab:red"


def _run_with_minimums(root, mode, seed, minimums, final_clean, score_every=5000, spread=10):
    """A Hopper run whose scorings have the given min_u a_u (the other 10 sets score ``spread``,
    2 · ``spread``, ... more: mean_u a_u = min_u a_u + 5 · ``spread``)."""
    path = os.path.join(root, f"{mode}-s{seed}")
    os.makedirs(path)
    OmegaConf.save(OmegaConf.structured(TrainConfig(env="hopper", missingness=mode, seed=seed)), os.path.join(path, "config.yaml"))
    with open(os.path.join(path, "scores.jsonl"), "w") as file:
        for t, minimum in enumerate(minimums):
            file.write(json.dumps({"env_steps": score_every * (t + 1), "scores": [minimum + spread * i for i in range(11)],
                                   "min_score": minimum, "clean_score": final_clean, "p_miss": [1 / 11] * 11}) + "\n")
    return path


def test_summary_table_reports_final_and_auc_per_mode(tmp_path):
    """Hand-computed: two adversarial seeds, min_u a_u [10, 20, 30, 40] and [20, 30, 50, 60],
    final clean returns 100 and 120; one uniform seed, its sets spread wider."""
    paths = [
        _run_with_minimums(str(tmp_path), "adversarial", 0, [10, 20, 30, 40], 100),
        _run_with_minimums(str(tmp_path), "adversarial", 1, [20, 30, 50, 60], 120),
        _run_with_minimums(str(tmp_path), "uniform", 0, [5, 6, 7, 8], 90, spread=30),
    ]
    header, rule, adversarial, uniform = summary_table(paths).splitlines()
    cells = lambda row: [cell.strip() for cell in row.strip("|").split("|")]
    # Two seeds: 95% half-width t(0.975, 1) · sd / √2 = 12.706 · sd / √2.
    # final: mean(40, 60) = 50, sd 14.142 → ± 127.1; AUC: mean(25, 40) = 32.5, sd 10.607 → ± 95.3;
    # final mean_u a_u: mean(90, 110) = 100 ± 127.1; clean: mean(100, 120) = 110 ± 127.1.
    # The last column: where the mode is weak at the end (set 0, the lowest in every row here).
    worst = _names("hopper")[0]
    assert cells(adversarial) == ["hopper", "adversarial", "2", "20000", "50.0 ± 127.1", "32.5 ± 95.3", "100.0 ± 127.1",
                                  "110.0 ± 127.1", f"{worst} (2 of 2)"]
    # One seed: the values alone, no interval (AUC: mean(5, 6, 7, 8) = 6.5; mean_u a_u: 8 + 5 · 30 = 158).
    assert cells(uniform) == ["hopper", "uniform", "1", "20000", "8.0", "6.5", "158.0", "90.0", f"{worst} (1 of 1)"]
    # final_scores.png's numbers: set i scores (40, 60) + 10 i at the last record: 50 + 10 i ± 127.1.
    steps, mean, low, high = final_scores([load_run(path) for path in paths[:2]])
    assert steps == 20000
    np.testing.assert_allclose(mean, 50.0 + 10.0 * np.arange(11))
    np.testing.assert_allclose(high - mean, 127.06, atol=0.01)


def test_adversarial_minus_uniform_is_welchs_t(tmp_path):
    """The verdict's numbers: adversarial − uniform with Welch's interval (unequal variances,
    Welch–Satterthwaite df), hand-computed, and its reading in words."""
    # Finals 40, 60 against 8, 10: difference 41, se = √(200/2 + 2/2) = √101,
    # df = 101² / (100² + 1²) = 1.02, t(0.975, 1.02) = 12.132: half-width 121.93, p = 0.149.
    # (A pooled-variance t would give df 2 and half-width 43.2.)
    difference = Difference("final", np.array([40.0, 60.0]), np.array([8.0, 10.0]))
    low, high, p = difference.interval()
    assert difference.mean == 41.0
    np.testing.assert_allclose([low, high, p], [41 - 121.929, 41 + 121.929, 0.1493], atol=1e-3)
    assert difference.reading() == "not distinguishable (95% interval holds 0)"
    tight_high, tight_low = np.array([100.0, 101.0, 102.0]), np.array([10.0, 11.0, 12.0])
    assert Difference("x", tight_high, tight_low).reading() == "adversarial higher"
    assert Difference("x", tight_low, tight_high).reading() == "uniform higher"
    assert Difference("x", tight_low, tight_high, baseline_mode="worst").reading() == "worst higher"
    assert Difference("x", np.array([5.0]), tight_low).interval() is None
    # P(adversarial > uniform), ties half: both adversarial seeds above both uniform ones: 1, in
    # every bootstrap resample too. [2, 3] against [2, 1]: a tie (1/2) and 3 wins of 4 pairs,
    # 3.5 / 4. Resampling each mode's 2 seeds gives 16 equally likely pairs of draws; the
    # lowest, [2, 2] against [2, 2] (all ties, 0.5), has 1/16 > 2.5% of them, and wins of 1
    # more (e.g. [3, 3] against [2, 1]): the 95% interval is [0.5, 1].
    assert difference.probability_of_improvement() == (1.0, 1.0, 1.0)
    assert Difference("x", np.array([2.0, 3.0]), np.array([2.0, 1.0])).probability_of_improvement() == (0.875, 0.5, 1.0)
    # The modes' seeds are resampled apart: [1, 3] against [0, 2] (3 wins of 4 pairs) falls to 0
    # where adversarial draws [1, 1] and uniform [2, 2] (1/16 of the draws): interval [0, 1].
    # Drawn with the same indices, those two never meet, and the interval would be [0.75, 1].
    assert Difference("x", np.array([1.0, 3.0]), np.array([0.0, 2.0])).probability_of_improvement() == (0.75, 0.0, 1.0)
    assert Difference("x", tight_low, tight_high).improvement_text() == "0.00 [0.00, 0.00]"
    assert Difference("x", np.array([5.0]), tight_low).improvement_text() == "—"
    # Seeds that never cross: how often chance alone orders them so, Mann–Whitney's exact two-sided
    # p = 2 / C(n + m, n): 2 of the 6 orders of 2 and 2 seeds, 2 of the 20 of 3 and 3; none where they cross.
    assert difference.chance_of_order() == pytest.approx(1 / 3)
    assert Difference("x", tight_low, tight_high).chance_of_order() == pytest.approx(0.1)
    assert Difference("x", np.array([2.0, 3.0]), np.array([2.0, 1.0])).chance_of_order() is None
    assert Difference("x", np.array([5.0]), tight_low).chance_of_order() is None

    # From run directories: final and AUC min_u a_u, final mean_u a_u and clean return, over
    # the records both modes share (AUC: mean(25, 40) − mean(6.5, 7.5) = 25.5; clean: 110 − 92
    # = 18). The uniform runs' other sets score higher, so their average case is better while
    # their worst case is not (mean_u a_u: mean(90, 110) − mean(158, 160) = −59; the same
    # spreads as the finals, so the same half-width, 121.93; t = −59 / √101 = −5.87 on df 1.02, p = 0.104).
    paths = [
        _run_with_minimums(str(tmp_path), "adversarial", 0, [10, 20, 30, 40], 100),
        _run_with_minimums(str(tmp_path), "adversarial", 1, [20, 30, 50, 60], 120),
        _run_with_minimums(str(tmp_path), "uniform", 0, [5, 6, 7, 8], 90, spread=30),
        _run_with_minimums(str(tmp_path), "uniform", 1, [5, 6, 9, 10], 94, spread=30),
    ]
    cells = lambda row: [cell.strip() for cell in row.strip("|").split("|")]
    rows = [cells(row) for row in format_comparison(mode_differences(paths)).splitlines()[2:]]
    assert [row[:3] for row in rows] == [["hopper", "final min_u a_u", "+41.0"], ["hopper", "AUC min_u a_u", "+25.5"],
                                         ["hopper", "final mean_u a_u", "-59.0"], ["hopper", "final clean return", "+18.0"]]
    assert rows[0][3:] == ["[-80.9, 162.9]", "0.149", "1.00 [1.00, 1.00]", "not distinguishable (95% interval holds 0)"]
    assert rows[2][3:6] == ["[-180.9, 62.9]", "0.104", "0.00 [0.00, 0.00]"]
    assert format_comparison(mode_differences(paths[:2])) == ""  # one mode: nothing to compare
    # The CLI's summary.md carries it under the per-mode table; where mode worst ran too (here
    # as the uniform seeds did), adversarial − worst follows, the paper's stochastic adversary
    # against its deterministic one.
    _run_with_minimums(str(tmp_path), "worst", 0, [5, 6, 7, 8], 90, spread=30)
    _run_with_minimums(str(tmp_path), "worst", 1, [5, 6, 9, 10], 94, spread=30)
    assert main([str(tmp_path), f"out={tmp_path / 'figures'}", "formats=png"]) == 0
    summary = (tmp_path / "figures" / "summary.md").read_text()
    against_uniform, _, against_worst = summary.partition("Adversarial − worst (the paper's stochastic adversary")
    for section in (against_uniform, against_worst):
        assert "| hopper | final min_u a_u | +41.0 | [-80.9, 162.9] | 0.149 | 1.00 [1.00, 1.00] |" in section
    assert "| adversarial − worst | 95% interval (Welch) | p (two-sided) | P(adversarial > worst) " in against_worst
    assert "Seeds per mode that would tell adversarial from worst apart where these cannot" in against_worst
    assert "| env | metric | adversarial − uniform | 95% interval (Welch) | p (two-sided) | P(adversarial > uniform) " \
           "[95% bootstrap] | reading |\n|---|---|---|---|---|---|---|" in summary
    # None of the four told apart: the seeds per mode that would be (80% power at the difference
    # and spread seen). Finals: s² = 200 + 2, Welch's df (n − 1) · 202² / (200² + 2²) = 1.02 (n − 1);
    # n = 3: (t_0.975 + t_0.8 at 2.04 df)² · 202 / 41² = (4.23 + 1.06)² · 0.120 = 3.4 > 3; n = 4:
    # (3.15 + 0.98)² · 0.120 = 2.0 <= 4. Clean: s² = 200 + 8, gap 18: n = 7 gives 7.0 > 7, n = 8 6.7.
    assert ("Seeds per mode that would tell adversarial from uniform apart where these cannot (80% power at the "
            "difference and spread seen, two-sided 5% t-test): hopper final min_u a_u: about 4; hopper AUC min_u a_u: "
            "about 4; hopper final mean_u a_u: about 3; hopper final clean return: about 8.") in summary
    assert ("Where every seed of one mode ends above every seed of the other, the bootstrap interval is that one "
            "value whatever the seeds; how often chance alone orders seeds so (Mann–Whitney's exact two-sided p): "
            "hopper final min_u a_u: 0.333 (2 and 2 seeds); hopper AUC min_u a_u: 0.333 (2 and 2 seeds); hopper final "
            "mean_u a_u: 0.333 (2 and 2 seeds); hopper final clean return: 0.333 (2 and 2 seeds).") in summary
    tight = Difference("x", tight_high, tight_low)
    assert tight.seeds_to_separate() is None and Difference("x", np.array([5.0]), tight_low).seeds_to_separate() is None


def test_plots_say_what_they_show(tmp_path, capsys, monkeypatch):
    """Window, cell positions, feature names, seed counts and the output folder."""
    paths = [_fake_run(str(tmp_path / "runs"), "adversarial", seed, records=7) for seed in range(2)]
    runs = [load_run(path) for path in paths]
    # The default smooths as the paper does (40 of 200 records, a fifth of a shorter run's);
    # a window longer than the records is shortened visibly; a bad one is refused.
    assert effective_window(runs, 0) == 1 and effective_window(runs, 40) == 7 and effective_window(runs, 3) == 3
    assert [effective_window([load_run(_fake_run(str(tmp_path / f"r{n}"), "uniform", 0, records=n))], 0)
            for n in (4, 12, 58, 200, 400)] == [1, 2, 11, 40, 40]
    for bad in (-3, 2.5):
        with pytest.raises(ValueError, match="window must be an int >= 0"):
            effective_window(runs, bad)
    # Heatmap cells are centred on their scoring steps.
    np.testing.assert_allclose(_cell_edges(np.array([5000.0, 10000.0, 15000.0])), [2500, 7500, 12500, 17500])
    # Ant's 105 rows are each named, in the observation's order from the top (a pool's
    # heatmap too, blank where no pooled set hides the feature): a label every third row
    # left the row of a dark cell to be counted.
    import matplotlib.pyplot as plt

    names = _names("ant")
    pooled = np.full((3, 105), np.nan)
    pooled[:, [28, 29, 31]] = [[-1.0, -2.0, -3.0]] * 3
    for values in (pooled, np.zeros((3, 105))):
        figure, ax = plt.subplots()
        _heatmap(ax, figure, np.array([5000.0, 10000.0, 15000.0]), values, names, "a_u")
        assert [label.get_text() for label in ax.get_yticklabels()] == names
        assert ax.get_ylim() == (104.5, -0.5)
        env_steps_axis(ax)  # few scorings: a tick on each column, none past the last
        figure.canvas.draw()
        assert [label.get_text() for label in ax.get_xticklabels()] == ["5k", "10k", "15k"]
        plt.close(figure)
    # Rows carry Gymnasium's observation names; one seed is "1 seed".
    assert runs[0].set_names[:3] == ["torso z", "torso angle", "thigh joint angle"]
    assert _names("hopper", 2, True)[:2] == ["nothing hidden", "torso z + torso angle"]
    up_to_two = load_run(_fake_run(str(tmp_path / "up_to_k"), "adversarial", 0, records=2, sets=66, k=2, up_to_k=True))
    assert up_to_two.set_names[10:12] == [observation_names("hopper")[10], "torso z + torso angle"]  # 11 singles first
    assert _names("ant")[27:30] == ["torso contact torque x", "torso contact torque y", "torso contact torque z"]
    assert _seeds(1) == "1 seed" and _seeds(5) == "5 seeds"
    # per_seed: each seed's own moving average, thin, after the mean's line (here one curve of 2 seeds).
    for per_seed in (False, True):
        figure, ax = plt.subplots()
        extent = draw_curves(ax, runs, "min_score", 3, per_seed)  # what the seeds took: their raw records bound it
        assert extent == (min(run.min_score.min() for run in runs), max(run.min_score.max() for run in runs))
        lines = ax.get_lines()  # the mean, each seed's line where asked, the dots
        assert len(lines) == (4 if per_seed else 2)
        for run, line in zip(runs, lines[1:-1]):
            np.testing.assert_allclose(line.get_ydata(), moving_average(run.min_score, 3))
        # The curve: the seeds' mean of their moving averages; the dots: the seeds' mean of each record, unsmoothed.
        np.testing.assert_allclose(lines[0].get_ydata(), np.mean([moving_average(run.min_score, 3) for run in runs], 0))
        np.testing.assert_allclose(lines[-1].get_ydata(), np.mean([run.min_score for run in runs], axis=0))
        plt.close(figure)
    # Two seeds' t-interval reaches 6.4 times their difference past their mean: the y axis keeps to the seeds'
    # values and their range beyond, and says it cut; a band within that is drawn whole.
    figure, ax = plt.subplots()
    ax.fill_between([0, 1], -1000, 1000)
    assert keep_to_seeds(ax, 20.0, 80.0) and ax.get_ylim() == (-40.0, 140.0)
    ax.set_ylim(0, 100)
    assert not keep_to_seeds(ax, 20.0, 80.0) and ax.get_ylim() == (0, 100)
    plt.close(figure)

    # The last scoring's bars carry a t-interval over seeds; one seed has none to draw, and says so.
    for group, interval in (([runs], True), ([runs[:1]], False)):
        figure = _final_scores_figure("hopper", runs[0].set_names, group)
        ax = figure.axes[0]
        assert any(type(container).__name__ == "ErrorbarContainer" for container in ax.containers) == interval
        assert ("bars: 95% t-interval" in ax.get_title()) == interval
        assert ("one seed per curve: no interval" in ax.get_title()) == (not interval)
        assert ("are cut at the axes" in ax.get_title()) == interval  # as the curves' bands, these 2 seeds' bars
        # The curve's clean return at that record, dashed: what hiding each set costs.
        (clean,) = [line for line in ax.get_lines() if line.get_linestyle() == "--"]
        clean_mean = np.mean([run.clean_score[-1] for run in group[0]])
        np.testing.assert_allclose(clean.get_ydata(), [clean_mean] * 2)
        assert clean.get_label() == f"{runs[0].curve}: clean return {clean_mean:.1f} (nothing hidden)"
        plt.close(figure)
    # So do the curves' captions: a band is promised only where one is drawn, and said cut where one
    # reaches past the axes (these 2 seeds' band does in Figure 1's panel).
    captions = _captions(monkeypatch)
    for run_dirs, interval in ((paths, True), (paths[:1], False)):
        plot_envs_side_by_side(run_dirs, str(tmp_path / "side"))
        plot_runs(run_dirs, str(tmp_path / "curves"))
        assert captions["figure1"][1] == interval
        for caption, cut in (captions.pop(name) for name in ("figure1", "min_score")):
            assert ("shaded: 95% t-interval over seeds" in caption) == interval
            assert (CUT_BANDS in caption) == cut, caption
    monkeypatch.undo()

    # The CLI writes into a new folder each time, never over earlier figures, and its
    # summary says how the figure was smoothed.
    root = str(tmp_path / "runs")
    asked = []  # what the CLI's per_seed= reaches the panels as
    monkeypatch.setattr("admissable_jax.plot.draw_curves", lambda *args: asked.append(args[-1]) or draw_curves(*args))
    assert main([root, "formats=png"]) == 0 and main([root, "window=40", "formats=png", "per_seed=true"]) == 0
    assert asked == [False] * 3 + [True] * 3  # min_u a_u, mean_u a_u and clean return, each run
    monkeypatch.undo()
    assert sorted(name for name in os.listdir(root) if name.startswith("figures")) == ["figures", "figures-2"]
    with open(os.path.join(root, "figures", "summary.md")) as file:
        assert "moving average over 1 record (the paper's 40 of 200, scaled to the runs' 7)" in file.read()
    with open(os.path.join(root, "figures-2", "summary.md")) as file:
        assert "moving average over 7 records (window=40 shortened: the runs have 7)" in file.read()
    with pytest.raises(SystemExit) as exit_info:
        main([root, "window=-1"])
    assert exit_info.value.code == 2
    assert capsys.readouterr().err.strip().splitlines()[-1] == ("error: window must be an int >= 0 (0: the paper's "
                                                                 "40 of 200 records, scaled to the runs), got -1")
    # A figure that cannot be written (pgf without LaTeX, a full disk): one line, exit 2.
    from matplotlib.figure import Figure

    def no_latex(*args, **kwargs):
        raise RuntimeError("'xelatex' not found; install it\nor change rcParams")

    monkeypatch.setattr(Figure, "savefig", no_latex)
    with pytest.raises(SystemExit) as exit_info:
        main([root, f"out={tmp_path / 'pgf'}", "formats=pgf"])
    assert exit_info.value.code == 2
    assert capsys.readouterr().err.strip().splitlines()[-1] == (
        f"error: cannot write {tmp_path / 'pgf' / 'min_score.pgf'}: 'xelatex' not found; install it")
    monkeypatch.undo()
    # Rows that do not hold one score per candidate set: one line naming the file, exit 2.
    narrow = _fake_run(str(tmp_path / "narrow"), "uniform", 0, records=2, sets=3)
    with pytest.raises(SystemExit) as exit_info:
        main([narrow])
    assert exit_info.value.code == 2
    assert capsys.readouterr().err.strip().splitlines()[-1] == (
        f"error: {narrow}/scores.jsonl: each row must hold 11 scores and p_miss values (one per set of hopper "
        "with k=1), got (3,) and (3,)")
    # A folder of figures whose runs are packed beside them, as benchmarks/results keeps a
    # campaign's: the error names the archive to unpack.
    packed = tmp_path / "packed"
    (packed / "hopper" / "figures").mkdir(parents=True)
    with tarfile.open(packed / "runs.tar.xz", "w:xz") as tar:
        tar.add(narrow, arcname="hopper/uniform-s0")
    with pytest.raises(SystemExit) as exit_info:
        main([str(packed / "hopper")])
    assert exit_info.value.code == 2
    assert capsys.readouterr().err.strip().splitlines()[-1] == (
        f"error: no run directories (config.yaml + scores.jsonl) under {packed / 'hopper'}; are they packed in "
        f"{packed / 'runs.tar.xz'}? unpack it (mkdir DIR && tar -xf {packed / 'runs.tar.xz'} -C DIR) and give DIR")


def test_long_runs_and_large_candidate_sets_stay_readable(tmp_path, monkeypatch):
    """A 1M-step run's axis reads 200k ... 1M (its six-digit ticks overlapped on a narrow
    panel); a U of more sets than a figure can give a row each (Walker2d at k = 2: 136) is
    drawn per feature, as a pool is, with its lowest sets as the bars (Ant at k = 2 drew
    two 76,000-pixel heatmaps in 141 s)."""
    import matplotlib.pyplot as plt

    assert [steps_text(steps) for steps in (0, 500, 2500, 20000, 255000, 1e6, 1.5e6)] == [
        "0", "500", "2.5k", "20k", "255k", "1M", "1.5M"]
    long_run = load_run(_fake_run(str(tmp_path / "long"), "adversarial", 0, records=200))
    figure, ax = plt.subplots(figsize=(5.5, 4))
    draw_curves(ax, [long_run], "min_score", 40)
    figure.canvas.draw()
    low, high = ax.get_xlim()
    assert [label.get_text() for label, tick in zip(ax.get_xticklabels(), ax.get_xticks()) if low <= tick <= high] == [
        "0", "200k", "400k", "600k", "800k", "1M"]
    plt.close(figure)

    # Per feature: the lowest a_u of the sets hiding it and the p_miss mass on them.
    members = np.array([[1, 1, 0, 0], [0, 1, 1, 0], [1, 0, 1, 0]])
    np.testing.assert_allclose(per_feature_of_sets(np.array([[5.0, 2.0, 7.0]]), members, "scores"), [[5, 2, 2, np.nan]])
    np.testing.assert_allclose(per_feature_of_sets(np.array([[0.2, 0.3, 0.5]]), members, "p_miss"), [[0.7, 0.5, 0.8, 0]])

    pairs = load_run(_fake_run(str(tmp_path / "pairs"), "adversarial", 0, records=3, sets=136, env="walker2d", k=2))
    features = observation_names("walker2d")
    drawn = []
    monkeypatch.setattr("admissable_jax.plot._save", lambda figure, out_dir, name, formats: drawn.append((name, figure)) or [])
    plot_runs([pairs.path], str(tmp_path / "figures"))
    heatmaps = {name: figure.axes[0] for name, figure in drawn if name in ("scores_adversarial", "p_miss_adversarial")}
    for name, ax in heatmaps.items():
        assert ax.get_ylim() == (len(features) - 0.5, -0.5) and ax.get_ylabel() == "feature (over the 136 sets hiding it)"
        assert [label.get_text() for label in ax.get_yticklabels()] == features
    rows = per_feature_of_sets(pairs.scores, pairs.set_members, "scores")
    np.testing.assert_allclose(heatmaps["scores_adversarial"].collections[0].get_array().reshape(len(features), -1),
                               rows.T)
    bars_axis = dict(drawn)["final_scores"].axes[0]
    lowest = np.argsort(pairs.scores[-1], kind="stable")[:LOWEST_BARS]
    assert [label.get_text() for label in bars_axis.get_xticklabels()] == [pairs.set_names[i] for i in lowest]
    np.testing.assert_allclose([bar.get_height() for bar in bars_axis.patches], pairs.scores[-1][lowest])
    assert f"the {LOWEST_BARS} lowest of 136 sets" in bars_axis.get_title()
    for _, figure in drawn:
        plt.close(figure)
