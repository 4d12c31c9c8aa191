"""benchmarks/campaign.py's plans from the speed records on main (no training, no GPU), what
the speed step's training benchmark records (on the point mass: seconds), and bad input to
the benchmarks' command lines."""

import json
import os
import subprocess
import sys
import tarfile

import pytest

import campaign  # benchmarks/ is on the tests' path (conftest.py)
import common
import scoring_round
import train_throughput


BENCHMARKS = os.path.join(os.path.dirname(__file__), "..", "benchmarks")
CAMPAIGN_SCRIPT = os.path.join(BENCHMARKS, "gpu_campaign.sh")
H100 = "speed_device=gpu:NVIDIA H100 80GB HBM3"
HOPPER_ON_THE_GPU = ["env=hopper", "modes=adversarial,uniform,none", "physics=warp", "seeds=5", "num_envs=125",
                     "score_every=5000", "checkpoint_every=20", "min_steps=200000", "max_steps=1000000"]


def test_the_next_lease_is_planned_from_the_committed_h100_record(capsys, monkeypatch):
    """The hopper step's plan as the next lease will make it, in one process, from the H100
    speed record on main (read through speed_device here, as on an H200 that has none): 1M
    env steps fit neither with the 15 pairs nor with the 10, so the longest run of the 15:
    1,650 s hold 156 scorings once the first run's extra 58 s
    and 8 checkpoint saves (every 20 scorings, and at the end) are counted."""
    status = campaign.main(["plan", *HOPPER_ON_THE_GPU, "total_steps=1000000", "fallback_modes=adversarial,uniform",
                            "or_longest=true", "deadline=1650", H100])
    shown = capsys.readouterr().out
    assert status == 0, shown
    assert shown.count("does not fit, refused") == 2
    assert "hopper cannot reach 1000000 env steps in 1650 s: the longest run that fits instead" in shown
    assert ("compile 50 s + first run 58 s + 156 scorings x (chunk 2.2 s + full-length scoring 7.5 s) + 8 checkpoint "
            "saves x 2.3 s = 1,649 s") in shown
    assert shown.strip().splitlines()[-1] == "modes=adversarial,uniform,none total_steps=780000"

    # On a device with no record of its own (an H200 lease), the refusal names the device
    # that has one, so the next call plans from it.
    statuses = []
    monkeypatch.setattr(common, "exit_with", statuses.append)
    monkeypatch.setattr(sys, "argv", ["benchmarks/campaign.py", "plan", *HOPPER_ON_THE_GPU, "total_steps=1000000",
                                      "deadline=1650", "speed_device=gpu:NVIDIA H200"])
    common.run_benchmark(campaign.main)
    assert statuses == [2]
    refusal = capsys.readouterr().err.strip()
    assert "\n" not in refusal and refusal.endswith(
        "the same shape was measured on gpu:NVIDIA H100 80GB HBM3: plan from it with speed_device= "
        "(gpu_campaign.sh: CAMPAIGN_SPEED_DEVICE=)")

    # An hour holds more than max_steps: the longest run stops there.
    status = campaign.main(["plan", *HOPPER_ON_THE_GPU, "total_steps=0", "max_steps=200000", "deadline=3600", H100])
    assert status == 0 and capsys.readouterr().out.strip().splitlines()[-1] == "modes=adversarial,uniform,none total_steps=200000"


def test_the_speed_steps_projections_and_a_lease_too_short_for_one_interval(capsys):
    """The speed step ends with what one lease can run, from the same H100 record, each run
    planned as its step will plan it: Hopper and Walker2d at 1M env steps with their 15 pairs,
    then their 10 (neither fits 690 s), then the longest run of the 15; the longest Ant run of
    the 10 (refused below the campaign's min_steps). A lease too short for a single scoring interval plans
    no run at all, whatever min_steps allows, and says why."""
    assert campaign.main(["projections", *HOPPER_ON_THE_GPU[2:], "total_steps=1000000", "deadline=690",
                          "min_steps=50000", H100]) == 0
    shown = capsys.readouterr().out.strip().splitlines()
    assert [line.split(" (warp")[0] for line in shown if line.startswith("projected wall time for")] == [
        "projected wall time for Hopper-v5, 15 pairs x 125 envs", "projected wall time for Hopper-v5, 10 pairs x 125 "
        "envs, timed with 15 (an upper bound)", "projected wall time for Walker2d-v5, 15 pairs x 125 envs",
        "projected wall time for Walker2d-v5, 10 pairs x 125 envs, timed with 15 (an upper bound)"]
    assert sum(line.endswith("device time left 690 s: does not fit, refused") for line in shown) == 4
    assert [line for line in shown if line.startswith("modes=")] == [
        "modes=adversarial,uniform,none total_steps=290000", "modes=adversarial,uniform,none total_steps=250000",
        "modes=adversarial,uniform total_steps=105000"]
    assert shown[-2].startswith("longest run of Ant-v5, 10 pairs x 125 envs (warp on gpu:NVIDIA H100 80GB HBM3) in "
                                "690 s: 105,000 env steps: compile 43 s") and shown[-1] == "modes=adversarial,uniform total_steps=105000"
    assert campaign.main(["projections", *HOPPER_ON_THE_GPU[2:], "total_steps=1000000", "deadline=690", H100]) == 0
    assert capsys.readouterr().out.strip().splitlines()[-1].endswith(  # the campaign's min_steps: 200k for Ant
        "that fits in 690 s is 105,000 env steps (compile 43 s + first run 38 s + 21 scorings x (chunk 2.6 s + "
        "full-length scoring 24.9 s) + 2 checkpoint saves x 15.9 s = 690 s (11.5 min)), below min_steps=200,000: refused")
    status = campaign.main(["plan", *HOPPER_ON_THE_GPU, "total_steps=0", "deadline=100", "min_steps=5000", H100])
    refusal = capsys.readouterr().out.strip()
    assert status == campaign.REFUSED and refusal.startswith("no run of Hopper-v5, 15 pairs x 125 envs (warp on gpu:")
    assert refusal.endswith("fits in 100 s: 5,000 env steps, the shortest, take compile 50 s + first run 58 s + 1 scoring "
                            "x (chunk 2.2 s + full-length scoring 7.5 s) + 1 checkpoint save x 2.3 s = 120 s (2.0 min): refused")


def test_a_plan_times_its_pairs_with_the_fewest_pairs_timed_but_never_fewer(tmp_path, capsys, monkeypatch):
    """A plan reads the record of its own number of pairs, else of the fewest more (an upper
    bound: more pairs cost more), never of fewer, which would time the run too short."""
    with open(os.path.join(common.COMMITTED_RESULTS_DIR, "campaign_speed.jsonl")) as file:
        records = [json.loads(line) for line in file]
    hopper = next(record for record in records if record["env"] == "Hopper-v5")  # 15 pairs
    with open(tmp_path / "campaign_speed.jsonl", "w") as file:  # this campaign's own: 20 pairs, slower
        file.write(json.dumps({**hopper, "pairs": 20, "chunk_s": 3.0}) + "\n")
    monkeypatch.setattr(campaign, "RESULTS_DIR", str(tmp_path))
    paired = [arg for arg in HOPPER_ON_THE_GPU if not arg.startswith("modes=")] + ["modes=adversarial,uniform"]
    assert campaign.main(["plan", *paired, "total_steps=100000", "deadline=1650", H100]) == 0
    assert "Hopper-v5, 10 pairs x 125 envs, timed with 15 (an upper bound)" in capsys.readouterr().out
    # Ant was timed with its 10 (adversarial, uniform) pairs only: 15 have no record to plan from.
    ant = ["env=ant" if arg == "env=hopper" else arg for arg in HOPPER_ON_THE_GPU]
    with pytest.raises(ValueError, match=r"no speed record in .* 'pairs': 15\} \(or more pairs\): run the campaign's "
                                         r"speed step first$"):
        campaign.main(["plan", *ant, "total_steps=100000", "deadline=1650", H100])


def test_a_continuation_is_planned_past_the_records_it_rebuilds(tmp_path, capsys):
    """The next lease continuing the committed 340k Hopper runs (CAMPAIGN_RECORDS): their 68
    recorded intervals re-trained first, a chunk each without a scoring round, then the
    longest run past them that fits; records of other pairs, or already at max_steps, refused."""
    with tarfile.open(os.path.join(common.COMMITTED_RESULTS_DIR, "fig1-hopper-340k-h200", "runs.tar.xz")) as tar:
        tar.extractall(tmp_path, filter="data")
    records = f"records={tmp_path / 'hopper'}"
    status = campaign.main(["plan", *HOPPER_ON_THE_GPU, "total_steps=1000000", "or_longest=true", "deadline=790",
                            records, H100])
    shown = capsys.readouterr().out
    assert status == 0, shown
    # 50 + 58 + 68 x 2.235 + 52 x (2.235 + 7.529) + 6 x 2.33 = 781 s of 790.
    assert ("compile 50 s + first run 58 s + 68 recorded intervals re-trained x chunk 2.2 s + 52 scorings x "
            "(chunk 2.2 s + full-length scoring 7.5 s) + 6 checkpoint saves x 2.3 s = 781 s") in shown
    assert shown.strip().splitlines()[-1] == "modes=adversarial,uniform,none total_steps=600000"

    status = campaign.main(["plan", *HOPPER_ON_THE_GPU, "total_steps=0", "max_steps=340000", "deadline=790",
                            records, H100])
    assert status == campaign.REFUSED
    assert f"the records in {tmp_path / 'hopper'} already reach 340,000 env steps: nothing to add at " \
           "max_steps=340,000, refused" in capsys.readouterr().out
    with pytest.raises(ValueError, match="cannot resume with other pairs: .* has adversarial-s0, .*, none-s4, this one "
                                         "adversarial-s0, .*, uniform-s4 "):
        campaign.main(["plan", *HOPPER_ON_THE_GPU, "modes=adversarial,uniform", "total_steps=0", "deadline=790",
                       records, H100])
    # Fallback modes would be other pairs than the records hold: refused at the plan, not on the GPU.
    with pytest.raises(ValueError, match="^records= continues the pairs its runs hold: fallback_modes cannot change them$"):
        campaign.main(["plan", *HOPPER_ON_THE_GPU, "fallback_modes=adversarial,uniform", "total_steps=1000000",
                       "deadline=790", records, H100])
    # One pair whose rows carry no state fingerprint (a run from before they were written):
    # the experiment cannot be continued from its records, and the plan says so.
    open(tmp_path / "hopper" / "none-s4" / "metrics.jsonl", "w").close()
    with pytest.raises(ValueError, match=f"^nothing to continue in {tmp_path / 'hopper'}: a run there records no "
                                         "scoring with a state fingerprint$"):
        campaign.main(["plan", *HOPPER_ON_THE_GPU, "total_steps=0", "deadline=790", records, H100])


def test_training_throughput_counts_every_seeds_env_steps(tmp_path, monkeypatch, capsys):
    """The speed step's goal "15 pairs train at >= 10x the env steps/s of 1" reads
    train_throughput's records: env steps and gradient steps per second over all the
    vmapped seeds (here 2 seeds x 4 envs x 5 iterations, every iteration learning, UTD 1),
    the env named even where it has no Gymnasium id."""
    monkeypatch.setattr(common, "RESULTS_DIR", str(tmp_path))
    train_throughput.main(["env=point_mass", "seeds=2", "num_envs=4", "iterations=5", "batch_size=32", "buffer_size=1000"])
    (record,) = [json.loads(line) for line in open(tmp_path / "train_throughput.jsonl")]
    assert (record["env"], record["seeds"], record["num_envs"], record["iterations"]) == ("point_mass", 2, 4, 5)
    run_s = record["run_s"]  # rounded to 0.01 s, and the rate to 0.1
    assert 2 * 4 * 5 / (run_s + 0.005) - 0.05 <= record["env_steps_per_s"] <= 2 * 4 * 5 / (run_s - 0.005) + 0.05
    assert record["grad_steps_per_s"] == record["env_steps_per_s"]
    assert capsys.readouterr().out.startswith("point_mass (jax physics): 2 seed(s) x 4 envs")


def test_a_scoring_round_records_what_it_stepped(tmp_path, monkeypatch, capsys):
    """The speed step's goal "an Ant scoring round of 1,000-step episodes <= 12 s" reads
    scoring_round's records of ``terminate=false`` (every episode runs ``max_steps``): here
    the point mass, whose untrained actor drifts out of bounds within 300 steps unless told
    not to stop there, on a pool of 4 slots (5 sets x 2 episodes refill them); env steps
    stepped are every slot's, the pure-physics ceiling (zero actions) scaled to them."""
    monkeypatch.setattr(common, "RESULTS_DIR", str(tmp_path))
    for terminate in ("true", "false"):
        scoring_round.main(["env=point_mass", "slots=4", "n_episodes=2", "max_steps=300", f"terminate={terminate}"])
    ended, full = [json.loads(line) for line in open(tmp_path / "scoring_round.jsonl")]
    assert capsys.readouterr().out.startswith("point_mass (jax physics), untrained actor: 4+1 sets x 2 episodes")
    assert (full["env"], full["batch_episodes"], full["slots"]) == ("point_mass", 10, 4)
    assert full["env_steps_in_episodes"] == 10 * 300 and full["loop_steps"] == 3 * 300  # 4 + 4 + 2 episodes
    assert ended["env_steps_in_episodes"] < 10 * 300 and ended["loop_steps"] < 3 * 300
    for record in (ended, full):
        assert record["env_steps_stepped"] == 4 * record["loop_steps"] >= record["env_steps_in_episodes"]
        assert record["physics_env_steps_stepped"] == 4 * 3 * 300  # zero actions: the point mass stays put
        ceiling = record["physics_run_s"] / record["physics_env_steps_stepped"] * record["env_steps_stepped"]
        assert record["ceiling_s"] == pytest.approx(ceiling, abs=1e-3)


def test_a_benchmark_refuses_bad_input_in_one_line(monkeypatch, capsys):
    """Bad input ends a benchmark with one line and exit status 2, not a traceback or a run:
    a key's bad value when the keys are parsed (the benchmark's own check), and one that only
    the package finds later (``common.run_benchmark``)."""
    monkeypatch.setattr(sys, "argv", ["benchmarks/scoring_round.py", "n_episodes=0"])
    with pytest.raises(SystemExit) as parsed:
        common.run_benchmark(scoring_round.main)
    assert parsed.value.code == 2 and capsys.readouterr().err.endswith("error: n_episodes must be >= 1, got 0\n")
    statuses = []
    monkeypatch.setattr(common, "exit_with", statuses.append)
    monkeypatch.setattr(sys, "argv", ["benchmarks/scoring_round.py", "env=nope"])
    common.run_benchmark(scoring_round.main)
    error = capsys.readouterr().err
    assert statuses == [2] and error.startswith("error: unknown env 'nope'") and error.count("\n") == 1
    monkeypatch.setattr(sys, "argv", ["benchmarks/campaign.py", "profile", "top=0"])
    common.run_benchmark(campaign.main)  # refused before anything compiles
    assert statuses == [2, 2] and capsys.readouterr().err == "error: top must be >= 1, got 0\n"
    monkeypatch.setattr(sys, "argv", ["benchmarks/campaign.py", "plan", "--help"])  # a script, not a module
    with pytest.raises(SystemExit) as helped:
        common.run_benchmark(campaign.main)
    assert helped.value.code == 0 and capsys.readouterr().out.startswith("usage: python benchmarks/campaign.py plan [key")


def test_the_speed_steps_benchmarks_let_mjx_run_the_mujoco_warp_package():
    """The deterministic mode (the campaign's default) needs MJX's Warp bridge to run the
    mujoco-warp package, put in its place before anything imports MJX. The smoke chain runs
    the campaign's other scripts in that mode; these three, which it leaves out, are each
    imported first in a fresh interpreter, as the campaign starts them. Until 2026-12-05
    ``brax_sac.py`` imported Brax (and so MJX) first, so its stage was refused in one
    line: smoke mode stopped the speed step there, and on a GPU (where the step goes on past
    a failed stage) the speed table would have had no Brax row."""
    code = ("import importlib, sys; importlib.import_module(sys.argv[1]); "
            "from admissable_jax.envs import physics, warp_package; print(warp_package.runs_package())")
    env = {**os.environ, "JAX_PLATFORMS": "cpu",
           "PYTHONPATH": os.pathsep.join(filter(None, (BENCHMARKS, os.environ.get("PYTHONPATH"))))}
    calls = {script: subprocess.Popen([sys.executable, "-c", code, script], env=env, stdout=subprocess.PIPE,
                                      stderr=subprocess.PIPE, text=True)
             for script in ("brax_sac", "scoring_round", "train_throughput")}
    runs = {script: call.communicate(timeout=120) for script, call in calls.items()}
    assert {script: out.strip() for script, (out, _) in runs.items()} == dict.fromkeys(calls, "True"), runs


def test_brax_sac_trains_at_matched_settings_and_times_its_update_against_ours(tmp_path):
    """The speed step's Brax rows (goal: >= 1.5x Brax SAC's env steps/s at matched settings),
    each run as the campaign starts it, on the point mass at a tiny size: Brax's own SAC on our
    env, its env steps/s from its second epoch (the first includes compilation), with
    ``num_envs x utd`` gradient steps per iteration; and the SAC updates alone, where ours on
    Brax's d raw features costs Brax's FLOPs (the networks matched) and the 2·d masked input a
    little more."""
    env = {**os.environ, "JAX_PLATFORMS": "cpu", "BENCHMARK_RESULTS_DIR": str(tmp_path)}
    script, sizes = os.path.join(BENCHMARKS, "brax_sac.py"), ["env=point_mass", "batch_size=32"]
    calls = [subprocess.Popen([sys.executable, script, *sizes, *extra], env=env, stdout=subprocess.PIPE,
                              stderr=subprocess.PIPE, text=True)
             for extra in (["num_envs=4", "utd=0.5", "steps_per_epoch=4", "num_eval_envs=2", "episode_length=10"],
                           ["update_only=true", "updates=5", "rounds=2"])]
    runs = [(call.communicate(timeout=240), call.returncode) for call in calls]
    assert [code for _, code in runs] == [0, 0], runs
    with open(tmp_path / "brax_sac.jsonl") as file:
        records = {record.get("mode", "train"): record for record in map(json.loads, file)}
    train, update = records["train"], records["update_only"]
    assert (train["trainer"], train["physics"], train["grad_updates_per_iteration"]) == ("brax.training.agents.sac", "jax", 2)
    assert 0 < train["first_epoch_sps_with_compile"] < train["env_steps_per_s"], train
    assert train["grad_steps_per_s"] == pytest.approx(train["env_steps_per_s"] * 2 / 4, abs=0.1), train
    assert f"{train['env_steps_per_s']:,.1f} env steps/s (second epoch" in runs[0][0][0]
    assert update["inputs"] == {"brax": 4, "ours": 8, "ours_raw_input": 4}, update
    assert update["ours_raw_input"]["update_gflop"] == pytest.approx(update["brax"]["update_gflop"], rel=0.02), update
    assert update["ours"]["update_gflop"] > update["ours_raw_input"]["update_gflop"], update
    assert update["ours_over_brax"] == pytest.approx(
        update["ours"]["updates_per_s"] / update["brax"]["updates_per_s"], rel=0.01), update
    assert "best of 2 rounds of 5 updates each" in runs[1][0][0]


def test_a_pid_file_naming_another_process_is_no_running_worker(tmp_path):
    """A call follows a worker only while its pid file names a live worker of this script: a
    pid that ended and went to another process since (here this test's own) is not one. By
    its pid alone, the call took it for the speed step's worker and refused to go on."""
    state = tmp_path / "campaign" / "state"
    state.mkdir(parents=True)
    (state / "speed.pid").write_text(f"{os.getpid()}\n")
    (state / "hopper.complete").touch()
    env = {**os.environ, "CAMPAIGN_SMOKE": "1", "CAMPAIGN_DIR": str(tmp_path / "campaign")}
    env.pop("OUT", None)
    result = subprocess.run(["bash", CAMPAIGN_SCRIPT, "hopper"], env=env, capture_output=True, text=True, timeout=60)
    assert result.returncode == 0 and result.stdout.startswith("step hopper complete\n"), (result.stdout, result.stderr)


def test_the_campaign_script_refuses_a_bad_setting_before_it_starts(tmp_path):
    """A CAMPAIGN_* setting the script cannot read is one line and exit 2 before anything
    starts: read as it was, ``CAMPAIGN_DETERMINISTIC=false`` passed for the deterministic
    mode, and a deadline of ``-5`` reached the plan."""
    for setting, expected in [("CAMPAIGN_DETERMINISTIC=false", "give 1 or 0"),
                              ("CAMPAIGN_DEADLINE=-5", "give a number of seconds >= 0"),
                              ("CAMPAIGN_MIN_STEPS=5e4", "give a whole number >= 0")]:
        name, value = setting.split("=")
        env = {**os.environ, "CAMPAIGN_SMOKE": "1", "CAMPAIGN_DIR": str(tmp_path / "campaign"), name: value}
        result = subprocess.run(["bash", CAMPAIGN_SCRIPT, "hopper"], env=env, capture_output=True, text=True, timeout=60)
        assert result.returncode == 2 and result.stdout == "", (setting, result.stdout, result.stderr)
        assert result.stderr == f"{setting}: {expected} (see the header)\n"
    assert not (tmp_path / "campaign").exists()
