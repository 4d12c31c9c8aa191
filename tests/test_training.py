"""The trainer end to end: SAC learning, per-episode missing sets, scoring, checkpoints, CLI.

All on the pure-JAX point mass (seconds to compile); Hopper runs end to end in
tests/test_hopper_pipelines.py.
"""

from __future__ import annotations

import collections
import csv
import dataclasses
import errno
import glob
import itertools
import json
import logging
import os
import re
import shutil
import struct
import subprocess
import sys
import unittest.mock

import jax
import jax.numpy as jnp
import mujoco
import numpy as np
import pytest
from omegaconf import OmegaConf

from admissable_jax import TrainConfig, candidate_sets, make_env, mask_observation, replay, score_missingness, train_fn
from admissable_jax.audit import main as audit_main
from admissable_jax.best_policy import BestPolicyNotWritten, KeptPolicy, best_kept, write_best_policy
from admissable_jax.branching import while_any
from admissable_jax.checkpointing import CheckpointError, Checkpoints, OtherStateLayout
from admissable_jax.envs import observation_names
from admissable_jax.export import main as export_main
from admissable_jax.exported_policy import ExportedPolicy
from admissable_jax.host_loop import TrainingDiverged, TrainingLoop, stacked_init_arguments
from admissable_jax.fingerprints import tree_fingerprint
from admissable_jax.method import inverse_score_p_miss, worst_set_p_miss
from admissable_jax.policies import load_policy
from admissable_jax.run_directory import metrics_row, recorded_observation_names, same_policy_record
from admissable_jax.run_spec import RunSpec
from admissable_jax.training import Trainer

POINT_MASS = TrainConfig(
    env="point_mass",
    total_steps=6000,
    score_every=1000,
    num_envs=4,
    learning_starts=1000,
    episode_length=100,
    score_episodes=4,
    batch_size=128,
    buffer_size=20_000,
    hidden_size=64,
    progress=False,
    logger="tensorboard,wandb",
)


@pytest.fixture(scope="module")
def point_mass_run(tmp_path_factory):
    out = str(tmp_path_factory.mktemp("runs") / "pm")
    with unittest.mock.patch.dict(os.environ, {"WANDB_MODE": "offline", "WANDB_SILENT": "true"}):
        return train_fn(dataclasses.replace(POINT_MASS, out=out))


def test_sac_learns_point_mass(point_mass_run):
    """5000 steps of SAC against doing nothing: the zero-force policy, scored the same way
    (clean, deterministic, 100-step episodes from the same start distribution)."""
    scores = point_mass_run.scores
    assert len(scores) == 6
    zero_force = score_missingness(make_env("point_mass", episode_length=100), lambda params, obs: jnp.zeros(2), None,
                                   jax.random.key(1), candidate_sets(4, k=1), 64)
    # The return is at most 100 (reward <= 1 per step). Standing still from a start in
    # [-1, 1]^2 earns about 56, and so does the untrained policy (its actions start near 0);
    # steering home earns more (SAC: about 95 after 5000 steps).
    baseline = float(zero_force.clean_score)
    assert 45 < baseline < 65, baseline
    first, last = scores[0]["clean_score"], scores[-1]["clean_score"]
    assert last > baseline + 15 and last > first + 15, (first, last, baseline)
    metrics = point_mass_run.metrics
    assert metrics[-1]["grad_steps"] == 5000  # UTD 1 from learning_starts on
    assert all(np.isfinite(m["critic_loss"]) for m in metrics[1:])


def test_run_directory_contents(point_mass_run, tmp_path):
    run_dir = point_mass_run.run_dir
    assert sorted(os.listdir(run_dir)) == ["best_policy.npz", "checkpoints", "config.yaml", "invocations.jsonl",
                                           "metrics.jsonl", "observation_names.json", "scores.jsonl", "tensorboard",
                                           "wandb", "wandb_run_id"]
    with open(os.path.join(run_dir, "observation_names.json")) as file:
        assert json.load(file) == observation_names("point_mass")
    assert recorded_observation_names(run_dir) == observation_names("point_mass")  # what plots and audits label with
    names_file = tmp_path / "observation_names.json"
    for text, message in (('{"x": 0}', "must hold a JSON list of feature names"), ("[", "cannot be read (Expecting")):
        names_file.write_text(text)  # edited by hand, or cut off: one line naming the file, not a label of "x"
        with pytest.raises(ValueError, match=f"^{re.escape(f'{names_file} {message}')}"):
            recorded_observation_names(str(tmp_path))
    with pytest.raises(TypeError, match="^train_fn expects a TrainConfig, got dict$"):
        train_fn({"env": "point_mass"})  # a config's fields as a dict: TrainConfig(**fields) is the config
    # What produced the run: this command, from step 0, on this machine's device and packages.
    (invocation,) = [json.loads(line) for line in open(os.path.join(run_dir, "invocations.jsonl"))]
    assert invocation["from_env_steps"] == 0 and invocation["physics"] == "jax" and invocation["runs_in_program"] == 1
    assert invocation["device"].startswith("cpu:") and invocation["devices"] == 1 and invocation["command"][1:] == sys.argv
    assert invocation["versions"]["jax"] == jax.__version__ and invocation["versions"]["mujoco"] == mujoco.__version__
    # Our commands are recorded as typed (python -m ...), not as the module's file Python puts in argv[0].
    import admissable_jax.provenance as provenance

    package = os.path.dirname(provenance.__file__)
    python = os.path.basename(sys.executable)
    for argv, command in (([os.path.join(package, "train.py"), "env=ant"], ["-m", "admissable_jax.train", "env=ant"]),
                          ([os.path.join(package, "__main__.py"), "audit", "x"], ["-m", "admissable_jax", "audit", "x"]),
                          ([os.path.join(package, "audit", "__main__.py")], ["-m", "admissable_jax.audit"]),
                          (["my_sweep.py", "--seed", "1"], ["my_sweep.py", "--seed", "1"])):
        with unittest.mock.patch.object(sys, "argv", argv):
            assert provenance.command_line() == [python, *command]
    for row in point_mass_run.scores:
        assert len(row["scores"]) == 4 and len(row["p_miss"]) == 4
        assert row["min_score"] == pytest.approx(min(row["scores"]), abs=1e-3)
        assert row["scores"][row["argmin"]] == pytest.approx(row["min_score"], abs=1e-3)
        assert row["mean_score"] == pytest.approx(np.mean(row["scores"]), abs=1e-3)  # the average case over U
        assert sum(row["p_miss"]) == pytest.approx(1.0, abs=1e-5)
        # Adversarial mode: p_miss after the update is the inverse-score distribution.
        inverse = 1.0 / np.maximum(np.array(row["scores"]), 0.0)
        np.testing.assert_allclose(row["p_miss"], inverse / inverse.sum(), rtol=1e-3)
    # A metrics row of an interval that starts learning midway: its losses are the means over the
    # iterations that learned (the warm-up's zeros left out), its returns per finished episode.
    chunk = {"learned": np.array([0, 0, 1, 1]), "episodes": np.array([0, 1, 0, 1]),
             "episode_return_sum": np.array([0.0, 10.0, 0.0, 30.0]), "episode_length_sum": np.array([0, 5, 0, 15]),
             **{name: np.array([0.0, 0.0, 2.0, 4.0]) for name in ("critic_loss", "actor_loss", "alpha", "entropy", "q_mean")}}
    row = metrics_row(1000, 8, chunk, 2.0, 1.0, TrainConfig(num_envs=4, score_every=1000), 1, 7)
    assert row == {"env_steps": 1000, "grad_steps": 8, "episodes": 2, "episode_return": 20.0, "episode_length": 10.0,
                   "env_steps_per_s": 500.0, "grad_steps_per_s": 4.0, "score_seconds": 1.0, "runs_in_program": 1,
                   "state_fingerprint": 7, "critic_loss": 3.0, "actor_loss": 3.0, "alpha": 3.0, "entropy": 3.0,
                   "q_mean": 3.0}


def _tensorboard_events(directory: str) -> list:
    """Every event in a tensorboardX log (TFRecord: length, its CRC, the Event proto, its CRC)."""
    from tensorboardX.proto import event_pb2

    events = []
    for name in sorted(os.listdir(directory)):
        with open(os.path.join(directory, name), "rb") as file:
            data = file.read()
        offset = 0
        while offset < len(data):
            (length,) = struct.unpack("<Q", data[offset:offset + 8])
            event = event_pb2.Event()
            event.ParseFromString(data[offset + 12:offset + 12 + length])
            events.append(event)
            offset += 12 + length + 4
    return events


def _wandb_history(run_dir: str) -> tuple[list[dict], list]:
    """The history rows of an offline W&B run, and its metric definitions (``define_metric``):
    its ``.wandb`` file is a LevelDB-style log (a 7-byte header, then 32 KiB blocks of chunks:
    CRC, length, type) of Record protos."""
    from wandb.proto import wandb_internal_pb2

    (path,) = glob.glob(os.path.join(run_dir, "wandb", "offline-run-*", "*.wandb"))
    with open(path, "rb") as file:
        data = file.read()
    assert data[:4] == b":W&B"
    offset, pending, rows, metrics = 7, b"", [], []
    while offset + 7 <= len(data):
        if 32768 - offset % 32768 < 7:  # a block's tail too short for a chunk header is padding
            offset += 32768 - offset % 32768
            continue
        _, length, kind = struct.unpack("<IHB", data[offset:offset + 7])
        if kind == 0:
            break
        pending += data[offset + 7:offset + 7 + length]
        offset += 7 + length
        if kind in (1, 4):  # a full record, or the last chunk of one
            record = wandb_internal_pb2.Record()
            record.ParseFromString(pending)
            pending = b""
            if record.WhichOneof("record_type") == "history":
                rows.append({item.key or "/".join(item.nested_key): json.loads(item.value_json) for item in record.history.item})
            elif record.WhichOneof("record_type") == "metric":
                metrics.append(record.metric)
    return rows, metrics


def test_loggers_mirror_the_jsonl_rows(point_mass_run, tmp_path, capsys, monkeypatch):
    """logger=tensorboard,wandb: each row's numbers as scalars at its env step, every a_u,
    p_miss as a histogram, in TensorBoard's event files and in W&B's offline run. Where the
    wandb package is missing, logger=wandb is refused before the run starts."""
    from admissable_jax.train import main

    with monkeypatch.context() as patched:
        patched.setitem(sys.modules, "wandb", None)  # what importlib finds where it is not installed
        assert main(["logger=tensorboard,wandb", f"out={tmp_path / 'never'}", "progress=false"]) == 2
    assert capsys.readouterr().err == "error: logger=wandb needs the wandb package: pip install -e '.[wandb]'\n"
    assert not (tmp_path / "never").exists()
    from admissable_jax.loggers import parse_logger_names  # a logger named twice is one logger

    assert parse_logger_names("tensorboard, wandb,tensorboard") == ("tensorboard", "wandb")
    values = collections.defaultdict(dict)
    for event in _tensorboard_events(os.path.join(point_mass_run.run_dir, "tensorboard")):
        for value in event.summary.value:
            values[value.tag][event.step] = value.histo if value.HasField("histo") else value.simple_value
    wandb_rows = collections.defaultdict(dict)
    history, metrics = _wandb_history(point_mass_run.run_dir)
    for row in history:
        wandb_rows[row["env_steps"]].update(row)
    # W&B draws every curve against env_steps, not its own count of log calls (which a resumed
    # run would not repeat): the rows written again land on the same x.
    assert any(metric.glob_name == "*" and metric.step_metric == "env_steps" for metric in metrics), metrics
    for row in point_mass_run.scores:
        step = row["env_steps"]
        assert values["scores/min_score"][step] == pytest.approx(row["min_score"], rel=1e-6)
        assert values["scores/clean_score"][step] == pytest.approx(row["clean_score"], rel=1e-6)
        assert [values[f"a_u/{u:03d}"][step] for u in range(4)] == pytest.approx(row["scores"], rel=1e-6)
        np.testing.assert_allclose(values["p_miss"][step].bucket, row["p_miss"], rtol=1e-6)
        logged = wandb_rows[step]
        assert logged["scores/min_score"] == pytest.approx(row["min_score"], rel=1e-6)
        assert [logged[f"a_u/{u:03d}"] for u in range(4)] == pytest.approx(row["scores"], rel=1e-6)
        np.testing.assert_allclose(logged["p_miss/values"], row["p_miss"], rtol=1e-6)
        np.testing.assert_allclose(logged["p_miss/bins"], np.arange(5) - 0.5)
    for row in point_mass_run.metrics[1:]:
        assert values["metrics/critic_loss"][row["env_steps"]] == pytest.approx(row["critic_loss"], rel=1e-6)
        assert "state_fingerprint" in row and "metrics/state_fingerprint" not in wandb_rows[row["env_steps"]]
        assert wandb_rows[row["env_steps"]]["metrics/critic_loss"] == pytest.approx(row["critic_loss"], rel=1e-6)
    assert "metrics/state_fingerprint" not in values  # a hash, not a curve
    with open(os.path.join(point_mass_run.run_dir, "wandb_run_id")) as file:  # resume=true logs on into this run
        assert glob.glob(os.path.join(point_mass_run.run_dir, "wandb", f"offline-run-*-{file.read().strip()}"))


def test_load_policy_is_the_trainers_deterministic_policy(point_mass_run, monkeypatch, tmp_path, capsys):
    """load_policy reads a run's checkpoint without touching it, only its networks (not
    the replay buffer beside them: GBs in a long run), and acts as scoring does."""
    import orbax.checkpoint as ocp

    asked = []
    restore = ocp.Checkpointer.restore
    monkeypatch.setattr(ocp.Checkpointer, "restore",
                        lambda reader, path, **kwargs: asked.append(kwargs["args"].item) or restore(reader, path, **kwargs))
    run_dir = point_mass_run.run_dir
    before = sorted(os.listdir(os.path.join(run_dir, "checkpoints")))
    policy = load_policy(run_dir)
    assert sorted(leaf.size for leaf in asked[0].values()) == sorted(
        leaf.size for leaf in jax.tree.leaves(point_mass_run.state.sac) if leaf.size)
    assert policy.step == 6000
    # Shown in a notebook: which policy and which run, in one line, not its parameters (and
    # the result of train_fn: its summary, not its state's networks and replay buffer).
    assert repr(policy) == (f"<TrainedPolicy of point_mass {point_mass_run.config.missingness} seed "
                            f"{point_mass_run.config.seed} at env step 6000 ({run_dir}): 4 features in, 2 actions out>")
    assert repr(point_mass_run) == f"<TrainResult {point_mass_run.summary()}>"
    obs = np.random.default_rng(0).normal(size=(7, 4)).astype(np.float32)
    expected = jax.vmap(point_mass_run.trainer.policy, (None, 0))(point_mass_run.actor_params,
                                                                  mask_observation(obs, np.array([0, 0, 1, 0])))
    np.testing.assert_allclose(policy(obs, hidden=[2]), expected, rtol=1e-6)
    np.testing.assert_allclose(policy(obs[0], hidden=np.array([0, 0, 1, 0], np.float32)), expected[0], rtol=1e-6)
    assert sorted(os.listdir(os.path.join(run_dir, "checkpoints"))) == before
    with pytest.raises(CheckpointError, match="no checkpoint 10 in .*; saved: \\[6000\\]"):
        load_policy(run_dir, step=10)
    with pytest.raises(TypeError, match="^step must be an env step \\(an int\\), 'best' or None for the latest, got '6000'$"):
        load_policy(run_dir, step="6000")  # (it said "no checkpoint 6000 ...; saved: [6000]")
    with pytest.raises(ValueError, match=r"hidden features must be in \[0, 4\)"):
        policy(obs, hidden=[4])

    def disk_full(file, **arrays):
        file.write(b"part of it")
        raise OSError(errno.ENOSPC, "No space left on device")

    # Exported (python -m admissable_jax.export): the actor's layers in one .npz, and the same
    # actions from NumPy alone, in a process that imports no JAX.
    assert export_main([run_dir]) == 0
    path = os.path.join(run_dir, "exported", "policy-step6000.npz")
    assert capsys.readouterr().out == (f"wrote {path}: point_mass {point_mass_run.config.missingness} seed "
                                       f"{point_mass_run.config.seed} at env step 6000, layers 8 -> 64 -> 64 -> 2; "
                                       "ExportedPolicy.load(path) from admissable_jax.exported_policy runs it with "
                                       "NumPy alone\n")
    exported = ExportedPolicy.load(path)
    assert repr(exported) == repr(policy).replace("TrainedPolicy", "ExportedPolicy").replace(f"({run_dir})",
                                                                                            f"({os.path.abspath(run_dir)})")
    np.testing.assert_allclose(exported(obs, hidden=[2]), expected, rtol=1e-5, atol=1e-6)
    np.save(tmp_path / "obs.npy", obs)
    code = ("import sys, numpy as np; from admissable_jax.exported_policy import ExportedPolicy; "
            f"policy = ExportedPolicy.load({path!r}); np.save({str(tmp_path / 'acted.npy')!r}, "
            f"policy(np.load({str(tmp_path / 'obs.npy')!r})[0], hidden=[0, 3])); assert 'jax' not in sys.modules")
    subprocess.run([sys.executable, "-c", code], check=True)
    np.testing.assert_allclose(np.load(tmp_path / "acted.npy"), policy(obs[0], hidden=[0, 3]), rtol=1e-5, atol=1e-6)
    with pytest.raises(ValueError, match=r"^expected a batch of masked observations \(n, 2·d = 8\), got shape \(7, 4\)$"):
        exported.masked(obs)
    assert audit_main([f"policy={path}"]) == 2  # the point mass has no Gymnasium env for the audit to name
    assert capsys.readouterr().err == f"error: {path} is a policy of point_mass, which has no Gymnasium env: give gym=\n"
    # Never written over: a file that is no exported policy (refused in one line, exit 2, left
    # as it was); one that is, is replaced. Nor is such a file read as a policy.
    stranger = tmp_path / "notes.npz"
    stranger.write_text("my notes")
    assert export_main([run_dir, f"out={stranger}"]) == 2
    assert capsys.readouterr().err == (f"error: {stranger} exists and is no exported policy: it is left as it is; "
                                       "give another out=\n") and stranger.read_text() == "my notes"
    cut_short = tmp_path / "cut.npz"  # an export cut short (a copy that stopped), as another NumPy file
    cut_short.write_bytes(open(path, "rb").read()[:5000])
    np.save(tmp_path / "array.npy", obs)
    for refused in (stranger, cut_short, tmp_path / "array.npy", os.path.join(run_dir, "best_policy.npz")):
        with pytest.raises(ValueError, match=f"^{refused} is no exported policy of admissable_jax \\(python -m "):
            ExportedPolicy.load(str(refused))
    with np.load(path) as data:  # a later version's format, whose arrays may mean other things
        np.savez(tmp_path / "later.npz", **{**data, "format": np.str_("admissable_jax exported policy 2")})
    with pytest.raises(ValueError, match=f"^{tmp_path / 'later.npz'} is an exported policy of another version of "
                                         "admissable_jax \\('admissable_jax exported policy 2'; this one reads "
                                         "'admissable_jax exported policy 1'\\)$"):
        ExportedPolicy.load(str(tmp_path / "later.npz"))
    assert export_main([run_dir, f"out={path}"]) == 0 and capsys.readouterr().out.startswith(f"wrote {path}: ")
    # Nor is another policy's (the run's best over its last checkpoint's: that checkpoint may be
    # gone), but the same run's, copied (or moved) since, is: its policy names where it is now.
    before = open(path, "rb").read()
    assert export_main([run_dir, "best=true", f"out={path}"]) == 2
    assert capsys.readouterr().err == (f"error: {path} holds the exported policy of another run or step "
                                       f"({os.path.abspath(run_dir)}, env step 6000): it is left as it is; give "
                                       "another out=\n") and open(path, "rb").read() == before
    twin = shutil.copytree(run_dir, tmp_path / "twin")
    assert export_main([str(twin)]) == 0
    # An equal record is its policy's even where its run is gone (an exported policy outlives
    # its run: a video of it written again), wherever the file lies.
    gone = {"run": str(tmp_path / "deleted-run"), "env_steps": 6000}
    assert same_policy_record(gone, dict(gone), str(tmp_path / "elsewhere.mp4"))
    assert not same_policy_record(gone, {**gone, "env_steps": 4000}, str(tmp_path / "elsewhere.mp4"))
    assert ExportedPolicy.load(str(twin / "exported" / "policy-step6000.npz")).source["run"] == str(twin)
    with monkeypatch.context() as patched:  # a write that fails (a full disk): nothing half-written, the file before kept
        patched.setattr(np, "savez", disk_full)
        assert export_main([run_dir, f"out={path}"]) == 1
    assert capsys.readouterr().err == f"error: cannot write the exported policy {path}: No space left on device\n"
    assert os.listdir(os.path.dirname(path)) == ["policy-step6000.npz"]
    assert ExportedPolicy.load(path).source["env_steps"] == 6000
    # The best policy: where a run keeps none (copied without it) or another run's, one line.
    copied = tmp_path / "copied"
    shutil.copytree(run_dir, copied, ignore=shutil.ignore_patterns("checkpoints", "best_policy.npz"))
    with pytest.raises(FileNotFoundError, match=f"^{copied} keeps no best_policy.npz: a run writes it at each scoring"):
        load_policy(str(copied), "best")
    # A write that fails (a full disk) removes what it wrote, keeps the earlier best and says so in one line.
    kept = KeptPolicy(500, 1.0, policy.actor_params, policy.critic_params)
    write_best_policy(str(copied), kept)
    # The closing line names a best kept from before the last scoring (here: this one), not one of the last.
    moved = lambda out: dataclasses.replace(point_mass_run, config=dataclasses.replace(point_mass_run.config, out=out))
    assert moved(str(copied)).summary().endswith(f"clean {point_mass_run.scores[-1]['clean_score']:.1f}; its best 1.0 at "
                                                 f"500 env steps, kept in best_policy.npz; run in {copied}")
    os.makedirs(tmp_path / "best_last")
    write_best_policy(str(tmp_path / "best_last"), dataclasses.replace(kept, env_steps=6000))
    assert moved(str(tmp_path / "best_last")).summary().endswith(
        f"clean {point_mass_run.scores[-1]['clean_score']:.1f}; run in {tmp_path / 'best_last'}")
    monkeypatch.setattr(np, "savez", disk_full)
    with pytest.raises(BestPolicyNotWritten, match=f"^cannot write the best policy of env step 600 in {copied}: No space "
                                                   f"left on device; the partial write was removed; free space, then "
                                                   f"continue with resume=true$"):
        write_best_policy(str(copied), dataclasses.replace(kept, env_steps=600))
    monkeypatch.undo()
    assert "best_policy.npz.partial" not in os.listdir(copied) and best_kept(str(copied)) == (500, 1.0)
    other_shape = lambda params: jax.tree.map(lambda leaf: np.zeros((2, *leaf.shape), np.float32), params)
    write_best_policy(str(copied), KeptPolicy(500, 1.0, other_shape(policy.actor_params), policy.critic_params))
    with pytest.raises(ValueError, match=f"^{copied}/best_policy.npz does not hold the networks of the run in {copied} "):
        load_policy(str(copied), "best")
    with pytest.raises(ValueError, match=r"^expected a batch of masked observations \(n, 2·d = 8\), got shape \(7, 4\)$"):
        policy.masked(obs)  # unmasked rows (it said Flax's "ScopeParamShapeError ...")


def test_missing_set_fixed_within_episode_and_drawn_from_p_miss_and_failing_from_a_drawn_step():
    env = make_env("point_mass", episode_length=5)  # many episode starts
    config = dataclasses.replace(POINT_MASS, num_envs=20, episode_length=5, hidden_size=32).resolved()
    trainer = Trainer(env, RunSpec.of(config))
    p_miss = jnp.array([0.55, 0.25, 0.15, 0.05])
    state = trainer.init(0, True, True, 0.0).replace(p_miss=p_miss)

    def record(state, _):
        state, _ = trainer.iteration(state)
        return state, (state.set_index, state.env_states.step_count)

    _, (set_index, step_count) = jax.jit(lambda s: jax.lax.scan(record, s, None, length=300))(state)
    set_index, step_count = np.asarray(set_index), np.asarray(step_count)
    episode_start = step_count[1:] == 0
    changed = set_index[1:] != set_index[:-1]
    assert not (changed & ~episode_start).any(), "u changed within an episode"
    draws = set_index[1:][episode_start]
    assert len(draws) > 800
    frequencies = np.bincount(draws, minlength=4) / len(draws)
    tolerance = 4 * np.sqrt(np.asarray(p_miss) * (1 - np.asarray(p_miss)) / len(draws))
    assert (np.abs(frequencies - np.asarray(p_miss)) < tolerance).all(), frequencies
    assert state.failure_step is None and state.buffer.data.steps_past_failure is None  # the paper's state

    # fail_at=3,0: each episode also draws the env step its u fails, 0 or 3, held for the
    # episode. The policy sees every feature until then; the replay hides u in obs and in
    # next_obs each from that step on (the transition across it: obs whole, next_obs without u).
    failing = Trainer(env, RunSpec.of(dataclasses.replace(config, fail_at="3,0").resolved()))
    state = failing.init(0, True, True, 0.0).replace(p_miss=p_miss)

    def record_failing(state, _):
        seen = (failing.hidden_now(state), state.set_index, state.failure_step, state.env_states.step_count)
        return failing.iteration(state)[0], seen

    iterations = 100
    state, (hidden, set_index, failure_step, step_count) = jax.jit(
        lambda s: jax.lax.scan(record_failing, s, None, length=iterations))(state)
    hidden, set_index, failure_step, step_count = map(np.asarray, (hidden, set_index, failure_step, step_count))
    episode_start = step_count[1:] == 0
    assert not ((failure_step[1:] != failure_step[:-1]) & ~episode_start).any(), "the failure step changed within an episode"
    draws = failure_step[1:][episode_start]
    assert set(draws) == {0, 3} and abs(np.mean(draws == 3) - 0.5) < 4 * np.sqrt(0.25 / len(draws))
    u = candidate_sets(4, 1)[set_index]  # (iterations, envs, d)
    np.testing.assert_array_equal(hidden, u * (step_count >= failure_step)[..., None])
    written = replay.latest(state.buffer, iterations * config.num_envs)
    stored = jax.tree.map(np.asarray, written)
    steps_past = (step_count - failure_step).reshape(-1)
    np.testing.assert_array_equal(stored.steps_past_failure, steps_past)
    learned_from = failing.masked_batch(state, written)
    u = u.reshape(-1, 4)
    for masked, raw, hidden_rows in ((learned_from.obs, stored.obs, u * (steps_past >= 0)[:, None]),
                                     (learned_from.next_obs, stored.next_obs, u * (steps_past >= -1)[:, None])):
        np.testing.assert_array_equal(np.asarray(masked), np.concatenate([raw * (1 - hidden_rows), hidden_rows], axis=1))
    assert (steps_past == -1).sum() > 100  # transitions across the failure, each masked on its own side


def test_candidate_pool_for_k2_search_draws_and_records(tmp_path, monkeypatch):
    """k = 2 with a pool of P = 3 of the C(4, 2) = 6 pairs: every round a beam search of
    width 3 (ranked here by rollouts) picks the pool, only the pool is scored and p_miss is
    over it; adversarial episodes draw from the pool by p_miss or, with probability
    pool_explore, any pair of U; uniform mode draws every pair alike; an episode keeps its
    pair when the pool changes under it. End to end, scores.jsonl lists each row's pool and
    plot draws per-feature heatmaps. With MAX_CANDIDATE_SETS below |U| here, as for Ant's
    187,460 triples, U is never listed: every set's row is computed from its index."""
    from admissable_jax import method
    from admissable_jax.plot import plot_runs
    from admissable_jax.method import parse_set
    from admissable_jax.results import load_run, summary_table, write_tables
    from admissable_jax.scoring import beam_search_worst_sets

    config = dataclasses.replace(POINT_MASS, k=2, pool_size=3, pool_ranker="rollout", pool_explore=0.3, num_envs=20,
                                 episode_length=5, hidden_size=32, learning_starts=128, logger="none",
                                 out=str(tmp_path / "pool")).resolved()
    monkeypatch.setattr(method, "MAX_CANDIDATE_SETS", 5)
    trainer = Trainer(make_env("point_mass", episode_length=5), RunSpec.of(config))
    pairs = list(itertools.combinations(range(4), 2))  # U's order
    state = trainer.init(0, True, True, 0.0)
    assert state.p_miss.shape == (3,) and len(set(np.asarray(state.pool).tolist())) == 3

    scored_state, scores = jax.jit(trainer.score_and_update)(state)
    _, score_rng = jax.random.split(state.rng)
    score_rng, search_rng = jax.random.split(score_rng)
    rank = lambda rng: lambda rows: score_missingness(trainer.env, trainer.policy, state.sac.actor_params, rng, rows,
                                                      config.score_episodes).scores
    found = beam_search_worst_sets(rank(search_rng), 4, 2, 3)
    assert [pairs[i] for i in np.asarray(scored_state.pool)] == [tuple(np.flatnonzero(r)) for r in found.rows]
    pool_rows = trainer.sets.rows(scored_state.pool)  # computed from the indices: the finalists' own rows
    np.testing.assert_array_equal(pool_rows, found.rows)
    np.testing.assert_allclose(scores.scores, rank(score_rng)(pool_rows), rtol=1e-5)
    weights = 1 / np.asarray(scores.scores)
    np.testing.assert_allclose(scored_state.p_miss, weights / weights.sum(), rtol=1e-5)

    # Draws: adversarial with a fixed pool and p_miss, then uniform; the pool changes mid-run.
    pool, p_miss = jnp.array([0, 2, 5]), jnp.array([0.6, 0.3, 0.1])

    def record(state, t):
        state = state.replace(pool=jnp.where(t == 150, jnp.array([1, 3, 4]), state.pool))
        state, _ = trainer.iteration(state)
        return state, (state.set_index, state.env_states.step_count)

    record_300 = jax.jit(lambda start: jax.lax.scan(record, start, jnp.arange(300))[1])  # both modes: one compile

    def draws(adversarial):
        start = trainer.init(1, adversarial, True, 0.0).replace(pool=pool, p_miss=p_miss)
        set_index, step_count = (np.asarray(values) for values in record_300(start))
        starts = step_count[1:] == 0
        assert not ((set_index[1:] != set_index[:-1]) & ~starts).any(), "u changed within an episode"
        return set_index[1:][starts & (np.arange(1, 300) < 150)[:, None]]

    adversarial_draws, uniform_draws = draws(True), draws(False)
    expected = np.full(6, 0.3 / 6)
    expected[[0, 2, 5]] += 0.7 * np.asarray(p_miss)
    for drawn, p in ((adversarial_draws, expected), (uniform_draws, np.full(6, 1 / 6))):
        frequencies = np.bincount(drawn, minlength=6) / len(drawn)
        assert (np.abs(frequencies - p) < 4 * np.sqrt(p * (1 - p) / len(drawn))).all(), frequencies

    result = train_fn(dataclasses.replace(config, total_steps=3000, score_every=1000, checkpoint_every=1))
    rows = result.scores
    assert len(rows) == 3 and all(len(set(row["sets"])) == 3 == len(row["scores"]) for row in rows)
    assert f"lowest a_u of the pool {rows[-1]['min_score']:.1f} (u = {rows[-1]['argmin_set']}; 3 of 6 sets scored)" \
        in result.summary()
    assert not any("mean_score" in row for row in rows)  # a pool's sets are the worst found: no average over U
    run = load_run(config.out)
    assert run.scores.shape == (3, 4) and np.allclose(run.p_miss.sum(axis=1), 2.0)  # each pair counts for 2 features
    assert np.isnan(run.mean_score).all()
    # Its tidy table: a row per feature, the lowest a_u of the pool's sets hiding it (empty where none does).
    write_tables([config.out], str(tmp_path / "tables"))  # a folder not there yet is made
    with open(tmp_path / "tables" / "scores.csv") as file:
        table = list(csv.DictReader(file))
    names = observation_names("point_mass")
    assert [row["hidden"] for row in table] == names * 3 and {row["pooled"] for row in table} == {"True"}
    for t, row in enumerate(rows):
        for i in range(len(names)):
            hiding = [score for hidden, score in zip(row["sets"], row["scores"]) if i in parse_set(hidden)]
            cell = table[len(names) * t + i]["a_u"]
            assert (float(cell) if cell else None) == (min(hiding) if hiding else None)
    # (one run directory may be given as itself, not in a list)
    assert any("scores_adversarial.png" in path for path in plot_runs(config.out, str(tmp_path / "figures"), formats=("png",)))
    # Fast-forward puts each recorded round's pool in place by its sets' names: from checkpoint
    # 2000, the last interval re-trained without scoring gives the run's final state again.
    shutil.rmtree(os.path.join(config.out, "checkpoints", "3000"))
    forwarded = train_fn(dataclasses.replace(config, total_steps=3000, score_every=1000, checkpoint_every=1,
                                             resume=True, fast_forward=True))
    assert forwarded.scores == rows
    for a, b in zip(jax.tree.leaves(forwarded.state), jax.tree.leaves(result.state)):
        np.testing.assert_array_equal(np.asarray(a), np.asarray(b))
    last = summary_table([config.out]).splitlines()[-1].split(" | ")
    assert last[-3] == "—"  # no final mean_u a_u
    # Where the run is weak at the end: the pool's set of lowest a_u, as the trainer recorded it.
    worst = " + ".join(observation_names("point_mass")[i] for i in parse_set(rows[-1]["argmin_set"]))
    assert last[-1] == f"{worst} (1 of 1) |"


def _feature_zero_controller(gain, masked_obs):
    """Pushes x home using only feature 0 (x); blind to everything else."""
    return jnp.clip(jnp.array([-gain * masked_obs[0], 0.0]), -1.0, 1.0)


def test_score_missingness_equals_a_plain_loop_and_finds_the_used_feature(caplog):
    env = make_env("point_mass", episode_length=60)
    hidden_sets = candidate_sets(4, k=1)
    rng = jax.random.key(7)
    n_episodes = 3
    scored = score_missingness(env, _feature_zero_controller, 2.0, rng, hidden_sets, n_episodes)
    # Called directly it runs compiled: the same call again compiles nothing.
    with jax.log_compiles(), caplog.at_level(logging.WARNING):
        again = score_missingness(env, _feature_zero_controller, 2.0, jax.random.key(8), hidden_sets, n_episodes)
    assert not [record for record in caplog.records if "Compiling" in record.getMessage()]
    assert again.returns.shape == scored.returns.shape and not np.array_equal(again.returns, scored.returns)
    # A pool of 4 slots for the 15 episodes: slots start unstarted episodes as theirs end.
    pooled = score_missingness(env, _feature_zero_controller, 2.0, rng, hidden_sets, n_episodes, num_slots=4)
    np.testing.assert_array_equal(pooled.lengths, scored.lengths)
    np.testing.assert_allclose(pooled.returns, scored.returns, rtol=1e-6)
    assert int(scored.loop_steps) == int(scored.lengths.max())
    assert int(pooled.loop_steps) >= int(np.ceil(scored.lengths.sum() / 4))
    # Checking for running episodes every 7 steps only (GPU hosts wait at each check): the
    # steps past the last episode's end change nothing, and are not counted.
    for reference, slots in ((scored, None), (pooled, 4)):
        checked = score_missingness(env, _feature_zero_controller, 2.0, rng, hidden_sets, n_episodes, num_slots=slots,
                                    steps_per_check=7)
        np.testing.assert_array_equal(checked.lengths, reference.lengths)
        np.testing.assert_allclose(checked.returns, reference.returns, rtol=1e-6)
        assert int(checked.loop_steps) == int(reference.loop_steps)
    # Slots beyond the 15 episodes never run: more than max_batch of them are taken (training's
    # score_envs, used for a smaller scoring), but not 15 episodes at once in an env built for 14
    # (Warp's buffers hold max_batch worlds).
    beyond = score_missingness(env, _feature_zero_controller, 2.0, rng, hidden_sets, n_episodes,
                               num_slots=env.options.max_batch + 1)
    np.testing.assert_array_equal(beyond.returns, scored.returns)
    narrow = make_env("point_mass", episode_length=60, max_batch=14)
    for scoring_env, slots, every, max_steps, message in (
            (narrow, 16, 1, None, "num_slots=16 steps 15 envs at once, more than the env's max_batch=14; build the "
                                  "env with a larger max_batch or give fewer slots"),
            (env, None, 0, None, "steps_per_check must be >= 1, got 0"),
            (env, None, 1, 0, "max_steps must be >= 1, got 0")):
        with pytest.raises(ValueError, match=f"^{re.escape(message)}($|\n)"):  # (JAX may add a note)
            score_missingness(scoring_env, _feature_zero_controller, 2.0, rng, hidden_sets, n_episodes, max_steps,
                              num_slots=slots, steps_per_check=every)

    # Vmapped rollouts whose episodes end at different times (a policy that pushes harder
    # leaves the arena sooner) step together until the last ends: each member's results are its own.
    pushes = jnp.asarray([0.3, 1.0])
    pusher = lambda push, masked_obs: jnp.stack([push + 0.0 * masked_obs[0], 0.0])
    for reference_slots in (None, 4):
        one_rollout = lambda push: score_missingness(env, pusher, push, rng, hidden_sets, n_episodes, num_slots=reference_slots)
        together = jax.jit(jax.vmap(one_rollout))(pushes)
        if reference_slots is None:  # no per-member select of the carry (JAX's batching of a while_loop: one per leaf)
            selects = [jax.jit(program).lower(arg).as_text().count("stablehlo.select")
                       for program, arg in ((one_rollout, pushes[0]), (jax.vmap(one_rollout), pushes))]
            assert selects[0] == selects[1], selects
        alone = [score_missingness(env, pusher, push, rng, hidden_sets, n_episodes, num_slots=reference_slots)
                 for push in pushes]
        assert int(alone[1].loop_steps) < int(alone[0].loop_steps)
        for member, result in enumerate(alone):
            np.testing.assert_array_equal(together.lengths[member], result.lengths)
            np.testing.assert_allclose(together.returns[member], result.returns, rtol=1e-6)
            assert int(together.loop_steps[member]) == int(result.loop_steps)

    step = jax.jit(env.step)
    policy = jax.jit(_feature_zero_controller)
    keys = jax.random.split(rng, n_episodes)
    for row, hidden in enumerate([*hidden_sets, np.zeros(4, np.float32)]):
        for episode in range(n_episodes):
            state, total, length = env.reset(keys[episode]), 0.0, 0
            while length < env.max_episode_steps:
                state = step(state, policy(2.0, mask_observation(state.obs, jnp.asarray(hidden))))
                total += float(state.reward)
                length += 1
                if bool(state.terminated):
                    break
            assert scored.returns[row, episode] == pytest.approx(total, rel=1e-5, abs=1e-4)
            assert int(scored.lengths[row, episode]) == length
    assert int(scored.argmin) == 0
    assert float(scored.scores[0]) < float(scored.clean_score) - 1.0
    np.testing.assert_allclose(scored.scores[1:], scored.clean_score, rtol=1e-6)


def test_while_any_steps_every_member_while_any_runs():
    """``branching.while_any``: unbatched, a ``while_loop``; vmapped (nested too), every member
    runs the body while any member's condition holds, with no per-member select of the carry,
    so results that stop changing with a member's own condition are the ``while_loop``'s."""

    def cond(carry, limit, _):
        return carry["own"] < limit

    def body(carry, limit, increment):
        runs = carry["own"] < limit
        return {"own": carry["own"] + runs.astype(jnp.int32) * increment, "every": carry["every"] + 1}

    start = {"own": jnp.zeros((), jnp.int32), "every": jnp.zeros((), jnp.int32)}
    loop = lambda limit, increment: while_any(cond, body, start, limit, increment)
    assert jax.jit(loop)(3, 1) == {"own": 3, "every": 3}
    limits = jnp.asarray([[1, 2], [3, 7]])
    for vmapped, increment in ((jax.vmap(jax.vmap(loop, in_axes=(0, None)), in_axes=(0, None)), 1),
                               (jax.vmap(jax.vmap(loop)), jnp.ones((2, 2), jnp.int32))):
        out = jax.jit(vmapped)(limits, increment)
        np.testing.assert_array_equal(out["own"], limits)  # as the while_loop's, member by member
        np.testing.assert_array_equal(out["every"], jnp.full((2, 2), 7))  # every member ran all 7 bodies
        hlo = jax.jit(vmapped).lower(limits, increment).as_text()
        assert hlo.count("stablehlo.while") == 1 and "stablehlo.select" not in hlo, "a select of each member's carry"


def test_checkpoint_resume_continues_exactly(tmp_path, capsys):
    """resume=true from a checkpoint, and fast_forward=true from the records alone (the run's
    checkpoints left behind on another machine): both continue the run bit for bit. The run's
    sensors fail mid-episode (fail_at), so its state holds each episode's failure step and the
    replay's steps past it, which the checkpoint and the fingerprint must carry too; its
    scoring's sensors fail too (score_fail_at), which its rows name."""
    from admissable_jax.fast_forward import FastForwardDiverged

    config = dataclasses.replace(POINT_MASS, total_steps=2000, score_every=500, learning_starts=500, checkpoint_every=1,
                                 hidden_size=32, logger="none", fail_at="0,20", score_fail_at="20,0")
    straight = train_fn(dataclasses.replace(config, out=str(tmp_path / "straight")))
    resumed_dir = str(tmp_path / "resumed")
    train_fn(dataclasses.replace(config, total_steps=1000, out=resumed_dir))
    elsewhere = str(tmp_path / "elsewhere")  # what comes back from a lent machine: the records, no checkpoint
    shutil.copytree(resumed_dir, elsewhere, ignore=shutil.ignore_patterns("checkpoints"))
    with pytest.raises(FileExistsError, match="resume=true"):
        train_fn(dataclasses.replace(config, out=resumed_dir))
    with pytest.raises(ValueError, match="cannot resume with seed=1"):
        train_fn(dataclasses.replace(config, out=resumed_dir, resume=True, seed=1))
    resumed = train_fn(dataclasses.replace(config, out=resumed_dir, resume=True))

    assert straight.state.failure_step is not None and straight.state.buffer.data.steps_past_failure is not None
    assert "sensors fail mid-episode: each training episode hides its u from env step 0 or 20 (one drawn per " \
           "episode) on, every feature seen before; scoring hides each set's u from env step 0 or 20 (its N episodes " \
           "split evenly) on" in capsys.readouterr().err
    assert {row["score_fail_at"] for row in straight.scores} == {"0,20"}
    exported = load_policy(straight.run_dir).exported().source  # (what an audit of the exported file names)
    assert (exported["fail_at"], exported["score_fail_at"]) == ("0,20", "0,20")
    assert [r["scores"] for r in resumed.scores] == [r["scores"] for r in straight.scores]
    assert [r["p_miss"] for r in resumed.scores] == [r["p_miss"] for r in straight.scores]
    for a, b in zip(jax.tree.leaves(resumed.state), jax.tree.leaves(straight.state)):
        np.testing.assert_array_equal(np.asarray(a), np.asarray(b))

    # Fast-forward: without a checkpoint, resume=true alone has nothing to start from.
    with pytest.raises(CheckpointError, match=f"no checkpoint to resume from in {elsewhere}/checkpoints; the records "
                                              "reach env step 1000: resume=true fast_forward=true rebuilds the run"):
        train_fn(dataclasses.replace(config, out=elsewhere, resume=True))
    with pytest.raises(ValueError, match="fast_forward=true continues a run from its records: pass resume=true too"):
        train_fn(dataclasses.replace(config, out=elsewhere, fast_forward=True))
    metrics_path = os.path.join(elsewhere, "metrics.jsonl")
    recorded = [json.loads(line) for line in open(metrics_path)]
    assert [row["state_fingerprint"] for row in recorded] == [row["state_fingerprint"] for row in straight.metrics[:2]]
    # A rebuilt state that is not the recorded one (a device that computes differently; here
    # a record altered) stops the command in one line, the records untouched.
    altered = [{**row, "state_fingerprint": row["state_fingerprint"] ^ 1} if row["env_steps"] == 500 else row
               for row in recorded]
    with open(metrics_path, "w") as file:
        file.writelines(json.dumps(row) + "\n" for row in altered)
    ahead = dataclasses.replace(config, out=elsewhere, resume=True, fast_forward=True)
    with pytest.raises(FastForwardDiverged, match=f"fast-forward diverged at env step 500 in {elsewhere}: the rebuilt "
                                                  "state's fingerprint 0x[0-9a-f]{8} is not the recorded") as error:
        train_fn(ahead)
    assert "\n" not in str(error.value)
    assert [json.loads(line) for line in open(metrics_path)] == altered
    with open(metrics_path, "w") as file:
        file.writelines(json.dumps(row) + "\n" for row in recorded)
    # From the records alone: 1,000 env steps re-trained without scoring (learning from 500) to
    # a checkpoint, a command that says so in invocations.jsonl though it wrote no row; then
    # trained on from that checkpoint.
    train_fn(dataclasses.replace(ahead, total_steps=1000))
    assert "fast-forward: re-training env steps 0 to 1000 from the start, each scoring's p_miss read from the " \
           "records; the run ends there" in capsys.readouterr().err
    invocations = [json.loads(line) for line in open(os.path.join(elsewhere, "invocations.jsonl"))]
    assert [(record["from_env_steps"], record["fast_forward_to"]) for record in invocations] == [(0, None), (0, 1000)]
    forwarded = train_fn(dataclasses.replace(ahead, fast_forward=False))
    assert forwarded.scores == straight.scores
    for a, b in zip(jax.tree.leaves(forwarded.state), jax.tree.leaves(straight.state)):
        np.testing.assert_array_equal(np.asarray(a), np.asarray(b))
    # Records without fingerprints (older runs) cannot be checked, so they are not fast-forwarded.
    with open(metrics_path, "w") as file:
        file.writelines(json.dumps({key: value for key, value in row.items() if key != "state_fingerprint"}) + "\n"
                        for row in forwarded.metrics)
    shutil.rmtree(os.path.join(elsewhere, "checkpoints"))
    with pytest.raises(ValueError, match=f"nothing to fast-forward: {elsewhere} records no scoring with a state "
                                         "fingerprint after env step 0"):
        train_fn(dataclasses.replace(ahead, total_steps=2500))


def test_a_state_fingerprint_sees_every_bit_and_where_it_is():
    """The fingerprint a fast-forward checks: equal for equal bits (whatever order a device
    sums in), different for one flipped bit, two values swapped, or a leaf's change of kind."""
    values = jax.random.normal(jax.random.key(0), (1000, 7))
    tree = {"params": values, "steps": jnp.int32(12), "done": jnp.zeros(5, bool), "key": jax.random.PRNGKey(3)}
    fingerprint = jax.jit(tree_fingerprint)
    base = int(fingerprint(tree))
    assert base == int(tree_fingerprint(tree)) == int(fingerprint(jax.tree.map(jnp.copy, tree)))
    flipped = values.at[500, 3].set(jax.lax.bitcast_convert_type(
        jax.lax.bitcast_convert_type(values[500, 3], jnp.uint32) ^ jnp.uint32(1), jnp.float32))
    swapped = values.at[0, 0].set(values[1, 0]).at[1, 0].set(values[0, 0])
    changed = [{**tree, "params": flipped}, {**tree, "params": swapped}, {**tree, "steps": jnp.int32(13)},
               {**tree, "done": tree["done"].at[4].set(True)}, {**tree, "steps": jnp.float32(12)}]
    assert len({base, *(int(fingerprint(other)) for other in changed)}) == 1 + len(changed)
    np.testing.assert_array_equal(jax.vmap(tree_fingerprint)(jax.tree.map(lambda leaf: jnp.stack([leaf, leaf]), tree)),
                                  [base, base])


def test_corrupt_checkpoint_and_divergence_keep_finished_work(tmp_path):
    out = str(tmp_path / "diverges")
    # Learning starts after the first scoring; a huge learning rate then blows up the losses.
    config = dataclasses.replace(
        POINT_MASS, total_steps=3000, score_every=500, learning_starts=600, learning_rate=1e6,
        checkpoint_every=1, out=out, hidden_size=32, logger="none",
    )
    with pytest.raises(TrainingDiverged) as diverged:
        train_fn(config)
    # It names the first loss of the interval that became non-finite (critic, actor, alpha).
    assert str(diverged.value) == (f"critic_loss became non-finite before env step 1000 in {out}; "
                                   f"last checkpoint (step 500) kept in {out}/checkpoints")
    with open(os.path.join(out, "scores.jsonl")) as file:
        assert [json.loads(line)["env_steps"] for line in file] == [500]

    checkpoint = os.path.join(out, "checkpoints", "500")
    for root, _, files in os.walk(checkpoint):
        for name in files:
            with open(os.path.join(root, name), "wb") as file:
                file.write(b"garbage")
    with pytest.raises(CheckpointError, match="checkpoint 500 .* is corrupt .*; no older checkpoint is intact"):
        train_fn(dataclasses.replace(config, resume=True))


def test_a_checkpoint_of_an_older_state_layout_is_named_and_its_networks_still_read(tmp_path):
    """A checkpoint written before TrainState gained a field (as ``lower_bound``) cannot be
    resumed; the error says why, in one line, and offers no older checkpoint (all are alike).
    One that lacks only a bool flag appended last restores with it False."""
    checkpoints = Checkpoints(str(tmp_path / "checkpoints"))
    written = {"sac": jnp.arange(3.0), "pool": jnp.zeros(2, jnp.int32)}
    checkpoints.save(1000, written)
    checkpoints.save(2000, written)
    now = {**written, "z_added_last": jnp.zeros(())}  # leaves flatten in key order: the new one last
    with pytest.raises(OtherStateLayout, match="^checkpoint 2000 in .* holds 2 arrays where this version's training "
                                               "state has 3: another version of admissable_jax wrote it") as error:
        checkpoints.restore(now)
    assert "\n" not in str(error.value) and "intact" not in str(error.value)
    step, sac = checkpoints.read(now, part=lambda state: state["sac"])
    assert step == 2000
    np.testing.assert_array_equal(sac, written["sac"])
    # A mode's flag appended since (mode worst's greedy, per pair of an experiment): restored as
    # False, the only value the older version knew; a flag anywhere else still changes the layout.
    flagged = {**written, "z_flag": jnp.ones(2, bool)}
    step, restored = checkpoints.read(flagged)
    assert step == 2000 and not restored["z_flag"].any() and restored["z_flag"].shape == (2,)
    np.testing.assert_array_equal(restored["sac"], written["sac"])
    with pytest.raises(OtherStateLayout):
        checkpoints.restore({**written, "a_flag": jnp.ones(2, bool)})  # first in key order
    checkpoints.close()


@pytest.mark.parametrize(
    "args, message",
    [
        (["bogus=1"], "unknown key 'bogus' (see --help for the valid keys)"),
        (["total_step=5000"], "unknown key 'total_step' (did you mean total_steps? see --help"),
        (["zeta=5000"], "unknown key 'zeta' (did you mean score_every? see --help"),
        (["total_steps=ten"], "bad value for 'total_steps'"),
        (["env=cheetah"], "unknown env 'cheetah'"),
        (["env=hopper,Walker2d-v5"], "env=hopper,Walker2d-v5 names 2 envs; a command trains or scores one: run one "
                                     "command per env (env=hopper, ...), then plot them together"),
        (["missingness=sometimes"], "missingness must be one of"),
        (["env=hopper", "k=11"], "k must satisfy 1 <= k < d = 11"),
        (["score_envs=-1"], "score_envs must be >= 0"),
        (["worlds_per_call=-1"], "worlds_per_call must be >= 0, got -1"),
        (["env=hopper", "physics=warp", "worlds_per_call=4"],
         "worlds_per_call=4 splits the JAX physics' batch; MuJoCo Warp steps one flat batch"),
        (["physics=cuda"], "physics must be one of auto, jax, warp"),
        (["logger=tensorboard,mlflow"], "logger must be none or a comma list of tensorboard, wandb, got 'tensorboard,mlflow'"),
        (["score_estimator=guess"], "score_estimator must be one of rollout, critic, horizon"),
        (["env=hopper", "k=2", "pool_size=55"], "pool_size=55 is not below |U| = 55"),
        (["env=ant", "k=3"], "C(105, 3) = 187,460 candidate sets exceed the 100,000 that one batched rollout scores "
                             "and one (|U|, d) matrix holds: score a pool of the worst sets a search finds with pool_size=P"),
        (["env=ant", "k=9", "pool_size=16"], "C(105, 9) = 3,005,047,770,725 candidate sets exceed the 2,147,483,647"),
        (["pool_ranker=guess"], "pool_ranker must be one of rollout, critic, horizon"),
        (["pool_size=-1"], "pool_size must be >= 0 (0 = score all sets), got -1"),
        (["env=hopper", "k=2", "pool_size=4", "include_empty_set=true"],
         "pool_size > 0 searches sets of features: it excludes include_empty_set=true"),
        (["env=hopper", "k=2", "pool_size=12"], "pool_size must be <= d = 11 and k <= d/2"),
        (["pool_explore=2"], "pool_explore must be in [0, 1], got 2.0"),
        (["score_horizon=0"], "score_horizon must be >= 1, got 0"),
        (["score_episodes=0"], "score_episodes must be >= 1, got 0"),
        (["time_limit=-5"], "time_limit must be >= 0 (0 = no limit), got -5.0"),
        (["utd=0"], "utd must be > 0, got 0.0"),
        (["epsilon=0"], "epsilon must be > 0, got 0.0"),
        (["gamma=1.5"], "gamma must be in [0, 1], got 1.5"),
        (["tau=0"], "tau must be in (0, 1], got 0.0"),
        (["total_steps=1234.5"], "bad value for 'total_steps'"),
        (["seed=-1"], "seed must be >= 0, got -1"),
        (["resume_step=2000"], "resume_step=2000 picks the checkpoint a run continues from: pass resume=true too"),
        (["resume=true", "resume_step=-2"], "resume_step must be -1 (the latest checkpoint) or a checkpoint's env step"),
        (["learning_starts=100"], "learning_starts (100) must be >= batch_size (256)"),
        (["episode_length=1001"], "episode_length must be <= 1000 (the v5 limit)"),
        (["fast_forward=true"], "fast_forward=true continues a run from its records: pass resume=true too"),
        (["score_every=1000", "num_envs=3"], "score_every (1000) must be a multiple of num_envs (3)"),
        (["episode_length=200", "fail_at=0,200"], "fail_at=200 is not below the episodes' 200 steps: nothing would fail"),
        (["fail_at=soon"], "fail_at must be an env step or a comma list of them, e.g. 0,50,100; got 'soon'"),
        (["score_fail_at=0,20,50"], "score_fail_at=0,20,50 splits each set's score_episodes=10 episodes unevenly: give "
                                    "score_episodes a multiple of 3"),
        (["score_fail_at=20", "score_estimator=critic"], "score_fail_at=20 needs score_estimator=rollout"),
        (["episode_length=200", "score_fail_at=200"], "score_fail_at=200 is not below the episodes' 200 steps"),
    ],
)
def test_cli_rejects_bad_input_with_one_line(args, message, tmp_path, capsys, monkeypatch):
    """In-process (``main``); tests/test_runs.py runs the real command line for a bad input."""
    from admissable_jax.train import main

    def reached_compile(loop):  # a setting let through fails here, at once, not after a million env steps
        raise AssertionError(f"{args} reached the compile")

    monkeypatch.setattr(TrainingLoop, "compile", reached_compile)
    try:
        status = main([*args, f"out={tmp_path}/x", "progress=false"])
    except SystemExit as exit_info:  # parse_args exits; settings train_fn refuses return 2
        status = exit_info.code
    stderr = capsys.readouterr().err
    assert status == 2
    assert message in stderr
    assert len(stderr.strip().splitlines()) == 1, stderr
    assert not os.path.exists(tmp_path / "x")  # refused before anything is created


def test_settings_whose_effect_their_keys_do_not_say_are_warned():
    """A run says, one warning line each, where its settings do what their keys do not say: its
    total_steps rounded up to a multiple of ζ; a learning_starts not below its planned env
    steps (SAC never updates), and a utd whose
    num_envs · utd gradient steps per iteration is rounded (the run's utd is another); not
    for a product that float arithmetic leaves a hair off a whole number (100 · 0.07); and a
    replay buffer that holds fewer transitions than one minibatch."""
    from admissable_jax.config import setting_warnings

    def warnings(**settings):
        return setting_warnings(dataclasses.replace(POINT_MASS, **settings).resolved())

    assert warnings() == warnings(num_envs=100, utd=0.07) == warnings(num_envs=8, utd=0.25) == []
    assert warnings(num_envs=4, utd=0.3) == [
        "utd=0.3 with num_envs=4 asks for 1.2 gradient steps per iteration, which is rounded to 1: the run's utd is "
        "0.25 (choose num_envs and utd whose product is a whole number)"]
    assert warnings(total_steps=1000, learning_starts=1000) == [
        "learning_starts=1000 is not below the run's 1000 env steps: SAC never updates, and every scoring scores the "
        "untrained policy (lower learning_starts or raise total_steps)"]
    assert warnings(total_steps=1001, learning_starts=1000) == [  # planned: 2000 env steps (ζ = 1000), said
        "the run trains 2,000 env steps: total_steps=1001 rounded up to a multiple of score_every=1000, as every "
        "interval ends in a scoring"]
    # A replay buffer smaller than a minibatch (as rounded to whole iterations): minibatches repeat the last steps.
    assert warnings(buffer_size=1) == [
        "buffer_size=1 holds 4 transitions (rounded to a multiple of num_envs=4), fewer than one minibatch "
        "(batch_size=128): every minibatch repeats transitions, all from the last 4 env steps (raise buffer_size)"]
    assert warnings(buffer_size=100, batch_size=101) == [
        "buffer_size=100 holds 100 transitions, fewer than one minibatch (batch_size=101): every minibatch repeats "
        "transitions, all from the last 100 env steps (raise buffer_size)"]
    assert warnings(buffer_size=131) == warnings(buffer_size=128, batch_size=128) == []  # 131: 128 rows, a whole minibatch


def test_numpy_scalars_are_settings_as_python_numbers():
    """A sweep's np.arange seeds or np.linspace bounds are settings as the Python numbers they
    name (they were refused: "seed must be int, got np.int64(2)"); a float for an int field
    still is."""
    import numpy as np

    config = dataclasses.replace(POINT_MASS, seed=np.int64(2), lower_bound=np.float32(0.5), gamma=np.int64(1)).resolved()
    assert (config.seed, config.lower_bound, config.gamma) == (2, 0.5, 1.0)
    assert (type(config.seed), type(config.lower_bound), type(config.gamma)) == (int, float, float)
    with pytest.raises(TypeError, match=r"^total_steps must be int, got np.float64\(1000.0\)$"):
        dataclasses.replace(POINT_MASS, total_steps=np.float64(1000)).resolved()
    # fail_at and score_fail_at from Python as a step or a list of them: the sorted comma lists a run saves.
    assert [dataclasses.replace(POINT_MASS, fail_at=given).resolved().fail_at
            for given in (np.int64(50), [50, 0, 50], np.array([20, 10]), " 30 , 5")] == ["50", "0,50", "10,20", "5,30"]
    assert [dataclasses.replace(POINT_MASS, score_fail_at=given).resolved().score_fail_at
            for given in (np.int64(50), [50, 0, 50], " 30 , 5")] == ["50", "0,50", "5,30"]
    # An experiment from Python: modes, lower_bounds and fail_at as sequences too (they failed
    # deep inside: "'list' object has no attribute 'split'"), saved as the command line's comma lists.
    from admissable_jax.config import ExperimentConfig, pair_configs
    from admissable_jax.experiment import run_experiment

    given = ExperimentConfig(env="point_mass", modes=["adversarial", "uniform"], lower_bounds=np.linspace(0, 50, 2),
                             seeds=np.int64(2), out="sweep", fail_at=(0, 20), score_fail_at=[20, 0]).resolved()
    assert given == ExperimentConfig(env="point_mass", modes="adversarial,uniform", lower_bounds="0.0,50.0", seeds=2,
                                     out="sweep", fail_at="0,20", score_fail_at="20,0")
    assert [os.path.basename(pair.out) for pair in pair_configs(given)] == [
        "adversarial-l0-s0", "adversarial-l0-s1", "adversarial-l50-s0", "adversarial-l50-s1", "uniform-s0", "uniform-s1"]
    with pytest.raises(TypeError, match=r"^seeds must be int, got '3'$"):
        ExperimentConfig(env="point_mass", seeds="3").resolved()
    with pytest.raises(TypeError, match=r"^run_experiment expects an ExperimentConfig, got TrainConfig \(one run: "
                                        r"train_fn\)$"):
        run_experiment(POINT_MASS)  # (it said "'TrainConfig' object has no attribute 'modes'")


def test_config_file_sets_keys_the_command_line_overrides(tmp_path, capsys, monkeypatch):
    """``config=FILE``: a run's config.yaml (or an experiment's, or one's own) sets the keys,
    key=value items override them; the keys that say which run the file came from are left
    out, said in one line; a bad file is one line and exit 2, from train's and experiment's
    own command lines."""
    from admissable_jax.cli import parse_args
    from admissable_jax.config import ExperimentConfig, config_file_of, run_out
    from admissable_jax.experiment import main as experiment_main
    from admissable_jax.train import main as train_main

    saved = tmp_path / "config.yaml"
    OmegaConf.save(OmegaConf.structured(dataclasses.replace(POINT_MASS, k=2, score_episodes=3, missingness="uniform",
                                                            seed=4, out="runs/old").resolved()), saved)
    train = parse_args(TrainConfig, [f"config={saved}", "seed=1"], "t", "", config_file=config_file_of(TrainConfig))
    assert (train.env, train.k, train.score_episodes, train.missingness, train.seed, train.out) == (
        "point_mass", 2, 3, "uniform", 1, "")
    assert capsys.readouterr().err == f"config={saved}: fast_forward, out, resume, resume_step not taken from it (they say which run it came from)\n"
    experiment = parse_args(ExperimentConfig, [f"config={saved}", "seeds=2"], "e", "",
                            config_file=config_file_of(ExperimentConfig))
    assert (experiment.env, experiment.k, experiment.score_episodes, experiment.seeds, experiment.modes) == (
        "point_mass", 2, 3, 2, "adversarial,uniform")
    assert "fast_forward, missingness, out, resume, resume_step, seed not taken" in capsys.readouterr().err

    # resume=true without config=: the resumed run's own config.yaml gives the keys, so that
    # resume=true out=DIR needs no other; the invocation's and machine's own keys (time_limit,
    # progress, score_envs, worlds_per_call) are not taken from it. Where out is not given, it is the run of
    # env, missingness and seed; config= names the file instead.
    run = tmp_path / "runs" / "point_mass-uniform-s4"
    run.mkdir(parents=True)
    OmegaConf.save(OmegaConf.structured(dataclasses.replace(
        POINT_MASS, k=2, score_episodes=5, missingness="uniform", seed=4, time_limit=60.0, progress=False,
        score_envs=6, worlds_per_call=4, out=str(run)).resolved()), run / "config.yaml")
    monkeypatch.chdir(tmp_path)
    for argv in (["resume=true", f"out={run}", "total_steps=9000"],
                 ["resume=true", "env=point_mass", "missingness=uniform", "seed=4", "total_steps=9000"]):
        resumed = parse_args(TrainConfig, argv, "t", "", config_file=config_file_of(TrainConfig))
        assert (resumed.env, resumed.k, resumed.score_episodes, resumed.missingness, resumed.seed, resumed.total_steps,
                resumed.time_limit, resumed.progress, resumed.score_envs, resumed.worlds_per_call, resumed.resume) == (
            "point_mass", 2, 5, "uniform", 4, 9000, 0.0, True, 0, 0, True), argv
        said = capsys.readouterr().err
        assert said == f"resume=true: the run's settings from {run_out(resumed)}/config.yaml; keys given here override them\n"
    resumed = parse_args(TrainConfig, [f"config={saved}", "resume=true", f"out={run}"], "t", "",
                         config_file=config_file_of(TrainConfig))
    assert (resumed.score_episodes, resumed.out) == (3, str(run)) and "not taken from it" in capsys.readouterr().err
    fresh = parse_args(TrainConfig, [f"out={run}"], "t", "", config_file=config_file_of(TrainConfig))
    assert (fresh.env, fresh.k) == (TrainConfig.env, TrainConfig.k) and not capsys.readouterr().err
    # worlds_per_call, a machine's setting, reaches the env the run builds (EnvOptions.worlds_per_call).
    assert RunSpec.of(dataclasses.replace(POINT_MASS, worlds_per_call=4).resolved()).env_options.worlds_per_call == 4

    # Step counts as researchers write them: 1e6 on the command line (a float to OmegaConf),
    # 2e5 in YAML (a string to it), both taken as ints; 1234.5 is refused (above).
    (tmp_path / "counts.yaml").write_text("total_steps: 2e5\nseeds: 3.0\n")
    experiment = parse_args(ExperimentConfig, [f"config={tmp_path / 'counts.yaml'}", "score_every=5e3"], "e", "",
                            config_file=config_file_of(ExperimentConfig))
    assert (experiment.total_steps, experiment.seeds, experiment.score_every) == (200_000, 3, 5000)
    assert type(experiment.total_steps) is type(experiment.score_every) is int
    train = parse_args(TrainConfig, ["total_steps=1e6", "epsilon=1e-8"], "t", "")
    assert (train.total_steps, train.epsilon) == (1_000_000, 1e-8) and type(train.total_steps) is int
    # A key given twice counts at its last value (README), as a key added to a command from one's history.
    train = parse_args(TrainConfig, ["env=hopper", "seed=2", "env=ant"], "t", "")
    assert (train.env, train.seed) == ("ant", 2)

    (tmp_path / "typo.yaml").write_text("env: hopper\nlerning_rate: 0.001\n")
    (tmp_path / "bad_value.yaml").write_text("k: two\n")
    (tmp_path / "broken.yaml").write_text("k: [1\n")
    (tmp_path / "list.yaml").write_text("- k\n")
    for main, args, message in [
        (train_main, [f"config={tmp_path / 'missing.yaml'}"], f"cannot read config={tmp_path / 'missing.yaml'}: No such file"),
        (train_main, [f"config={tmp_path / 'typo.yaml'}"],
         f"unknown key 'lerning_rate' in config={tmp_path / 'typo.yaml'} (did you mean learning_rate? see --help"),
        (experiment_main, [f"config={tmp_path / 'bad_value.yaml'}"], f"in config={tmp_path / 'bad_value.yaml'}: bad value for 'k'"),
        (experiment_main, [f"config={tmp_path / 'broken.yaml'}"], f"config={tmp_path / 'broken.yaml'} is not valid YAML (line 2)"),
        (train_main, [f"config={tmp_path / 'list.yaml'}"], f"config={tmp_path / 'list.yaml'} must hold key: value lines"),
        (train_main, [f"config={saved}", f"config={saved}"], "config= given 2 times"),
    ]:
        with pytest.raises(SystemExit) as exit_info:
            main([*args, f"out={tmp_path / 'never'}"])
        error = capsys.readouterr().err.strip()
        assert exit_info.value.code == 2 and error.startswith(f"error: {message}") and "\n" not in error, error
    assert not (tmp_path / "never").exists()


def test_a_run_without_keys_has_the_papers_and_sb3s_settings():
    """The paper's Table 1 (ζ = 5000, ε = 1e-8, l = 0), its k = 1, adversarial mode and 1M env
    steps, our N = 10 (the paper leaves N open), and SB3's SAC, which the paper trains with:
    the CLI's SAC defaults are the agent's own (``config.SB3_SAC``)."""
    config = TrainConfig()
    paper = dict(score_every=5000, epsilon=1e-8, lower_bound=0.0, k=1, up_to_k=False, include_empty_set=False,
                 missingness="adversarial", total_steps=1_000_000, score_episodes=10, score_estimator="rollout",
                 episode_length=1000)
    sac = dict(learning_rate=3e-4, gamma=0.99, tau=0.005, batch_size=256, hidden_size=256, hidden_layers=2,
               buffer_size=1_000_000, utd=1.0)
    assert {key: getattr(config, key) for key in {**paper, **sac}} == {**paper, **sac}


def test_cli_help_lists_every_key():
    result = subprocess.run(
        [sys.executable, "-m", "admissable_jax.train", "--help"], capture_output=True, text=True
    )
    assert result.returncode == 0
    for field in dataclasses.fields(TrainConfig):
        assert f"  {field.name}=" in result.stdout


def test_train_step_vmaps_over_seeds_and_modes():
    """Three (seed, mode, l) pairs in one vmapped program give each pair's unbatched result
    (scoring on a pool of 3 slots for the 10 episodes, so refills run under vmap too). The
    second pair starts 64 env steps on, so for 16 iterations one pair learns and the other
    does not; and the vmapped program still branches on learning_starts (branching.lazy_cond)
    rather than computing every update for every pair. The third is the first with another
    lower bound l: the same scores, and p_miss by its own l (one program sweeps l). The fourth
    is the first in mode worst: the same scores, and p_miss all on their argmin."""
    env = make_env("point_mass", episode_length=20)
    config = dataclasses.replace(POINT_MASS, learning_starts=64, batch_size=32, episode_length=20, score_envs=3,
                                 score_episodes=2, hidden_size=32).resolved()
    trainer = Trainer(env, RunSpec.of(config))

    def run(head_start, *init_arguments):
        state = trainer.init(*init_arguments)
        state, _ = trainer.run_chunk(state.replace(env_steps=state.env_steps + head_start), 40)
        state, scores = trainer.score_and_update(state)
        return state, scores.scores

    chunk = lambda state: trainer.run_chunk(state, 40)
    state_shapes = jax.eval_shape(trainer.init, 0, True, True, 0.0)
    pair_shapes = jax.tree.map(lambda leaf: jax.ShapeDtypeStruct((2, *leaf.shape), leaf.dtype), state_shapes)
    branches = [jax.jit(program).lower(shapes).as_text().count("stablehlo.case")
                for program, shapes in ((chunk, state_shapes), (jax.vmap(chunk), pair_shapes))]
    assert branches == [1, 1]  # learning_starts' branch, one run or two pairs

    pairs = (jnp.array([0, 64, 0, 0]), *stacked_init_arguments([
        dataclasses.replace(config, seed=seed, missingness=mode, lower_bound=lower_bound)
        for seed, mode, lower_bound in ((0, "adversarial", 0.0), (1, "uniform", 0.0), (0, "adversarial", 9.0),
                                        (0, "worst", 0.0))]))
    batched, unbatched = jax.jit(jax.vmap(run)), jax.jit(run)
    batched_state, batched_scores = batched(*pairs)
    for pair, arguments in enumerate(zip(*pairs)):
        state, scores = unbatched(*arguments)
        np.testing.assert_allclose(batched_scores[pair], scores, rtol=1e-4, atol=1e-4)
        np.testing.assert_allclose(
            batched_state.sac.actor_params["params"]["Dense_0"]["kernel"][pair],
            state.sac.actor_params["params"]["Dense_0"]["kernel"], rtol=1e-4, atol=1e-5,
        )
        assert int(batched_state.grad_steps[pair]) == int(state.grad_steps) > 0
    assert batched_state.grad_steps[0] < batched_state.grad_steps[1]  # the head start learned longer
    # The adversarial pairs moved p_miss, each by its own l (eq. of §3); the uniform one did not.
    assert not np.allclose(batched_state.p_miss[0], 0.25)
    np.testing.assert_allclose(batched_state.p_miss[1], 0.25)
    np.testing.assert_array_equal(batched_scores[2], batched_scores[0])
    for pair, lower_bound in ((0, 0.0), (2, 9.0)):
        np.testing.assert_allclose(batched_state.p_miss[pair],
                                   inverse_score_p_miss(batched_scores[pair], lower_bound, config.epsilon), rtol=1e-5)
    assert not np.allclose(batched_state.p_miss[2], batched_state.p_miss[0], rtol=1e-3)
    # Mode worst: every episode hides argmin_u a_u, the deterministic adversary (§3).
    np.testing.assert_array_equal(batched_scores[3], batched_scores[0])
    np.testing.assert_array_equal(batched_state.p_miss[3], np.eye(4)[int(np.argmin(batched_scores[3]))])
    np.testing.assert_array_equal(worst_set_p_miss(np.array([3.0, 1.0, 2.0, 1.0])), [0.0, 0.5, 0.0, 0.5])  # ties share
    # A state of another mode fingerprints as one without the flag (an earlier version's records).
    first = jax.tree.map(lambda leaf: leaf[0], batched_state)
    assert int(tree_fingerprint(first)) == int(tree_fingerprint(first.replace(greedy=None)))
