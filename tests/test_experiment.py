"""Seeds × modes in one vmapped program (``admissable_jax.experiment``) and the quickstart notebook."""

from __future__ import annotations

import dataclasses
import json
import os
import re
import shutil
import types

import jax
import jax.numpy as jnp
import nbformat
import numpy as np
import pytest
from nbclient import NotebookClient

from admissable_jax import mask_observation
from admissable_jax.config import ExperimentConfig, curve_names, pair_configs
from admissable_jax.envs import observation_names
from admissable_jax.errors import INTERRUPTED
from admissable_jax.experiment import main as experiment_main
from admissable_jax.experiment import run_experiment, scored_up_to
from admissable_jax.plot import plot_runs
from admissable_jax.results import Difference, estimate, find_runs, mode_differences, summary_table
from admissable_jax.memory import MemoryBudgetExceeded
from admissable_jax.method import inverse_score_p_miss, parse_set
from admissable_jax.audit import AuditConfig, audit_experiment, audit_run
from admissable_jax.audit import main as audit_main  # the command line, in this process
from admissable_jax.export import main as export_main
from admissable_jax.exported_policy import ExportedPolicy
from admissable_jax.placement import PairPlacement
from admissable_jax.policies import checkpoint_steps, load_policy

EXPERIMENT = dict(
    env="point_mass", seeds=2, modes="adversarial,uniform", score_every=1000, num_envs=4,
    learning_starts=500, episode_length=50, score_episodes=2, batch_size=64, buffer_size=5000, hidden_size=32,
    checkpoint_every=1, progress=False,
)
REPO = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


def _scores(root: str) -> dict[str, list]:
    return {
        name: [json.loads(line)["scores"] for line in open(os.path.join(root, name, "scores.jsonl"))]
        for name in sorted(os.listdir(root)) if os.path.isfile(os.path.join(root, name, "scores.jsonl"))
    }


def test_experiment_runs_pairs_resumes_as_one_unit_and_plots(tmp_path, capsys, monkeypatch):
    spread, programs = PairPlacement.spread, []  # how each program spreads its pairs
    monkeypatch.setattr(PairPlacement, "spread", lambda placement, per_pair, in_turn=False: (
        programs.append((per_pair.__name__, in_turn)) or spread(placement, per_pair, in_turn)))
    pair_state, taken = PairPlacement.pair_state, []  # which pairs' states were taken from the experiment's
    monkeypatch.setattr(PairPlacement, "pair_state", lambda placement, tree, pair: (
        taken.append(pair) or pair_state(placement, tree, pair)))
    straight = run_experiment(ExperimentConfig(**EXPERIMENT, total_steps=3000, out=str(tmp_path / "straight")))
    monkeypatch.setattr(PairPlacement, "spread", spread)
    # The pairs train vmapped; on a CPU, where a batched step costs each pair's work, they score
    # one after another (vmapped, every pair would step until the slowest round ends).
    assert sorted(set(programs)) == [("<lambda>", False), ("init", False), ("score_and_update", True)], programs
    assert [(r.config.missingness, r.config.seed) for r in straight] == [
        ("adversarial", 0), ("adversarial", 1), ("uniform", 0), ("uniform", 1)]
    for result in straight:
        assert sorted(os.listdir(result.run_dir)) == ["best_policy.npz", "config.yaml", "invocations.jsonl",
                                                      "metrics.jsonl", "observation_names.json", "scores.jsonl"]
        (invocation,) = [json.loads(line) for line in open(os.path.join(result.run_dir, "invocations.jsonl"))]
        assert invocation["runs_in_program"] == 4 and invocation["from_env_steps"] == 0
        assert [row["env_steps"] for row in result.scores] == [1000, 2000, 3000]
        assert result.metrics[-1]["runs_in_program"] == 4
        if result.config.missingness == "uniform":
            np.testing.assert_allclose(result.scores[-1]["p_miss"], 0.25)
        else:
            assert not np.allclose(result.scores[-1]["p_miss"], 0.25)
    # Seeds differ, so pairs of one mode differ.
    assert straight[0].scores[-1]["scores"] != straight[1].scores[-1]["scores"]
    # A pair's policy outside the trainer: the experiment's checkpoint, that pair's part. The
    # result's state is that pair's part of the experiment's final state, taken when first read,
    # not every pair's at the run's end (copies of their replay buffers: GBs).
    policy = load_policy(straight[2].run_dir)
    assert taken == []
    for kept, saved in zip(jax.tree.leaves(straight[2].actor_params), jax.tree.leaves(policy.actor_params), strict=True):
        np.testing.assert_array_equal(kept, saved)
    assert straight[2].state is straight[2].state and taken == [2]
    # Each pair keeps its own best policy: that pair's networks at its best scoring, as the
    # experiment's checkpoint holds them where one was kept at that step.
    compared = 0
    for result in straight:
        best_row = max(result.scores, key=lambda row: row["min_score"])
        best = load_policy(result.run_dir, "best")
        assert (best.step, best.best_min_score) == (best_row["env_steps"], best_row["min_score"])
        if best.step in checkpoint_steps(result.run_dir):
            at_checkpoint, compared = load_policy(result.run_dir, best.step), compared + 1
            for kept, saved in zip(jax.tree.leaves(best.actor_params), jax.tree.leaves(at_checkpoint.actor_params)):
                np.testing.assert_array_equal(kept, saved)
    assert compared >= 2, compared  # (of 4 pairs, those whose best came at a kept checkpoint, 2000 or 3000)
    root = os.path.dirname(straight[2].run_dir)  # the experiment's folder is none of its runs: one line naming one
    with pytest.raises(FileNotFoundError, match=rf"^{root} is not a run directory \(no config.yaml\); the runs under "
                                                rf"it are its folders, like {root}/adversarial-s0$"):
        load_policy(root)
    # Exported, each pair's best (python -m admissable_jax.export EXPERIMENT best=true): into its own folder.
    assert export_main([root, "best=true"]) == 0
    lines = capsys.readouterr().out.splitlines()
    assert len(lines) == len(straight)
    for result, line in zip(straight, lines):
        best = load_policy(result.run_dir, "best")
        path = os.path.join(result.run_dir, "exported", f"policy-best-step{best.step}.npz")
        assert line.startswith(f"wrote {path}: point_mass {result.config.missingness} seed {result.config.seed} at env "
                               f"step {best.step}, ")
        exported = ExportedPolicy.load(path)
        assert exported.source["best_min_score"] == best.best_min_score
        masked = np.random.default_rng(1).normal(size=(5, 8)).astype(np.float32)
        np.testing.assert_allclose(exported.masked(masked), best.masked(masked), rtol=1e-5, atol=1e-6)
    assert export_main([root, "best=true", f"out={tmp_path / 'one.npz'}"]) == 2
    assert capsys.readouterr().err.startswith(f"error: {root} is an experiment: each pair's policy goes into its own")
    # A train run into the experiment's folder, or continuing one of its pairs alone (whose
    # checkpoints are the experiment's), is refused, naming the command that continues it; so
    # is an experiment into a train run's folder (they said "already holds a run" or "no
    # checkpoint to resume from", and a train run would have written into the experiment's).
    from admissable_jax import train_fn

    pair = straight[0].config
    refused = {root: "an experiment", pair.out: f"a pair of the experiment in {root}, whose checkpoints hold every pair"}
    for out, resume in ((root, False), (pair.out, True)):
        with pytest.raises(FileExistsError, match=rf"^{out} is {refused[out]}: choose another out, or continue it with "
                                                  rf"python -m admissable_jax.experiment resume=true out={root}$"):
            train_fn(dataclasses.replace(pair, out=out, resume=resume))
    assert sorted(os.listdir(root)) == ["adversarial-s0", "adversarial-s1", "checkpoints", "experiment.yaml",
                                        "uniform-s0", "uniform-s1"]
    lone = tmp_path / "lone"
    lone.mkdir()
    shutil.copy(os.path.join(pair.out, "config.yaml"), lone)
    with pytest.raises(FileExistsError, match=rf"^{lone} is a train run: choose another out, or continue it with "
                                              rf"python -m admissable_jax.train resume=true out={lone}$"):
        run_experiment(ExperimentConfig(**EXPERIMENT, total_steps=3000, out=str(lone)))
    assert sorted(os.listdir(lone)) == ["config.yaml"]
    obs = np.random.default_rng(0).normal(size=(5, 4)).astype(np.float32)
    expected = jax.vmap(straight[2].trainer.policy, (None, 0))(straight[2].actor_params, mask_observation(obs, np.array([0, 1, 0, 0])))
    assert policy.step == 3000 and policy.config.missingness == "uniform"
    np.testing.assert_allclose(policy(obs, hidden=[1]), expected, rtol=1e-5, atol=1e-6)
    with pytest.raises(ValueError, match=r"^expected observations of 4 features, got shape \(5, 8\); a masked "
                                         r"observation \(8: features, then the indicator\) goes to the policy's "
                                         r"\.masked\(batch\)$"):
        policy(np.concatenate([obs, obs], axis=1))  # an 8-wide row is no two 4-wide ones, but may be one masked
    # The whole experiment audited: every pair into its own folder, then the modes compared per k.
    results, written = audit_experiment(AuditConfig(run_dir=str(tmp_path / "straight"), k="1,2", episodes=3,
                                                    shapley="exact", dropout="0.3", dropout_masks=4))
    assert [(result.source["mode"], result.source["seed"]) for result in results] == [
        ("adversarial", 0), ("adversarial", 1), ("uniform", 0), ("uniform", 1)]
    assert written[-1] == str(tmp_path / "straight" / "audit-step3000" / "comparison.md")
    assert os.path.isfile(tmp_path / "straight" / "uniform-s1" / "audit-step3000" / "report.md")
    pairless = tmp_path / "pairless"  # an experiment whose pairs' folders were moved away
    pairless.mkdir()
    shutil.copy(tmp_path / "straight" / "experiment.yaml", pairless)
    with pytest.raises(FileNotFoundError, match=f"^{pairless} holds an experiment.yaml but no pair directories$"):
        audit_experiment(AuditConfig(run_dir=str(pairless), k="1"))
    alone, _ = audit_run(AuditConfig(run_dir=str(tmp_path / "straight" / "uniform-s1"), k="1,2", episodes=3,
                                     out=str(tmp_path / "alone")))  # its own env and policy function
    for k in (1, 2):
        np.testing.assert_allclose([e.score for e in alone.sets[k]], [e.score for e in results[3].sets[k]], rtol=1e-6)
    comparison = open(written[-1]).read()
    for k in (1, 2):
        worst = [min(entry.score for entry in result.sets[k]) for result in results[2:]]
        average = [np.mean([entry.score for entry in result.sets[k]]) for result in results[2:]]
        assert f"| {k} | uniform | 2 | {np.mean(worst):.1f} ± " in comparison
        assert f" | {np.mean(average):.1f} ± " in comparison.split(f"| {k} | uniform | 2 |")[1].splitlines()[0]
        differences = comparison.split("## Random sensor failure")[0].split("adversarial − uniform")[-1]
        gap = np.mean([min(e.score for e in r.sets[k]) for r in results[:2]]) - np.mean(worst)
        assert f"| {k} | worst a_u | {gap:+.1f} | [" in differences
        gap = np.mean([np.mean([e.score for e in r.sets[k]]) for r in results[:2]]) - np.mean(average)
        assert f"| {k} | mean a_u | {gap:+.1f} | [" in differences
        # 2 seeds per mode cannot tell the modes' worst a_u apart here (the same in both, to
        # about 0.0 ± 13), and far more seeds would be needed than the sentence counts.
        adversarial = [min(e.score for e in r.sets[k]) for r in results[:2]]
        assert Difference("", np.array(adversarial), np.array(worst)).seeds_to_separate() > 1000
        assert f"k={k} worst a_u: over 1,000" in differences.split("Seeds per mode that would tell")[1]
    worth = comparison.split("## What each feature is worth, per mode")[1]  # φ_i per mode, over its pairs
    for i, name in enumerate(["x", "y", "x velocity", "y velocity"]):
        by_mode = [estimate(np.array([result.shapley.values[i] for result in pairs])) for pairs in (results[:2], results[2:])]
        assert f"| {name} | {i} | {by_mode[0]} | {by_mode[1]} |" in worth
    failing = comparison.split("## Random sensor failure, per mode")[1]  # R(p) per mode, then adversarial − uniform
    by_mode = [np.array([result.dropout[0].score for result in pairs]) for pairs in (results[:2], results[2:])]
    assert f"| 0.3 | {estimate(by_mode[0])} | {estimate(by_mode[1])} |" in failing
    assert f"| 0.3 | adversarial | {by_mode[0].mean() - by_mode[1].mean():+.1f} | [" in failing
    # The command line, at an earlier checkpoint (step=): every pair's.
    assert audit_main([str(tmp_path / "straight"), "k=1", "episodes=2", "step=2000", f"out={tmp_path / 'audits'}"]) == 0
    said = capsys.readouterr().out
    for pair in ("adversarial-s0", "uniform-s1"):
        assert "checkpoint (env step) 2000, " in open(tmp_path / "audits" / pair / "report.md").read()
    assert "uniform seed 1: k=1: worst" in said and "| 1 | adversarial | 2 |" in said
    # Each pair's best policy (best=true), each at its own best scoring, compared as one checkpoint's are;
    # here with sensors that fail at env step 20 of the 50, into folders named for both.
    assert audit_main([str(tmp_path / "straight"), "k=1", "episodes=2", "best=true", "fail_at=20"]) == 0
    capsys.readouterr()
    best_steps = {os.path.basename(result.run_dir): max(result.scores, key=lambda row: row["min_score"])["env_steps"]
                  for result in straight}
    for pair, step in best_steps.items():
        record = json.loads((tmp_path / "straight" / pair / f"audit-best-step{step}-fail20" / "audit.json").read_text())
        assert record["source"]["checkpoint (env step)"] == step and record["source"]["kept as"].startswith("its best scoring")
        assert record["fail_at"] == 20
    comparison = (tmp_path / "straight" / "audit-best-fail20" / "comparison.md").read_text()
    assert comparison.startswith(
        "# Robustness audit of an experiment: point_mass, each pair's best scoring (env steps "
        f"{', '.join(f'{step:,}' for step in sorted(set(best_steps.values())))})\n")
    assert "Each pair audited as its own report says (N = 2 episodes per set, `rollout`, sensors failing at env step 20)" in comparison
    # ...and at steps 0 and 20 in one command: each step's audits of every pair, then the modes
    # side by side by failure step, with adversarial − uniform at each.
    assert audit_main([str(tmp_path / "straight"), "k=1", "episodes=2", "best=true", "fail_at=20,0"]) == 0
    printed = capsys.readouterr().out
    times = tmp_path / "straight" / "audit-failure-times-best"
    assert sorted(os.listdir(times)) == ["fail0", "fail20", "failure_times.md", "failure_times.png"]
    worst = {}
    for pair, step in best_steps.items():
        alone = json.loads((tmp_path / "straight" / pair / f"audit-best-step{step}-fail20" / "audit.json").read_text())
        listed = json.loads((times / "fail20" / pair / "audit.json").read_text())
        assert listed["sets"] == alone["sets"] and listed["fail_at"] == 20
        worst.setdefault(pair.split("-")[0], []).append(min(entry["score"] for entry in listed["sets"]["1"]))
    adversarial, uniform = np.array(worst["adversarial"]), np.array(worst["uniform"])
    table = (times / "failure_times.md").read_text()
    assert f"| 1 | 20 | {estimate(adversarial)} | {estimate(uniform)} |" in table
    assert f"| 1 | 20 | adversarial | {adversarial.mean() - uniform.mean():+.1f} | [" in table
    assert "fail_at 20, uniform seed 1: k=1: worst" in printed and table in printed
    assert said.strip().endswith(f"and {tmp_path / 'audits' / 'comparison.md'}")
    assert sorted(os.listdir(tmp_path / "audits")) == ["adversarial-s0", "adversarial-s1", "comparison.md",
                                                       "comparison.png", "uniform-s0", "uniform-s1"]

    resumed_root = str(tmp_path / "resumed")
    run_experiment(ExperimentConfig(**EXPERIMENT, total_steps=2000, out=resumed_root))
    assert sorted(os.listdir(os.path.join(resumed_root, "checkpoints"))) == ["1000", "2000"]
    with pytest.raises(FileExistsError, match="resume=true"):
        run_experiment(ExperimentConfig(**EXPERIMENT, total_steps=3000, out=resumed_root))
    # Resumed from the command line, which ends with what the pairs found: the summary per mode
    # and adversarial − uniform, as plot's summary.md has them.
    argv = [f"{key}={str(value).lower() if isinstance(value, bool) else value}" for key, value in EXPERIMENT.items()]
    pair_folder = os.path.join(resumed_root, "uniform-s1")  # a pair's folder given for its experiment's
    before = sorted(os.listdir(pair_folder))
    capsys.readouterr()  # (what the runs above said)
    status = experiment_main([*argv, "total_steps=3000", f"out={pair_folder}", "resume=true"])
    assert (status, capsys.readouterr().err.strip().splitlines()[-1]) == (  # (it said "nothing to resume")
        2, f"error: {pair_folder} is a pair of the experiment in {resumed_root}, whose checkpoints hold every pair: "
           f"choose another out, or continue it with python -m admissable_jax.experiment resume=true out={resumed_root}")
    assert sorted(os.listdir(pair_folder)) == before  # and nothing was made in it
    elsewhere = str(tmp_path / "elsewhere")  # the records alone, as a lent machine's pack brings them back
    shutil.copytree(resumed_root, elsewhere, ignore=shutil.ignore_patterns("checkpoints"))
    # resume=true out=DIR needs no other key: the experiment's own experiment.yaml gives them;
    # resume=auto is resume=true where the experiment holds a checkpoint, as here.
    assert experiment_main(["total_steps=3000", f"out={resumed_root}", "resume=auto", "progress=false"]) == 0
    assert _scores(resumed_root) == _scores(str(tmp_path / "straight"))
    said, stderr = capsys.readouterr()
    assert f"resume=auto: {resumed_root} holds a checkpoint: resume=true\n" in stderr
    assert f"resume=true: the run's settings from {resumed_root}/experiment.yaml; keys given here override" in stderr
    status = experiment_main(["total_steps=3000", f"out={resumed_root}", "resume=true", "seeds=3"])
    assert (status, capsys.readouterr().err.strip().splitlines()[-1]) == (2, (
        f"error: cannot resume with other pairs: the experiment in {resumed_root} has adversarial-s0, adversarial-s1, "
        "uniform-s0, uniform-s1, this one adversarial-s0, adversarial-s1, adversarial-s2, uniform-s0, uniform-s1, "
        "uniform-s2 (keep seeds, first_seed, modes and lower_bounds)"))
    # Fast-forwarded from them, the four pairs re-train 2,000 env steps without scoring, each
    # pair's rounds put in place from its own records, and go on as the uninterrupted run.
    # (resume=auto with fast_forward=true: records and no checkpoint, as where the checkpoints
    # stayed on another node's disk, are rebuilt from.)
    assert experiment_main([*argv, "total_steps=3000", f"out={elsewhere}", "resume=auto", "fast_forward=true"]) == 0
    assert _scores(elsewhere) == _scores(str(tmp_path / "straight"))
    rebuilt = capsys.readouterr().err
    assert f"resume=auto: {elsewhere} holds records and no checkpoint: resume=true\n" in rebuilt
    assert "fast-forward: re-training env steps 0 to 2000 from the start" in rebuilt
    final_min = {mode: np.array([r.scores[-1]["min_score"] for r in straight if r.config.missingness == mode])
                 for mode in ("adversarial", "uniform")}
    features = observation_names("point_mass")
    for mode, values in final_min.items():
        assert f"| point_mass | {mode} | 2 | 3000 | {estimate(values)} | " in said
        # The row ends with where the mode is weak: the set most often worst at the end, as the trainer recorded it.
        worst = [features[parse_set(r.scores[-1]["argmin_set"])[0]] for r in straight if r.config.missingness == mode]
        common = max(worst, key=worst.count)
        row = said.split(f"| point_mass | {mode} | 2 | 3000 | ")[1].splitlines()[0]
        assert row.endswith(f"| {common} ({worst.count(common)} of 2) |")
    difference = Difference("final min_u a_u", final_min["adversarial"], final_min["uniform"])
    assert f"| point_mass | final min_u a_u | {difference.cells()} |" in said.split("Adversarial − uniform")[1]
    assert said.rstrip().endswith(f"figures, summary.md and CSV tables: python -m admissable_jax.plot {resumed_root}")
    # A summary that cannot be made costs a warning, not the exit status: the runs are written.
    def unreadable(run_dirs):
        raise ValueError("a torn scores.jsonl")

    monkeypatch.setattr("admissable_jax.experiment.summary_table", unreadable)
    assert experiment_main([*argv, "total_steps=3000", f"out={resumed_root}", "resume=true"]) == 0  # nothing left
    assert f"warning: no summary of the pairs (a torn scores.jsonl); python -m admissable_jax.plot {resumed_root}" \
        in capsys.readouterr().err
    # Nor does a Ctrl-C during it: one line, status 130.
    def ctrl_c(run_dirs):
        raise KeyboardInterrupt

    monkeypatch.setattr("admissable_jax.experiment.summary_table", ctrl_c)
    try:
        status = experiment_main([*argv, "total_steps=3000", f"out={resumed_root}", "resume=true"])
    except KeyboardInterrupt:
        status = "a traceback"
    assert status == INTERRUPTED
    assert capsys.readouterr().err.strip().splitlines()[-1] == (
        f"interrupted: the runs are written; python -m admissable_jax.plot {resumed_root} summarises them")
    monkeypatch.undo()

    with monkeypatch.context() as here:  # one folder as itself, not letter by letter ("r", "e", ...; "/" first if absolute)
        here.chdir(tmp_path)
        assert [str(tmp_path / run) for run in find_runs("resumed")] == find_runs([resumed_root])
    written = plot_runs(find_runs([resumed_root]), str(tmp_path / "figures"), window=2, formats=("png",))
    assert {os.path.basename(path) for path in written} >= {"min_score.png", "p_miss_adversarial.png"}


def test_process_0_summarises_only_pairs_whose_last_scoring_it_sees(tmp_path):
    """A multi-process experiment's process 0 reports on every pair only if each pair's folder
    is here with the scoring it reached (test_sharding runs the processes)."""
    assert not scored_up_to(str(tmp_path / "on-another-host"), 2000)
    (tmp_path / "scores.jsonl").write_text('{"env_steps": 1000}\n{"env_steps": 2000}\n')
    assert scored_up_to(str(tmp_path), 2000) and not scored_up_to(str(tmp_path), 3000)  # stale: an earlier run
    (tmp_path / "scores.jsonl").write_text('{"env_steps": 1000}\n{"env_st')  # cut off mid-append
    assert not scored_up_to(str(tmp_path), 1000)


def test_experiment_refuses_what_does_not_fit_before_allocating(tmp_path, monkeypatch):
    import admissable_jax.memory as memory

    class Tiny:
        available = 1024

    monkeypatch.setattr(memory.psutil, "virtual_memory", lambda: Tiny())
    config = ExperimentConfig(**EXPERIMENT, total_steps=1000, out=str(tmp_path / "big"))
    with pytest.raises(MemoryBudgetExceeded, match="does not fit: memory on cpu\\S*: training state .* GiB available"):
        run_experiment(config)
    assert not (tmp_path / "big").exists()  # nothing was trained, and the folders it made are gone

    monkeypatch.undo()  # the memory there is again
    # A dry run in a folder that was there before: the pairs' folders it made go, what was there stays.
    (tmp_path / "kept" / "adversarial-s0").mkdir(parents=True)
    (tmp_path / "kept" / "adversarial-s0" / "notes.txt").write_text("mine")
    assert run_experiment(ExperimentConfig(**EXPERIMENT, total_steps=1000, out=str(tmp_path / "kept"),
                                           budget_only=True)) == []
    assert sorted(os.listdir(tmp_path / "kept")) == ["adversarial-s0", "checkpoints", "experiment.yaml"]
    assert (tmp_path / "kept" / "adversarial-s0" / "notes.txt").read_text() == "mine"

    # The count itself: the state (each of 2 devices holds half) stays live beside the larger
    # of the two programs' temporaries, which run one after the other.
    class Compiled:
        def __init__(self, temp_bytes):
            self.temp_bytes = temp_bytes

        def memory_analysis(self):
            return types.SimpleNamespace(temp_size_in_bytes=self.temp_bytes)

    state = {"buffer": jax.ShapeDtypeStruct((1000,), jnp.float32), "steps": jax.ShapeDtypeStruct((4,), jnp.int32)}
    budget = memory.memory_budget(state, Compiled(300), Compiled(500), num_devices=2)
    assert (budget.state_bytes, budget.chunk_temp_bytes, budget.score_temp_bytes) == (2008, 300, 500)
    assert budget.devices_sharing == min(2, jax.local_device_count())  # CPU devices share the host's memory
    assert budget.needed_bytes == budget.devices_sharing * 2508


@pytest.mark.parametrize(
    "args, message",
    [
        (["modes=adversarial,sometimes"], "modes must be a comma-separated list"),
        (["modes=uniform,uniform"], "modes repeats a mode"),
        (["seeds=0"], "seeds must be >= 1"),
        (["missingness=uniform"], "unknown key 'missingness'"),
        (["env=ant", "k=105"], "k must satisfy 1 <= k < d = 105"),
        (["lower_bounds=0,x"], "lower_bounds must be a comma-separated list of numbers, got '0,x'"),
        (["lower_bounds=0,50,0.0"], "lower_bounds repeats a value"),
        (["lower_bounds=0,inf"], "lower_bounds must be finite numbers, got '0,inf'"),
        (["modes=uniform", "lower_bounds=0,50"], "lower_bounds sweeps the adversarial mode's l, and modes='uniform' "
                                                 "has no adversarial"),
    ],
)
def test_experiment_cli_rejects_bad_input_with_one_line(args, message, tmp_path, capsys):
    """In-process (``main``); tests/test_runs.py runs the real command line for a bad input."""
    from admissable_jax.experiment import main

    try:
        status = main([*args, f"out={tmp_path}/x", "progress=false"])
    except SystemExit as exit_info:
        status = exit_info.code
    stderr = capsys.readouterr().err
    assert status == 2, stderr
    assert message in stderr
    assert len(stderr.strip().splitlines()) == 1, stderr


def test_the_progress_bar_shows_min_score_per_mode():
    from admissable_jax.host_loop import progress_postfix

    rows = [{"min_score": low, "clean_score": clean} for low, clean in ((10, 50), (30, 70), (20, 60), (40, 80))]
    assert progress_postfix(rows, ["adversarial"] * 4) == {"min_a_u": "25.0", "clean": "65.0"}
    assert progress_postfix(rows, ["adversarial", "uniform", "adversarial", "uniform"]) == {
        "min_a_u_adversarial": "15.0", "min_a_u_uniform": "35.0"}
    # A sweep of l: a curve per value (the uniform runs' l is never read, so never named).
    curves = curve_names([("adversarial", 0.0), ("adversarial", 50.0), ("uniform", 0.0), ("uniform", 50.0)])
    assert curves == ["adversarial-l0", "adversarial-l50", "uniform", "uniform"]
    assert curve_names([("adversarial", 50.0), ("uniform", 0.0)]) == ["adversarial", "uniform"]
    assert progress_postfix(rows, curves) == {"min_a_u_adversarial-l0": "10.0", "min_a_u_adversarial-l50": "30.0",
                                              "min_a_u_uniform": "30.0"}


def test_one_program_sweeps_the_lower_bound_and_each_value_meets_the_one_uniform_curve(tmp_path, capsys):
    """``lower_bounds=0,15``: the adversarial seeds train once per l, the uniform seeds once,
    all in one program; each pair's p_miss follows its own l (paper §3's update), and plot's
    summary, the comparison and the audit set every l against the one uniform curve."""
    root = str(tmp_path / "sweep")
    results = run_experiment(ExperimentConfig(**{**EXPERIMENT, "seeds": 1}, lower_bounds="0,15", total_steps=2000,
                                              out=root))
    assert [os.path.basename(result.run_dir) for result in results] == [
        "adversarial-l0-s0", "adversarial-l15-s0", "uniform-s0"]
    assert [result.config.lower_bound for result in results] == [0.0, 15.0, 0.0]
    assert results[0].metrics[-1]["runs_in_program"] == 3
    assert [result.summary().split(" seed ")[0] for result in results] == [
        "done: point_mass adversarial", "done: point_mass adversarial (l = 15)", "done: point_mass uniform"]
    last = results[2].scores[-1]  # the whole line, as a run ends with it
    assert f"{last['clean_score']:.1f}" != f"{last['min_score']:.1f}"  # the line tells them apart
    trained = [row for row in results[2].scores if row["env_steps"] > results[2].config.learning_starts]
    best = max(trained, key=lambda row: row["min_score"])
    assert best is not last  # its best scoring came earlier: the line names it, and the file that keeps it
    assert results[2].summary() == (
        f"done: point_mass uniform seed 0, 2000 env steps, min_u a_u {last['min_score']:.1f} (u = {last['argmin_set']}), "
        f"clean {last['clean_score']:.1f}; its best {best['min_score']:.1f} at {best['env_steps']} env steps, kept in "
        f"best_policy.npz; run in {results[2].run_dir}")
    for result in results[:2]:
        for row in result.scores:
            np.testing.assert_allclose(row["p_miss"], inverse_score_p_miss(
                np.array(row["scores"]), result.config.lower_bound, result.config.epsilon), rtol=1e-5)
    # One seed, so the first scoring's a_u agree; only l moved p_miss apart.
    assert results[0].scores[0]["scores"] == results[1].scores[0]["scores"]
    assert not np.allclose(results[0].scores[0]["p_miss"], results[1].scores[0]["p_miss"], rtol=1e-3)
    np.testing.assert_allclose(results[2].scores[-1]["p_miss"], 0.25)

    run_dirs = find_runs([root])
    assert [row.split(" | ")[1:3] for row in summary_table(run_dirs).splitlines()[2:]] == [
        ["adversarial, lower_bound=0", "1"], ["adversarial, lower_bound=15", "1"], ["uniform", "1"]]
    differences = mode_differences(run_dirs)
    assert list(differences) == ["point_mass, lower_bound=0", "point_mass, lower_bound=15"]
    uniform_final = results[2].scores[-1]["min_score"]
    for result, (label, rows) in zip(results, differences.items()):
        assert rows[0].metric == "final min_u a_u"
        np.testing.assert_allclose(rows[0].adversarial, [result.scores[-1]["min_score"]])
        np.testing.assert_allclose(rows[0].baseline, [uniform_final])

    # Resumed with other values: refused before anything runs, naming the pairs.
    with pytest.raises(ValueError, match="has adversarial-l0-s0, adversarial-l15-s0, uniform-s0, this one "
                                         "adversarial-l0-s0, adversarial-l20-s0, uniform-s0"):
        run_experiment(ExperimentConfig(**{**EXPERIMENT, "seeds": 1}, lower_bounds="0,20", total_steps=3000,
                                        out=root, resume=True))
    audits, written = audit_experiment(AuditConfig(run_dir=root, k="1", episodes=2))
    comparison = open(written[-1]).read()
    for curve in ("adversarial-l0", "adversarial-l15", "uniform"):
        assert f"| 1 | {curve} | 1 | " in comparison
    for curve in ("adversarial-l0", "adversarial-l15"):
        assert f"| 1 | worst a_u ({curve}) | " in comparison


def test_pair_configs_name_one_directory_per_pair():
    pairs = pair_configs(ExperimentConfig(env="Hopper-v5", seeds=3, first_seed=4, modes="uniform,none"))
    assert [p.out for p in pairs] == [f"runs/fig1-hopper/{m}-s{s}" for m in ("uniform", "none") for s in (4, 5, 6)]
    assert all(p.env == "hopper" and p.num_envs > 0 for p in pairs)


def test_quickstart_notebook_runs(tmp_path):
    """The notebook end to end, its parameter cell replaced by a tiny run on the point mass
    (its code is the same for every env; Hopper's pipelines on both backends are tested in
    test_hopper_pipelines.py)."""
    notebook = nbformat.read(os.path.join(REPO, "notebooks", "quickstart.ipynb"), as_version=4)
    parameters = next(cell for cell in notebook.cells if cell.source.startswith("# Parameters"))
    parameters.source = "\n".join([
        "ENV = 'point_mass'", "TOTAL_STEPS = 80", "SCORE_EVERY = 40", "NUM_ENVS = 4", "SCORE_EPISODES = 2",
        "EPISODE_LENGTH = 25", "LEARNING_STARTS = 48", "PHYSICS = 'jax'",
        "EXTRA = dict(batch_size=32, hidden_size=32, buffer_size=1000, progress=False)",
        f"OUT = {str(tmp_path / 'quickstart')!r}",
    ])
    NotebookClient(notebook, timeout=1200, kernel_name="python3",
                   resources={"metadata": {"path": str(tmp_path)}}).execute()
    outputs = "".join(
        output.get("text", "") for cell in notebook.cells if cell.cell_type == "code" for output in cell.outputs
    )
    assert "min_u a_u =" in outputs and "env steps: min_u a_u" in outputs
    assert "PointMass(obs 4, actions 2)" in outputs and "hidden; clean" in outputs
    images = [o for cell in notebook.cells if cell.cell_type == "code" for o in cell.outputs if "image/png" in o.get("data", {})]
    assert len(images) == 4  # bar chart, a_u by failure step, Figure 1, p_miss
    failing = re.findall(r"^sensors fail at env step (\d+): k=1: worst ", outputs, re.M)
    assert failing[0] == "0" and len(set(failing)) == len(failing) >= 2, outputs  # from the start, then mid-episode
    assert os.path.exists(tmp_path / "quickstart" / "figures" / "min_score.pdf")
