"""benchmarks/figure1.py: the campaign's FIGURE1.md, computed from run directories
(synthetic histories; no training)."""

import json
import os
import shutil
import subprocess
import sys

import numpy as np

import common  # benchmarks/ is on the tests' path (conftest.py)
import figure1
from test_plots import _edit_rows, _run_with_minimums

from admissable_jax.results import Difference, load_run

FIGURE1 = figure1.__file__


def _figure1(*args: str) -> int:
    """figure1.py's exit status, run in this process (its imports cost seconds per process)."""
    try:
        return figure1.main(list(args))
    except SystemExit as exit:
        return exit.code


def _audit_of_final_policy(run, set_scores: list[float], clean: float, policy_file: str,
                           pair_scores: tuple[float, ...] = ()) -> None:
    """``run/audit-final/audit.json`` as ``audit policy=run/exported/POLICY_FILE`` writes it
    (the fields figure1.py reads): N = 50, the k = 1 sets' a_u (and k = 2's, where given)
    and the clean return."""
    (run / "audit-final").mkdir(exist_ok=True)
    sets = {"1": [{"hidden": [index], "score": score} for index, score in enumerate(set_scores)]}
    if pair_scores:
        sets["2"] = [{"hidden": [0, index + 1], "score": score} for index, score in enumerate(pair_scores)]
    (run / "audit-final" / "audit.json").write_text(json.dumps({
        "env": "Hopper-v5", "n_episodes": 50, "clean_score": clean, "sets": sets,
        "source": {"Gymnasium env": "Hopper-v5", "policy": str(run / "exported" / policy_file)}}))


def test_figure1_computes_the_verdict_and_the_clean_sac_check(tmp_path, capsys, monkeypatch):
    """Hand-computed: adversarial finals 40, 60 against uniform 8, 10 (Welch: +41.0
    [-80.9, 162.9], p = 0.149); the same runs' final policies audited afresh. Mode none's final clean returns at 1M env steps against SB3's
    Hopper 2,326 ± 1,130 (mean − 1 sd = 1196), two seeds so ± t(0.975, 1) · 70.7 / √2 = 635.3:
    500 and 600 give [-85.3, 1185.3], under 1196: clearly below; 1000 and 1100 give
    [414.7, 1685.3]: within. The same at 20,000 env steps: not comparable yet."""
    root = tmp_path / "hopper"
    _run_with_minimums(str(root), "adversarial", 0, [10, 20, 30, 40], 100)
    _run_with_minimums(str(root), "adversarial", 1, [20, 30, 50, 60], 120)
    _run_with_minimums(str(root), "uniform", 0, [5, 6, 7, 8], 90)
    _run_with_minimums(str(root), "uniform", 1, [5, 6, 9, 10], 94)
    _run_with_minimums(str(root), "none", 0, [1, 2, 3, 4], 500, score_every=250_000)
    _run_with_minimums(str(root), "none", 1, [1, 2, 3, 4], 600, score_every=250_000)
    _run_with_minimums(str(root), "worst", 0, [5, 6, 7, 8], 90)  # mode worst, as uniform did: against it +41.0 too
    _run_with_minimums(str(root), "worst", 1, [5, 6, 9, 10], 94)
    # The program's times, in each run's metrics: chunks of 5,000 env steps at 2,500 env steps/s
    # (2 s each), scoring rounds of 1-4 s: 18 s in all; 196 scorings left to 1M at 2 + 2.5 s.
    # Every run timed every interval, so the wall-time figure is drawn and shown.
    for run in root.iterdir():
        steps = [json.loads(line)["env_steps"] for line in (run / "scores.jsonl").read_text().splitlines()]
        with open(run / "metrics.jsonl", "w") as file:
            for env_steps, seconds in zip(steps, (1.0, 2.0, 3.0, 4.0)):
                file.write(json.dumps({"env_steps": env_steps, "env_steps_per_s": 2500.0, "score_seconds": seconds,
                                       "runs_in_program": 6}) + "\n")
    # Where they were trained: two runs' records of one setup, as the host loop writes them.
    record = {"device": "gpu:NVIDIA H200", "devices": 1, "physics": "warp", "commit": "abc1234",
              "versions": {"jax": "0.10.2", "mujoco": "3.5.0", "warp-lang": "1.19.0"}}
    for name in ("adversarial-s0", "uniform-s0"):
        (root / name / "invocations.jsonl").write_text(json.dumps(record) + "\n")
    # The final policies of the adversarial and uniform runs audited afresh (audit policy=FILE.npz
    # into <run>/audit-final): their lowest set's a_u 50, 70 against 10, 12 (Welch: +49.0
    # [-72.9, 170.9], p = 0.125; ± t(0.975, 1) · sd / √2: 127.1 and 12.7); mode none's unaudited.
    # One audit also scored pairs (k=1,2), which the runs' U (k = 1) does not hold: not counted.
    for name, sets, clean in (("adversarial-s0", [55, 50], 1000), ("adversarial-s1", [70, 80], 1100),
                              ("uniform-s0", [10, 30], 900), ("uniform-s1", [40, 12], 900)):
        _audit_of_final_policy(root / name, sets, clean, "policy-step20000.npz", (1.0,) * (name == "adversarial-s0"))
    out = tmp_path / "FIGURE1.md"
    # The commit FIGURE1.md names is the code's: taken before its own outputs are written, and
    # blind to benchmarks/results (where the runs and figures live, tracked), as git would mark
    # the checkout +changes once figure1.png is redrawn or a run's figures moved.
    monkeypatch.setattr(common, "source_commit", lambda exclude=(): "feed123" + (
        "+changes" if (tmp_path / "figure1.png").exists() or "benchmarks/results" not in exclude else ""))
    assert _figure1(f"hopper={root}", "window=2", f"out={out}", "formats=svg") == 0
    text = out.read_text()
    assert " at commit feed123, from the runs'" in text
    assert ("Trained on (the runs' `invocations.jsonl`): gpu:NVIDIA H200 × 1, warp physics, jax 0.10.2, mujoco 3.5.0, "
            "warp-lang 1.19.0, commit abc1234 (2 of 2 records).") in text
    assert ("Cost (measured, the program of 6 runs, compiling not counted): 4 scorings in 18 s; a training chunk of "
            "5,000 env steps per run 2.00 s (median), a scoring round 2.50 s on average, 2.50 s over the last 4. "
            "1M env steps projected at 900 s (15.0 min): the remaining 196 scorings") in text
    assert "| hopper | 20,000 | final min_u a_u | +41.0 | 1.00 [1.00, 1.00] | not distinguishable (95% interval holds 0) |" in text
    # The top table's second row: AUC, mean(25, 40) − mean(6.5, 7.5) = +25.5.
    assert "| hopper | 20,000 | AUC min_u a_u | +25.5 | 1.00 [1.00, 1.00] | not distinguishable (95% interval holds 0) |" in text
    assert ("- final min_u a_u: adversarial − uniform = +41.0 [-80.9, 162.9], p = 0.149, P(adversarial > uniform) "
            "= 1.00 [1.00, 1.00]: the seeds cannot tell "
            "the modes apart (the 95% interval holds 0); about 4 seeds per mode would (80% power at the difference "
            "and spread seen); every seed of one mode ends above every seed of the other, an order chance alone gives "
            "with p = 0.333 (Mann–Whitney, exact; the bootstrap interval cannot widen past one value then).") in text
    assert ("Clean SAC (mode `none`, 2 seeds): final clean return 550.0 [-85.3, 1185.3] against the SB3 RL-Zoo "
            "SAC at 1M, 2,326 ± 1,130 (v3 envs): clearly below SB3's (our 95% interval lies under its mean − 1 sd).") in text
    assert "(8 runs, 20,000 env steps each, not the paper's 1M)" in text
    assert ("Adversarial − worst (the paper's stochastic adversary against the deterministic one it decides against "
            "\"to avoid training instabilities and forgetting\", §3):\n\n| env | metric | adversarial − worst |"
            ) in text
    assert "- final min_u a_u: adversarial − worst = +41.0 [-80.9, 162.9], p = 0.149, P(adversarial > worst)" in text
    assert ("**The final policies, audited afresh** (4 of 8 runs, `<run>/audit-final/`: Gymnasium's own C-MuJoCo env, "
            "new start states, 50 episodes per set, against the training's last scoring of 10;") in text
    assert "| adversarial | 2 | 60.0 ± 127.1 | 50.0 ± 127.1 | 1050.0 ± 635.3 |" in text
    assert "| uniform | 2 | 11.0 ± 12.7 | 9.0 ± 12.7 | 900.0 ± 0.0 |" in text and "\n| none |" not in text
    assert ("| audited final min_u a_u | +49.0 | [-72.9, 170.9] | 0.125 | 1.00 [1.00, 1.00] | not distinguishable "
            "(95% interval holds 0) |") in text
    # ...which the verdict and the top table name too.
    assert "- audited final min_u a_u: adversarial − uniform = +49.0 [-72.9, 170.9], p = 0.125, P(adversarial" in text
    assert ("| hopper | 20,000 | audited final min_u a_u | +49.0 | 1.00 [1.00, 1.00] | not distinguishable (95% interval "
            "holds 0) |") in text
    assert "![min_u a_u, mean_u a_u and clean return](hopper/figures/min_score.png)" in text
    assert "![min_u a_u against the wall time of training and scoring](hopper/figures/min_score_by_time.png)" in text
    assert "![every env's min_u a_u, as the paper's Figure 1 lays it out](figure1.png)" in text
    # The formats asked for, and PNG always (the file shows the PNGs).
    assert sorted(path.name for path in tmp_path.glob("figure1.*")) == ["figure1.png", "figure1.svg"]
    assert {path.suffix for path in (root / "figures").iterdir()} == {".png", ".svg", ".csv"}
    assert ("Every scoring of every run, as tidy tables for one's own analysis: `hopper/figures/curves.csv` (a row "
            "per run and scoring) and `hopper/figures/scores.csv` (a row per run, scoring and hidden set).") in text

    within, young = tmp_path / "within", tmp_path / "young"
    for seed, clean in enumerate((1000, 1100)):
        _run_with_minimums(str(within), "none", seed, [1, 2, 3, 4], clean, score_every=250_000)
        _run_with_minimums(str(young), "none", seed, [1, 2, 3, 4], clean)
    drawn = []  # per_seed=true reaches both figures (each seed's thin line: test_plots)
    for name in ("plot_runs", "plot_envs_side_by_side"):
        monkeypatch.setattr(figure1, name, lambda *args, draw=getattr(figure1, name): drawn.append(args[-1]) or draw(*args))
    assert _figure1(f"hopper={within}", f"out={out}", "formats=png", "per_seed=true") == 0
    assert drawn == [True, True]
    monkeypatch.undo()
    assert "Trained on: not recorded (runs written before `invocations.jsonl`)." in out.read_text()
    assert ("final clean return 1050.0 [414.7, 1685.3] against the SB3 RL-Zoo SAC at 1M, 2,326 ± 1,130 (v3 envs): "
            "within SB3's spread (our 95% interval reaches its mean ± 1 sd).") in out.read_text()
    # What a person noted under the computed part stays at the end when the file is written again.
    notes = "## Noted by hand\n\n- the runs are in runs.tar.xz\n"
    out.write_text(out.read_text() + "\n" + notes)
    assert _figure1(f"hopper={young}", f"out={out}", "formats=png") == 0
    assert "(v3 envs): not comparable yet (at 20,000 env steps, not the reference's 1M)." in out.read_text()
    assert out.read_text().endswith("/scores.csv` (a row per run, scoring and hidden set).\n\n" + notes)
    assert capsys.readouterr().out.endswith(f"written: {out} (its section '## Noted by hand' kept at the end)\n")

    # A folder given for the wrong env (the command itself, as a user runs it), or none at
    # all: one line, exit 2, nothing written.
    wrong = subprocess.run([sys.executable, FIGURE1, f"walker2d={root}", f"out={tmp_path / 'wrong.md'}"],
                           capture_output=True, text=True, env={**os.environ, "JAX_PLATFORMS": "cpu"})
    assert wrong.returncode == 2 and wrong.stderr.strip() == f"error: walker2d={root} holds runs of hopper"
    assert not (tmp_path / "wrong.md").exists()
    capsys.readouterr()
    assert _figure1() == 2
    assert capsys.readouterr().err.strip() == "error: give at least one of hopper=DIR, walker2d=DIR, ant=DIR"
    # Runs of other settings in one env's folder would be two experiments, not one comparison.
    mixed = tmp_path / "mixed"
    shutil.copytree(root / "uniform-s0", mixed / "uniform-s0")
    shutil.copytree(root / "uniform-s1", mixed / "uniform-s1")
    config = mixed / "uniform-s1" / "config.yaml"
    config.write_text(config.read_text().replace("score_episodes: 10", "score_episodes: 5"))
    assert _figure1(f"hopper={mixed}", f"out={tmp_path / 'mixed.md'}") == 2
    assert capsys.readouterr().err.strip() == (
        f"error: the runs in {mixed} differ in score_episodes: Figure 1 compares the modes at one setting per env "
        "(plot draws each setting as its own curve)")
    assert not (tmp_path / "mixed.md").exists()
    # An audit of another policy than the run's final one (an earlier lease's): one line.
    _audit_of_final_policy(root / "uniform-s1", [40, 12], 900, "policy-step15000.npz")
    assert _figure1(f"hopper={root}", f"out={tmp_path / 'stale.md'}") == 2
    audit = root / "uniform-s1" / "audit-final" / "audit.json"
    assert capsys.readouterr().err.strip() == (
        f"error: {audit} audits policy-step15000.npz, not the run's final policy-step20000.npz: audit that into "
        "audit-final/ (benchmarks/README.md, Step 5)")
    assert not (tmp_path / "stale.md").exists() and not (root / "figures-2").exists()  # checked before drawing
    # ...or one without a set size of the runs' U (here pairs only), or a file that is no
    # audit's (here without its sets): one line naming it.
    _audit_of_final_policy(root / "uniform-s1", [], 900, "policy-step20000.npz", (40.0, 12.0))
    assert _figure1(f"hopper={root}", f"out={tmp_path / 'stale.md'}") == 2
    assert capsys.readouterr().err.strip() == (f"error: {audit} audits sets of size 2, not every size of the run's U "
                                               "(1): audit it with its default k")
    audit.write_text(json.dumps({"n_episodes": 50, "clean_score": 900.0, "source": {"policy": "policy-step20000.npz"}}))
    assert _figure1(f"hopper={root}", f"out={tmp_path / 'stale.md'}") == 2
    assert capsys.readouterr().err.strip() == f"error: {audit} is no audit's audit.json (KeyError: 'sets')"
    _audit_of_final_policy(root / "uniform-s1", [40, 12], 900, "policy-step20000.npz")

    # Ctrl-C midway: one line, exit 130, FIGURE1.md not written; the figures folder stays if it
    # holds a figure, and goes if it was made and holds none.
    import admissable_jax.plot

    def ctrl_c(*args):
        raise KeyboardInterrupt
    for module, where, said in ((figure1, "write_tables", f"the figures drawn so far are in {young / 'figures-2'}"),
                                (admissable_jax.plot, "draw_curves", "no figures written")):  # in the folder, before any figure
        shutil.rmtree(young / "figures-2", ignore_errors=True)
        with monkeypatch.context() as patched:
            patched.setattr(module, where, ctrl_c)
            try:
                status = _figure1(f"hopper={young}", f"out={tmp_path / 'stopped.md'}", "formats=png")
            except KeyboardInterrupt:
                status = "a traceback"
        assert status == 130
        assert capsys.readouterr().err.strip().splitlines()[-1] == (
            f"interrupted: {tmp_path / 'stopped.md'} not written; {said}; the runs are untouched")
        assert (young / "figures-2").exists() == (where == "write_tables")
        assert not (tmp_path / "stopped.md").exists()


def test_figure1_words_each_reading_the_clean_check_above_sb3_and_the_late_rounds_cost(tmp_path):
    """figure1.py's own lines, without figures. Each reading in its words: finals 200, 210
    against 10, 12 (+194.0) read adversarial higher, the same swapped uniform higher. Mode
    none at 1M against SB3's Hopper 2,326 ± 1,130 (mean + 1 sd = 3,456), two seeds 10 apart
    (± t(0.975, 1) · 7.07 / √2 = 63.5): 3,700 and 3,710 give [3641.5, 3768.5], clearly above;
    3,000 and 3,010 give [2941.5, 3068.5], over SB3's mean but within its spread. The cost
    line: 12 scorings, chunks of 5,000 env steps at 2,500 env steps/s (2 s), rounds of 1 to
    12 s (late rounds run longest): 24 + 78 = 102 s at 60,000 env steps, 188 scorings left
    to 1M at 2 s + the last ten rounds' mean 7.5 s: 102 + 188 · 9.5 = 1,888 s."""
    higher = figure1._verdict(Difference("final min_u a_u", np.array([200.0, 210.0]), np.array([10.0, 12.0])))
    assert higher.startswith("final min_u a_u: adversarial − uniform = +194.0 [")
    separated = ("; every seed of one mode ends above every seed of the other, an order chance alone gives with "
                 "p = 0.333 (Mann–Whitney, exact; the bootstrap interval cannot widen past one value then).")
    assert higher.endswith(": adversarial training is higher, and 0 lies outside the 95% interval" + separated)
    lower = figure1._verdict(Difference("AUC min_u a_u", np.array([10.0, 12.0]), np.array([200.0, 210.0])))
    assert lower.startswith("AUC min_u a_u: adversarial − uniform = -194.0 [")
    assert lower.endswith(": uniform training is higher, and 0 lies outside the 95% interval" + separated)
    worst_higher = figure1._verdict(
        Difference("final min_u a_u", np.array([10.0, 12.0]), np.array([200.0, 210.0]), baseline_mode="worst"))
    assert worst_higher.startswith("final min_u a_u: adversarial − worst = -194.0 [")
    assert worst_higher.endswith(": worst training is higher, and 0 lies outside the 95% interval" + separated)
    assert figure1._verdict(Difference("final min_u a_u", np.array([40.0]), np.array([8.0, 10.0]))) == (
        "final min_u a_u: adversarial − uniform = +31.0 (one seed in a mode: no test).")

    def clean_line(folder, returns):
        """The check of mode none's seeds, each clean return climbing to ``returns`` at 1M: the last scoring's counts."""
        runs = []
        for seed, clean in enumerate(returns):
            minimums = [1, 2, 3, 4]  # a scoring each
            path = _run_with_minimums(str(tmp_path / folder), "none", seed, minimums, clean, score_every=250_000)
            _edit_rows(path, lambda t, row: {**row, "clean_score": clean * (t + 1) / len(minimums)})
            runs.append(load_run(path))
        return figure1._clean_sac_line("hopper", runs)
    assert clean_line("above", (3700, 3710)).endswith(
        "final clean return 3705.0 [3641.5, 3768.5] against the SB3 RL-Zoo SAC at 1M, 2,326 ± 1,130 (v3 envs): "
        "clearly above SB3's (our 95% interval lies over its mean + 1 sd).")
    assert clean_line("upper", (3000, 3010)).endswith(
        "final clean return 3005.0 [2941.5, 3068.5] against the SB3 RL-Zoo SAC at 1M, 2,326 ± 1,130 (v3 envs): "
        "within SB3's spread (our 95% interval reaches its mean ± 1 sd).")

    run = _run_with_minimums(str(tmp_path / "cost"), "adversarial", 0, [1, 2], 10)
    with open(os.path.join(run, "metrics.jsonl"), "w") as file:
        for t in range(12):
            file.write(json.dumps({"env_steps": 5000 * (t + 1), "env_steps_per_s": 2500.0,
                                   "score_seconds": float(t + 1), "runs_in_program": 2}) + "\n")
    assert figure1._cost_line([run]) == (
        "Cost (measured, the program of 2 runs, compiling not counted): 12 scorings in 102 s; a training chunk of "
        "5,000 env steps per run 2.00 s (median), a scoring round 6.50 s on average, 7.50 s over the last 10. "
        "1M env steps projected at 1,888 s (31.5 min): the remaining 188 scorings at the median chunk and the "
        "last 10 rounds' mean.")
    assert figure1._cost_line([str(tmp_path / "above" / "none-s0")]) == "Cost: not measured (no `metrics.jsonl`)."
