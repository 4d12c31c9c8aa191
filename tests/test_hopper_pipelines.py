"""Hopper end to end on both physics backends: ``train_fn`` on MJX's JAX implementation, an
experiment of three (seed, mode) pairs on MuJoCo Warp (on the CPU here), the two checked
against each other, and the GPU campaign's Hopper chain (benchmarks/gpu_campaign.sh in smoke
mode) repeating that experiment across device calls and a paused and resumed worker.

Warp programs compile in seconds, so the Warp side runs the whole experiment pipeline
(nested vmap over Warp data, checkpoints, resume); the JAX side is one short ``train_fn``
run (each JAX Hopper program costs a minute or more to compile on a small CPU). Short
horizons, where float32 physics on the two backends agree. The sizes are the campaign's
smoke sizes.
"""

from __future__ import annotations

import json
import os
import shutil
import signal
import subprocess
import sys
import tarfile
import warnings

import jax
import jax.numpy as jnp
import numpy as np
import pytest
import yaml

from admissable_jax import TrainConfig, make_env
from admissable_jax.best_policy import best_kept
from admissable_jax.envs import observation_names
from admissable_jax.experiment import ExperimentConfig, run_experiment
from admissable_jax.exported_policy import ExportedPolicy
from admissable_jax.host_loop import PhysicsCapacityExceeded
from admissable_jax.policies import load_policy
from admissable_jax.train import train_fn
import campaign  # benchmarks/ is on the tests' path (conftest.py)
import device_pack
from test_figure1 import _figure1

# 80 env steps in 2 scorings of 40 (10 iterations of 4 envs each); learning from step 48.
HOPPER = dict(
    env="hopper", score_every=40, num_envs=4, learning_starts=48, batch_size=32, hidden_size=32,
    buffer_size=1000, score_episodes=2, score_envs=24, episode_length=10, checkpoint_every=1, progress=False,
)


@pytest.fixture(scope="module")
def jax_run(tmp_path_factory):
    """Adversarial seed 0 on the JAX backend, through train_fn."""
    out = str(tmp_path_factory.mktemp("hopper") / "jax")
    return train_fn(TrainConfig(**HOPPER, physics="jax", total_steps=80, missingness="adversarial", out=out))


@pytest.fixture(scope="module")
def warp_experiment(tmp_path_factory):
    """(adversarial, uniform, none) × seed 0 on Warp, vmapped in one program."""
    out = str(tmp_path_factory.mktemp("hopper") / "warp")
    return run_experiment(ExperimentConfig(**HOPPER, physics="warp", seeds=1, modes="adversarial,uniform,none",
                                           total_steps=80, out=out))


def test_short_hopper_run_through_train_fn(jax_run):
    assert jax_run.config.physics == "jax" and jax_run.trainer.env.physics_name == "jax"
    assert [row["env_steps"] for row in jax_run.scores] == [40, 80]
    for row in jax_run.scores:
        assert len(row["scores"]) == 11
        assert 0 < row["mean_episode_length"] <= 10
        assert np.isfinite(row["clean_score"])
        assert row["min_score"] == min(row["scores"])
    # Learning starts once more than 48 env steps are collected: after iteration 13 of 20
    # (4 envs each), so iterations 13..20 take 4 gradient steps each.
    assert [row["grad_steps"] for row in jax_run.metrics] == [0, 8 * 4]
    assert int(jax_run.state.grad_steps) == 32 and int(jax_run.state.env_steps) == 80
    assert sorted(os.listdir(os.path.join(jax_run.run_dir, "checkpoints"))) == ["40", "80"]


def test_warp_experiment_matches_jax_train_fn(jax_run, warp_experiment):
    """The Warp experiment's adversarial pair and the JAX backend's unbatched run of the same
    seed and mode: same buffer, same scores, the same learning."""
    warp = warp_experiment[0]
    assert (warp.config.missingness, warp.config.seed, warp.config.physics) == ("adversarial", 0, "warp")
    assert warp.trainer.env.physics_name == "warp"
    assert int(warp.state.grad_steps) == int(jax_run.state.grad_steps) == 32
    assert [row["episodes"] for row in warp.metrics] == [row["episodes"] for row in jax_run.metrics]
    np.testing.assert_allclose(warp.state.buffer.data.obs, jax_run.state.buffer.data.obs, atol=2e-3)
    np.testing.assert_allclose(warp.state.buffer.data.reward, jax_run.state.buffer.data.reward, atol=2e-3)
    for warp_row, jax_row in zip(warp.scores, jax_run.scores):
        np.testing.assert_allclose(warp_row["scores"], jax_row["scores"], rtol=1e-3, atol=1e-2)
        np.testing.assert_allclose(warp_row["clean_score"], jax_row["clean_score"], rtol=1e-3, atol=1e-2)
        np.testing.assert_allclose(warp_row["p_miss"], jax_row["p_miss"], rtol=1e-3)
    # 32 Adam steps move each parameter by at most ~1e-2, so compare what learning changed
    # (relative), not the parameters (which are mostly their common initialisation).
    initial = jax_run.trainer.agent.init(jax.random.split(jax.random.PRNGKey(0), 4)[1]).actor_params
    for warp_leaf, jax_leaf, start in zip(*(jax.tree.leaves(p) for p in (warp.actor_params, jax_run.actor_params, initial))):
        jax_change, warp_change = np.asarray(jax_leaf - start), np.asarray(warp_leaf - start)
        assert np.linalg.norm(jax_change) > 0
        assert np.linalg.norm(warp_change - jax_change) <= 0.05 * np.linalg.norm(jax_change)


CALL_AGAIN, REFUSED = 75, 3


WITHOUT_MODULES = os.path.join(os.path.dirname(__file__), "data", "without_modules")


def _campaign(step: str, directory: str, **settings: str) -> subprocess.CompletedProcess:
    """A device call of ``gpu_campaign.sh STEP``, without the modules of the wheels the device packs leave out."""
    env = {**os.environ, "JAX_PLATFORMS": "cpu", "CAMPAIGN_SMOKE": "1", "CAMPAIGN_DIR": directory,
           "PYTHON": sys.executable, "PYTHONPATH": os.pathsep.join(filter(None, (WITHOUT_MODULES, os.environ.get("PYTHONPATH")))),
           "WITHOUT_MODULES": ",".join(device_pack.LEFT_OUT_MODULES),
           "WITHOUT_MODULES_LOG": directory + "-without-modules.log", **settings}
    env.pop("OUT", None)
    call = subprocess.Popen(["bash", os.path.join(os.path.dirname(__file__), "..", "benchmarks", "gpu_campaign.sh"), step],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env, start_new_session=True)
    stdout, stderr = call.communicate(timeout=900)
    try:  # as the device machine does when a call returns: kill what it left, bar new process sessions
        os.killpg(call.pid, signal.SIGKILL)
    except ProcessLookupError:
        pass
    return subprocess.CompletedProcess(call.args, call.returncode, stdout, stderr)


def _packed(directory: str, step: str) -> dict[str, bytes]:
    with tarfile.open(os.path.join(directory, "out", f"campaign-{step}.tar.gz")) as tar:
        return {member.name: tar.extractfile(member).read() for member in tar.getmembers() if member.isfile()}


def _repeats_the_straight_run(packed: dict[str, bytes], warp_experiment, rounds: int = 2) -> None:
    """Each pair's packed ``scores.jsonl`` holds the uninterrupted experiment's first
    ``rounds`` rounds: its scores and p_miss, bit for bit."""
    for straight in warp_experiment:
        rows = [json.loads(line) for line in packed[f"./hopper/{straight.config.missingness}-s0/scores.jsonl"].splitlines()]
        assert [row["scores"] for row in rows] == [row["scores"] for row in straight.scores[:rounds]]
        assert [row["p_miss"] for row in rows] == [row["p_miss"] for row in straight.scores[:rounds]]


def _final_policies_are_the_straight_runs(directory: str, warp_experiment, into: str) -> None:
    """The final policies the hopper step's last call packed: one per pair, at env step 80,
    the layers the uninterrupted experiment's last checkpoint exports."""
    with tarfile.open(os.path.join(directory, "out", "campaign-hopper-final-policies.tar.gz")) as tar:
        assert sorted(tar.getnames()) == [f"./hopper/{pair}/exported/policy-step80.npz"
                                          for pair in ("adversarial-s0", "none-s0", "uniform-s0")]
        tar.extractall(into, filter="data")
    for straight in warp_experiment:
        pair = f"{straight.config.missingness}-s0"
        final = ExportedPolicy.load(os.path.join(into, "hopper", pair, "exported", "policy-step80.npz"))
        expected = load_policy(straight.run_dir).exported()
        assert (final.source["missingness"], final.source["env_steps"]) == (straight.config.missingness, 80)
        for got, want in zip(final.weights + final.biases, expected.weights + expected.biases, strict=True):
            np.testing.assert_array_equal(got, want)


def _fresh_machine(directory: str, speed_records: str) -> str:
    """A campaign folder as a new lease starts it: nothing but the speed step's records."""
    os.makedirs(os.path.join(directory, "results"))
    shutil.copy(speed_records, os.path.join(directory, "results"))
    return directory


def test_gpu_campaign_hopper_chain_in_smoke_mode(warp_experiment, tmp_path):
    """The campaign as a lent GPU runs it, on the CPU: the speed step's measurement that
    plans read; a run refused for lack of time (nothing started); a run admitted, whose
    worker outlives the call that starts it and is followed to its end by the next call; a
    run paused and resumed by the next worker from the checkpoint holding Warp data,
    repeating the uninterrupted experiment exactly; what each call packs for the trip back;
    runs continued on another machine from the records a call brought back (CAMPAIGN_RECORDS:
    fast-forwarded, then trained on), again exactly the uninterrupted experiment; a run
    bounded by the deadline rather than by its plan, stopped where the deadline leaves no
    room for another interval; first of all, whether the machine repeats a run from its records.
    All of it without the modules of the wheels the device packs leave out."""
    directory = str(tmp_path / "campaign")
    speed = _campaign("speed", directory, CAMPAIGN_ONLY="^(repeatability-hopper|determinism-cost-hopper-.*|measure-hopper|projections)$")
    assert speed.returncode == 0, speed.stdout + speed.stderr
    # First, whether the machine repeats a run from its records alone (the CPU does), in the
    # deterministic mode, with XLA's deterministic flags (which the CPU's XLA accepts).
    assert "hopper, 80 env steps: repeated bit for bit" in speed.stdout
    (repeat,) = [json.loads(line) for line in open(os.path.join(directory, "results", "repeatability.jsonl"))]
    assert repeat["repeated"] and "--xla_gpu_deterministic_ops=true" in repeat["xla_flags"]
    assert "deterministic_physics=true" in repeat["extra"]
    # ...and what the mode costs: the env step with it and without, each in a process of its own;
    # with it, also without a CUDA graph (NONE), where a GPU's Warp checks the mode's buffers.
    with open(os.path.join(directory, "results", "physics_throughput.jsonl")) as file:
        costs = [json.loads(line) for line in file]
    assert sorted((row["deterministic"], row["graph_mode"] or "", row["mujoco_warp"], row["num_envs"]) for row in costs) == [
        (False, "", "mujoco-warp package", 4), (True, "", "mujoco-warp package", 4),
        (True, "NONE", "mujoco-warp package", 4)], costs
    for row in costs:  # env steps per second: every env's steps, from the ms a batched step takes
        # (the record rounds it to 0.1: at the CPU's 40-odd env steps/s that is more than 0.1%)
        assert row["env_steps_per_s"] == pytest.approx(row["num_envs"] * 1000 / row["env_ms_per_step"], rel=1e-3,
                                                       abs=0.051), row
        # The speed step's first goal, our env step over the bare physics of as many steps:
        # near 1 here (0.93 to 1.35 in every CPU record), as Warp's step outweighs the env's work.
        # Bounds wide enough for a busy machine (one timed call each, 10 steps): a bare rollout
        # of fewer steps than the env's reads far above them.
        assert row["env_over_bare"] == pytest.approx(row["env_ms_per_step"] / row["bare_ms_per_step"], rel=1e-2), row
        assert 0.4 < row["env_over_bare"] < 4, row
    # The speed step ends with steps 2-4 projected from what it measured (here Hopper only):
    # the 3 pairs at full length fit, so the run is theirs.
    assert "projected wall time for Hopper-v5, 3 pairs x 4 envs (warp" in speed.stdout
    assert "modes=adversarial,uniform,none total_steps=80" in speed.stdout
    assert "walker2d (adversarial,uniform,none): not projected: no speed record" in speed.stdout
    assert "ant (adversarial,uniform): not projected: no speed record" in speed.stdout
    records_path = os.path.join(directory, "results", "campaign_speed.jsonl")
    with open(records_path) as file:
        (record,) = [json.loads(line) for line in file]
    assert (record["env"], record["physics"], record["pairs"], record["num_envs"]) == ("Hopper-v5", "warp", 3, 4)
    assert record["device"].startswith("cpu") and record["learned_share"] > 0
    # Full length: each pair's (11 + 1) × 2 episodes at once (24 slots: fewer loop steps, where
    # the Warp step on a CPU costs its kernel launches), 10 steps each.
    assert record["score_full_loop_steps"] == 10
    assert {"./state/measure-hopper.done", "./results/repeatability.jsonl"} <= set(_packed(directory, "speed"))

    # Too little device time: the 3 pairs are refused, then the 2 (planned from the 3 pairs'
    # record, an upper bound), then the longest run: not even one interval fits; nothing starts.
    refused = _campaign("hopper", directory, CAMPAIGN_DEADLINE="1", CAMPAIGN_MIN_STEPS="60", CAMPAIGN_FIRST_SEED="5")
    assert refused.returncode == REFUSED, refused.stdout + refused.stderr
    assert " first_seed=5 deadline=1 min_steps=60 " in refused.stdout  # seeds 5.. (CAMPAIGN_FIRST_SEED) planned
    assert refused.stdout.count("does not fit, refused") == 2
    assert "hopper cannot reach 80 env steps in 1 s: the longest run that fits instead" in refused.stdout
    assert "fits in 1 s: 40 env steps, the shortest, take compile" in refused.stdout
    assert "refused: hopper: fewer than 60 env steps fit in 1 s" in refused.stdout
    assert not os.path.exists(os.path.join(directory, "hopper"))

    # An earlier step's policies on this machine (they came back with it): never packed again.
    earlier = os.path.join(directory, "walker2d", "adversarial-s0")
    os.makedirs(os.path.join(earlier, "exported"))
    for name in ("best_policy.npz", os.path.join("exported", "policy-step80.npz")):
        open(os.path.join(earlier, name), "w").close()

    # A worker paused by CAMPAIGN_RUN_SECONDS after its first scoring (as a failed one would
    # leave it), then a worker that resumes it, started by a call that returns at once and
    # followed by the next.
    first = _campaign("hopper", directory, CAMPAIGN_RUN_SECONDS="0.001")
    assert first.returncode == CALL_AGAIN, first.stdout + first.stderr
    assert "projected wall time for Hopper-v5, 3 pairs x 4 envs (warp" in first.stdout and "fits" in first.stdout
    assert "hopper is not finished: the next worker resumes it" in first.stdout
    assert " deterministic_physics=true first_seed=0 " in first.stdout  # the mode said, not left to the default
    halfway = str(tmp_path / "halfway.tar.gz")  # what that call brought back: the runs' records to env step 40
    shutil.copy(os.path.join(directory, "out", "campaign-hopper.tar.gz"), halfway)
    started = _campaign("hopper", directory, CAMPAIGN_CALL_SECONDS="0")
    assert started.returncode == CALL_AGAIN, started.stdout + started.stderr
    pid = started.stdout.split("started the hopper worker (pid ")[1].split(")")[0]
    assert f"call again: the hopper worker (pid {pid}) runs on" in started.stdout
    followed = _campaign("hopper", directory, CAMPAIGN_PACK_SECONDS="1")
    assert followed.returncode == 0, followed.stdout + followed.stderr
    assert f"following the hopper worker (pid {pid})" in followed.stdout
    assert followed.stdout.count("packed ") >= 2  # while following, and at the end
    assert "resume=true" in followed.stdout + started.stdout and "step hopper complete" in followed.stdout
    packed = _packed(directory, "hopper")
    assert b"paused at 40 of 80 env steps" in packed["./hopper.log"]
    _repeats_the_straight_run(packed, warp_experiment)
    # ...and, packed apart once the run has ended (none while it was paused), each run's final
    # policy: its last checkpoint's actor as NumPy arrays, the straight run's bit for bit.
    assert "packed 0 final policies" in first.stdout
    _final_policies_are_the_straight_runs(directory, warp_experiment, str(tmp_path / "finals"))

    # The next lease continues the runs from the records the paused call brought back: a
    # fresh machine (folder) with only the speed record, the runs rebuilt bit for bit to env
    # step 40 without scoring, then trained and scored on, as the straight experiment.
    elsewhere = _fresh_machine(str(tmp_path / "next-lease"), records_path)
    continued = _campaign("hopper", elsewhere, CAMPAIGN_RECORDS=halfway)
    assert continued.returncode == 0, continued.stdout + continued.stderr
    assert f"continuing the hopper runs of {halfway}" in continued.stdout
    assert "+ 1 recorded interval re-trained x chunk" in continued.stdout
    assert "fast-forward: re-training env steps 0 to 40 from the start" in continued.stdout
    _repeats_the_straight_run(_packed(elsewhere, "hopper"), warp_experiment)
    assert "packed 3 final policies" in continued.stdout

    # A run goes on past its planned length while the deadline allows, and stops where it
    # does not. The deadline here plans 40 env steps (one scoring fits, two do not); the run is
    # given max_steps (80) and time_limit from the deadline, which CAMPAIGN_RESERVE uses up,
    # so it stops after its first interval: the step complete, its records whole.
    bounded = _fresh_machine(str(tmp_path / "deadline"), records_path)
    one, two = (campaign.project(record, scorings, checkpoint_every=1).total_s for scorings in (1, 2))
    stopped = _campaign("hopper", bounded, CAMPAIGN_DEADLINE=f"{(one + two) / 2:.3f}", CAMPAIGN_RESERVE="100000")
    assert stopped.returncode == 0, stopped.stdout + stopped.stderr
    assert "modes=adversarial,uniform,none total_steps=40" in stopped.stdout  # the plan's 40
    assert "total_steps=80 " in stopped.stdout and " time_limit=1 (40 env steps planned" in stopped.stdout
    assert "hopper stopped at the deadline: 40 env steps (40 planned)" in stopped.stdout
    assert "step hopper complete" in stopped.stdout
    assert stopped.stdout.count("/exported/policy-step40.npz: hopper") == 3  # the final policies: where it stopped
    _repeats_the_straight_run(_packed(bounded, "hopper"), warp_experiment, rounds=1)

    # Step 5 on what came back: FIGURE1.md from the unpacked runs, computed, never typed in.
    with tarfile.open(os.path.join(directory, "out", "campaign-hopper.tar.gz")) as tar:
        tar.extractall(tmp_path / "back", filter="data")
    assert _figure1(f"hopper={tmp_path / 'back' / 'hopper'}", "window=2", f"out={tmp_path / 'FIGURE1.md'}", "formats=png") == 0
    text = (tmp_path / "FIGURE1.md").read_text()
    assert "(3 runs, 80 env steps each, not the paper's 1M)" in text
    assert "AUC min_u a_u: adversarial − uniform = " in text and "(one seed in a mode: no test)" in text
    clean = json.loads(packed["./hopper/none-s0/scores.jsonl"].splitlines()[-1])["clean_score"]
    assert f"Clean SAC (mode `none`, 1 seed): final clean return {clean:.1f} against" in text
    assert "not comparable yet" in text
    assert (tmp_path / "back" / "hopper" / "figures" / "min_score.png").exists()
    # ...and, packed apart, each run's best policy: that of its records' best scoring.
    with tarfile.open(os.path.join(directory, "out", "campaign-hopper-policies.tar.gz")) as tar:
        assert sorted(tar.getnames()) == [f"./hopper/{pair}/best_policy.npz" for pair in ("adversarial-s0", "none-s0", "uniform-s0")]
        tar.extractall(tmp_path / "back", filter="data")
    for pair in ("adversarial-s0", "uniform-s0", "none-s0"):
        learning_starts = yaml.safe_load(packed[f"./hopper/{pair}/config.yaml"])["learning_starts"]
        rows = [json.loads(line) for line in packed[f"./hopper/{pair}/scores.jsonl"].splitlines()]
        best = max((row for row in rows if row["env_steps"] > learning_starts), key=lambda row: row["min_score"])
        assert best_kept(str(tmp_path / "back" / "hopper" / pair)) == (best["env_steps"], best["min_score"])
    # The chain's Python processes (a call's worker, its plan, the runs: five at least) ran
    # without those modules: each logs its blocker's start.
    with open(directory + "-without-modules.log") as file:
        assert sum(line.endswith(" loaded\n") for line in file) >= 5


def test_capacity_overflow_is_detected_and_stops_the_run_in_one_line(tmp_path, monkeypatch):
    """A batch larger than the env's max_batch overflows Warp's shared contact buffer and the
    env says so; a run whose env says so stops with an error naming the setting."""
    # Sized for 1 world, 8 Hoppers falling onto the floor overflow (from step 12 of these
    # starts). (Sized for the batch, nothing overflows: the Warp experiment's 24 worlds, sized
    # for them, finish.)
    env = make_env("hopper", physics="warp", max_batch=1)
    actions = np.zeros((8, env.action_size), np.float32)

    def step(states, _):
        states = jax.vmap(env.step)(states, actions)
        return states, env.capacity_exceeded(states)

    states = jax.vmap(env.reset)(jax.random.split(jax.random.key(0), 8))
    assert bool(jax.jit(lambda s: jax.lax.scan(step, s, None, length=20)[1].any())(states))

    # The loop's side, on the point mass (seconds): an env that reports an overflow
    # mid-run stops it with one line naming the setting and the kept checkpoint.
    from admissable_jax.envs import PointMass

    monkeypatch.setattr(PointMass, "capacity_exceeded", lambda self, state: jnp.any(state.step_count >= 40))
    monkeypatch.setattr(PointMass, "capacity_message", lambda self: "contacts (naconmax) sized for max_batch=1 worlds; raise max_batch")
    config = TrainConfig(env="point_mass", total_steps=3000, score_every=500, num_envs=4, learning_starts=1000,
                         episode_length=100, score_episodes=2, batch_size=32, buffer_size=5000, hidden_size=32,
                         checkpoint_every=1, progress=False, out=str(tmp_path / "overflow"))
    with pytest.raises(PhysicsCapacityExceeded, match="at env step 500: .*raise max_batch; no checkpoint yet") as error:
        train_fn(config)
    assert "\n" not in str(error.value)


def test_video_of_the_trained_hopper_beside_its_worst_set(jax_run, tmp_path, capsys, monkeypatch):
    """The video: nothing hidden beside the same start with the checkpoint's worst set hidden,
    in Gymnasium's C-MuJoCo env; on the command line, bad input is one line."""
    import imageio.v3 as iio

    from admissable_jax import video
    from admissable_jax.missingness import candidate_sets

    with warnings.catch_warnings(record=True) as warned:  # not JAX's fork warning: ffmpeg's start only execs
        warnings.simplefilter("always")
        made = video.render_video(video.VideoConfig(run_dir=jax_run.run_dir, frames=20, out=str(tmp_path / "hopper.mp4")))
    assert not [warning for warning in warned if "os.fork()" in str(warning.message)]
    worst = np.flatnonzero(candidate_sets(11)[jax_run.scores[-1]["argmin"]])
    assert made.hidden == tuple(worst) and made.step == 80
    # A pool's row indexes its own sets, not U: hidden=worst hides the set the row names, that
    # of the checkpoint's own scoring (step= an older checkpoint: not the last row's).
    pooled = [{"env_steps": 80, "argmin": 1, "argmin_set": "{3,7}", "sets": ["{0,1}", "{3,7}"]},
              {"env_steps": 120, "argmin": 0, "argmin_set": "{5}", "sets": ["{5}", "{3,7}"]}]
    names = observation_names("hopper")
    assert [video.resolve_hidden("worst", "hopper", names, pooled, step) for step in (80, 120)] == [(3, 7), (5,)]
    with pytest.raises(ValueError, match="^hidden=worst needs the scoring at env step 100, which scores.jsonl does not hold"):
        video.resolve_hidden("worst", "hopper", names, pooled, 100)  # a checkpoint between scorings (ζ changed on resume)
    # 20 frames: the start, one per step until this barely trained Hopper falls (both sides
    # within 19 steps), then the end held (for up to a second).
    assert made.frames == 20 and 0 < made.hidden_length <= 19 and 0 < made.clean_length <= 19
    with video.ffmpeg_forks_quietly():  # reading it back forks ffmpeg too
        frames = iio.imread(made.path)
    assert frames.shape == (made.frames, video.LABEL_HEIGHT + video.PANEL_HEIGHT, 2 * video.PANEL_WIDTH, 3)
    # The same start on both sides: the first frame's panels match, up to H.264's loss (the
    # rendered panels are equal; encoded, they differ by about 2 of 255 on average). The
    # hidden set changes the actions, so the two sides' returns differ.
    scene = frames[0, video.LABEL_HEIGHT:].astype(np.float32)
    assert np.abs(scene[:, :video.PANEL_WIDTH] - scene[:, video.PANEL_WIDTH:]).mean() < 5
    assert made.clean_return != made.hidden_return
    # The file records what it shows. Another video (here another start) is never written
    # over, nor a file that records none; the same video is (here shorter), whole or not at
    # all: a render stopped mid-way leaves the earlier file as it was, and no part of its own.
    run = os.path.abspath(jax_run.run_dir)
    recorded = video.recorded_video(made.path)
    assert {key: recorded[key] for key in ("run", "env_steps", "hidden", "fail_at", "reset_seed")} == {
        "run": run, "env_steps": 80, "hidden": list(worst), "fail_at": 0, "reset_seed": 0}
    before = open(made.path, "rb").read()
    assert video.main([jax_run.run_dir, "frames=3", "seed=1", f"out={made.path}"]) == 2
    assert capsys.readouterr().err.strip() == (
        f"error: {made.path} holds another video ({run}, env step 80, hidden {{{','.join(map(str, worst))}}}, "
        "fail_at 0, seed 0): it is left as it is; give another out=")
    odd = {"run": "/runs/l=0;#1\\", "hidden": [1]}  # what ffmetadata escapes, read back
    with video.ffmpeg_forks_quietly(), video.video_writer(str(tmp_path / "odd.mp4"), 30, odd) as writer:
        writer.append_data(np.zeros((16, 16, 3), np.uint8))
    assert video.recorded_video(str(tmp_path / "odd.mp4")) == odd
    os.remove(tmp_path / "odd.mp4")
    (tmp_path / "notes.mp4").write_text("not a video")
    with pytest.raises(FileExistsError, match="notes.mp4 exists and holds no record of a video of this command"):
        video._check_free_for(str(tmp_path / "notes.mp4"), recorded)
    labelled, frames_labelled = video._labelled, iter(range(1000))
    monkeypatch.setattr(video, "_labelled", lambda *args: labelled(*args) if next(frames_labelled) < 9 else 1 / 0)
    with pytest.raises(ZeroDivisionError):
        video.render_video(video.VideoConfig(run_dir=jax_run.run_dir, frames=20, out=made.path))
    monkeypatch.undo()
    assert open(made.path, "rb").read() == before and sorted(os.listdir(tmp_path)) == ["hopper.mp4", "notes.mp4"]
    shorter = video.render_video(video.VideoConfig(run_dir=jax_run.run_dir, frames=3, out=made.path))
    assert shorter.frames == 3 and open(made.path, "rb").read() != before
    # Another start's default file is its own: named for its seed.
    assert video._file_ending((3, 7), video.VideoConfig(fail_at=19, seed=1)) == "hidden3-7-fail19-seed1.mp4"
    # Each panel's title names u by its indices (it said {0} for u = {10}: a 0/1 row's reading of indices).
    assert video.panel_titles((3, 10), ("leg joint angle", "foot joint angular velocity"), 50) == [
        "nothing hidden", "hidden {3,10} from step 50: leg joint angle, foot joint angular velocity"]
    assert video.panel_titles((), (), 0)[1] == "hidden {}: nothing"
    # The same set's sensors failing at env step 19 (fail_at), after the 19 steps 20 frames show:
    # the hidden side sees everything, so it runs the clean episode; the file is named for both.
    late = video.render_video(video.VideoConfig(run_dir=jax_run.run_dir, frames=20, fail_at=19))
    assert late.path == os.path.join(jax_run.run_dir, "videos", f"step80-hidden{'-'.join(map(str, worst))}-fail19.mp4")
    shutil.rmtree(os.path.dirname(late.path))
    assert (late.hidden_return, late.hidden_length) == (late.clean_return, late.clean_length) == (
        made.clean_return, made.clean_length)
    # With nothing hidden on either side, the two sides run one episode: the same start state
    # (returns compared in full: the command's line rounds them to 0.1, which hides other starts).
    # Here of the policy the run kept at its best scoring (best=true).
    same = video.render_video(video.VideoConfig(run_dir=jax_run.run_dir, hidden="", frames=5, best=True,
                                                out=str(tmp_path / "both-clean.mp4")))
    assert same.hidden == () and (same.clean_return, same.clean_length) == (same.hidden_return, same.hidden_length)
    assert same.step == max((row for row in jax_run.scores if row["env_steps"] > HOPPER["learning_starts"]),
                            key=lambda row: row["min_score"])["env_steps"]
    # The same policy exported (python -m admissable_jax.export) and shown from its file alone,
    # hidden= named (it holds no scorings): the same episode, beside the file by default.
    from admissable_jax.export import ExportConfig, export_policies

    ((exported_path, _),) = export_policies(ExportConfig(run_dir=jax_run.run_dir, best=True, out=str(tmp_path / "best.npz")))
    alike = video.render_video(video.VideoConfig(policy=exported_path, hidden="", frames=5))
    assert alike.path == str(tmp_path / "videos" / "best-hiddennone.mp4") and alike.step == same.step
    assert (alike.clean_return, alike.clean_length) == pytest.approx((same.clean_return, same.clean_length), rel=1e-5)
    for args in (["hidden=worst"], ["hidden=1", "step=80"]):
        with pytest.raises(SystemExit):
            video.main([f"policy={exported_path}", *args])
        assert capsys.readouterr().err.startswith("error: an exported policy holds no scorings nor checkpoints: name ")

    for hidden in ("elbow", "11"):  # Hopper's features are 0 to 10
        assert video.main([jax_run.run_dir, f"hidden={hidden}", f"out={tmp_path}/bad.mp4"]) == 2
        assert f"'{hidden}' is neither a feature index below 11 nor a feature name of hopper" in capsys.readouterr().err
    for args, message in ((["frames=0"], "frames must be at least 1, got 0"), (["seed=-1"], "seed must be >= 0, got -1"),
                          (["best=true", "step=80"], "best=true shows the policy the run kept at its best scoring: give "
                                                     "no step= (got 80)"),
                          ([f"out={tmp_path}/hopper.gif"], f"out must be an .mp4 file, got '{tmp_path}/hopper.gif'")):
        with pytest.raises(SystemExit) as refused:
            video.main([jax_run.run_dir, *args])
        assert refused.value.code == 2 and capsys.readouterr().err.strip() == f"error: {message}"
    assert video.main([jax_run.run_dir, "out=/dev/null/x.mp4"]) == 2
    assert capsys.readouterr().err.strip() == "error: cannot create the video folder /dev/null: File exists"
    find_spec = video.importlib.util.find_spec  # without the video extra: one line, not a traceback
    monkeypatch.setattr(video.importlib.util, "find_spec",
                        lambda name: None if name == "imageio_ffmpeg" else find_spec(name))
    with pytest.raises(SystemExit) as refused:
        video.main([jax_run.run_dir])
    assert refused.value.code == 2 and capsys.readouterr().err.strip() == (
        "error: video needs the video extra (imageio_ffmpeg not installed): pip install -e '.[video]'")


def test_warp_experiment_pairs_keep_their_modes(warp_experiment):
    """Nested vmap over Warp data: each pair trains in its own mode, on physics whose
    buffers (contacts, constraint rows) are sized for every pair's worlds at once."""
    assert {result.trainer.env.physics.max_batch for result in warp_experiment} == {3 * HOPPER["score_envs"]}
    assert [(r.config.missingness, r.config.physics) for r in warp_experiment] == [
        ("adversarial", "warp"), ("uniform", "warp"), ("none", "warp")]
    assert not np.allclose(warp_experiment[0].scores[-1]["p_miss"], 1 / 11)
    for uniform in warp_experiment[1:]:
        np.testing.assert_allclose(uniform.scores[-1]["p_miss"], 1 / 11, rtol=1e-6)
    assert all(result.finished and int(result.state.grad_steps) == 32 for result in warp_experiment)
