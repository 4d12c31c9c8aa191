"""Run directories as a user meets them: one owner at a time, one-line errors, Ctrl-C,
checkpoint recovery, moved directories. All on the point mass (seconds to compile)."""

from __future__ import annotations

import collections
import contextlib
import dataclasses
import importlib
import io
import json
import os
import re
import shutil
import signal
import subprocess
import sys
import threading
import time
import types

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from admissable_jax import TrainConfig, host_loop, train_fn
from admissable_jax.best_policy import KeptPolicy, best_kept, write_best_policy
from admissable_jax.checkpointing import CheckpointError, _reason
from admissable_jax.cli import LogLines, PacedBar, parse_args, progress_bar, run_from_cli, ticking
from admissable_jax.config import config_file_of
from admissable_jax.errors import INTERRUPTED
from admissable_jax.host_loop import TrainingLoop, interval_pieces
from admissable_jax import locks
from admissable_jax.locks import LOCK_NAME, RunDirectoryLocked, RunLock
from admissable_jax.memory import MemoryBudgetExceeded
from admissable_jax.policies import load_policy
from admissable_jax.run_directory import RunDirectory, read_run_file

RUN = TrainConfig(
    env="point_mass", total_steps=2000, score_every=500, num_envs=4, learning_starts=500, episode_length=50,
    score_episodes=2, batch_size=32, buffer_size=4000, hidden_size=32, checkpoint_every=1, progress=False,
)


def _cli(module: str, *args: str, subprocess_run: bool = False) -> subprocess.CompletedProcess:
    """``python -m module args`` as a user runs it: in this process (its ``main``), or as a
    real command line when ``subprocess_run`` (slower: a fresh interpreter imports JAX)."""
    if subprocess_run:
        return subprocess.run([sys.executable, "-m", module, *args], capture_output=True, text=True,
                              env={**os.environ, "JAX_PLATFORMS": "cpu"})
    stderr = io.StringIO()
    with contextlib.redirect_stderr(stderr), contextlib.redirect_stdout(io.StringIO()):
        try:
            status = importlib.import_module(module).main(list(args))
        except SystemExit as exit_info:
            status = exit_info.code
    return subprocess.CompletedProcess(args, status, "", stderr.getvalue())


def _items(config: TrainConfig) -> list[str]:
    """``config`` as a command line's ``key=value`` items: those that differ from the defaults."""
    return [f"{field.name}={getattr(config, field.name)}" for field in dataclasses.fields(config)
            if getattr(config, field.name) != field.default]


def _best_of(rows: list[dict]) -> tuple[int, float]:
    """(env step, min_u a_u) of the first of ``RUN``'s ``rows`` with the highest min_u a_u after
    ``learning_starts`` (before it the actor is untrained)."""
    best = max((row for row in rows if row["env_steps"] > RUN.learning_starts), key=lambda row: row["min_score"])
    return best["env_steps"], best["min_score"]


def _steps(run_dir: str) -> list[int]:
    with open(os.path.join(run_dir, "scores.jsonl")) as file:
        return [json.loads(line)["env_steps"] for line in file]


def test_a_run_directory_has_one_owner_and_a_stale_lock_is_taken_over(tmp_path, capsys, monkeypatch):
    out = tmp_path / "locked"
    out.mkdir()
    owner = subprocess.Popen([sys.executable, "-c", "import time; time.sleep(120)"])
    try:
        (out / LOCK_NAME).write_text(json.dumps({"pid": owner.pid, "host": os.uname().nodename}))
        with pytest.raises(RunDirectoryLocked, match=f"in use by process {owner.pid}"):
            train_fn(dataclasses.replace(RUN, out=str(out)))
        assert sorted(os.listdir(out)) == [LOCK_NAME]  # nothing written beside the owner
    finally:
        owner.kill()
        owner.wait()
    # A lock from another host that its owner does not renew (as before 2026-12-06) is never
    # taken over (its owner cannot be asked from here), though this host has no such process.
    (out / LOCK_NAME).write_text(json.dumps({"pid": owner.pid, "host": "another-host"}))
    eleven_minutes_ago = time.time() - 660
    os.utime(out / LOCK_NAME, (eleven_minutes_ago, eleven_minutes_ago))  # however long ago
    refused = RunLock(str(out))
    with pytest.raises(RunDirectoryLocked, match=f"in use by process {owner.pid} on another-host"):
        refused.acquire()
    refused.release()  # a clean-up's release of a lock it never took leaves the owner's
    assert json.loads((out / LOCK_NAME).read_text())["host"] == "another-host"
    # A run renews its lock while it holds it, so another host's lock that has gone unrenewed
    # for 10 minutes is a dead owner's (a cluster job killed on one node, continued on another).
    (out / LOCK_NAME).write_text(json.dumps({"pid": owner.pid, "host": "another-host", "renewed_every": 30.0}))
    with pytest.raises(RunDirectoryLocked, match="in use by process"):
        RunLock(str(out)).acquire()
    os.utime(out / LOCK_NAME, (eleven_minutes_ago, eleven_minutes_ago))
    monkeypatch.setattr(locks, "RENEW_SECONDS", 0.02)
    renewing = RunLock(str(out))
    renewing.acquire()
    assert json.loads((out / LOCK_NAME).read_text())["pid"] == os.getpid()
    os.utime(out / LOCK_NAME, (eleven_minutes_ago, eleven_minutes_ago))
    time.sleep(0.3)
    assert time.time() - os.path.getmtime(out / LOCK_NAME) < 60  # renewed
    renewing.release()
    (out / LOCK_NAME).write_text(json.dumps({"pid": owner.pid, "host": "another-host"}))  # as before
    # A lock holding this very process's pid is stale too: no run of this process holds it
    # (in a container, a run killed in the one before often had the pid this one has now).
    (out / LOCK_NAME).write_text(json.dumps({"pid": os.getpid(), "host": os.uname().nodename}))
    taken = RunLock(str(out))
    taken.acquire()
    assert taken.held and json.loads((out / LOCK_NAME).read_text())["pid"] == os.getpid()
    taken.release()
    # So is a lock file a process killed while writing it left half written (not JSON).
    (out / LOCK_NAME).write_text('{"pid": 12')
    taken.acquire()
    assert taken.held and json.loads((out / LOCK_NAME).read_text())["pid"] == os.getpid()
    taken.release()
    (out / LOCK_NAME).write_text(json.dumps({"pid": owner.pid, "host": os.uname().nodename}))
    # The owner is gone: its lock is stale, and the next run takes it over and gives it back.
    # (On a disk with 1 kB free, where its checkpoints cannot fit: it says so, and still runs.)
    monkeypatch.setattr(shutil, "disk_usage", lambda path: collections.namedtuple("usage", "total used free")(2, 1, 1000))
    result = train_fn(dataclasses.replace(RUN, total_steps=500, out=str(out)))
    assert _steps(result.run_dir) == [500]
    assert LOCK_NAME not in os.listdir(out)
    # With progress=false too, the run says what it compiles and how long that took. Its
    # learning_starts (500) is all its env steps: it says that SAC never updates.
    said = capsys.readouterr().err
    assert ("warning: learning_starts=500 is not below the run's 500 env steps: SAC never updates, and every scoring "
            "scores the untrained policy (lower learning_starts or raise total_steps)\n") in said
    assert re.search(r"warning: keeping 1 checkpoint\(s\) of about 0\.\d\d GiB each needs 0\.\d\d GiB, and 0\.00 GiB are "
                     rf"free for {out / 'checkpoints'}: lower keep_checkpoints or free space", said), said
    assert "compiling the training step and the scoring round for point_mass (jax physics) on cpu..." in said
    assert re.search(r"compiling the training step and the scoring round for point_mass \(jax physics\) on cpu: "
                     r"done in \d+\.\d s", said)


def test_a_runs_commit_is_marked_where_its_source_differs(tmp_path):
    """invocations.jsonl's ``commit``: the checkout's, ``+changes`` where a tracked file
    differs from it (not an excluded path, as the benchmarks exclude their own results)."""
    import importlib.util

    from admissable_jax import provenance as installed

    package = tmp_path / "checkout" / "package"
    package.mkdir(parents=True)
    shutil.copy(installed.__file__, package / "provenance.py")
    (tmp_path / "checkout" / "results.txt").write_text("1")
    git = lambda *args: subprocess.run(["git", "-c", "user.name=t", "-c", "user.email=t@t", *args], check=True,
                                       cwd=tmp_path / "checkout", capture_output=True, text=True).stdout.strip()
    git("init", "-q")
    git("add", "-A")
    git("commit", "-qm", "start")
    spec = importlib.util.spec_from_file_location("provenance_copy", package / "provenance.py")
    provenance = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(provenance)
    commit = git("rev-parse", "--short", "HEAD")
    assert provenance.source_commit() == commit
    (tmp_path / "checkout" / "runs").mkdir()  # a file git does not track (a run's output) changes no source
    (tmp_path / "checkout" / "runs" / "scores.jsonl").write_text("{}\n")
    assert provenance.source_commit() == commit
    (tmp_path / "checkout" / "results.txt").write_text("2")
    assert provenance.source_commit() == f"{commit}+changes"
    assert provenance.source_commit(exclude=("results.txt",)) == commit


@pytest.mark.parametrize("out, message, subprocess_run", [("/proc/x", "cannot create the run directory /proc/x", True),
                                                          ("/dev/null/x", "cannot create the run directory /dev/null/x", False)])
def test_unwritable_out_is_one_line(out, message, subprocess_run):
    """The first case runs a real command line, ``python -m admissable_jax train ...`` (the
    package's dispatch to the train command): nothing else (an import warning, say) may add a line."""
    command = ("admissable_jax", "train") if subprocess_run else ("admissable_jax.train",)
    result = _cli(*command, "env=point_mass", f"out={out}", "progress=false", subprocess_run=subprocess_run)
    assert result.returncode == 2, result.stderr
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith(f"error: {message}: "), result.stderr


def test_cli_edge_cases_are_one_line(tmp_path):
    empty_modes = _cli("admissable_jax.experiment", "env=point_mass", "modes=", f"out={tmp_path}/e", "progress=false")
    assert empty_modes.returncode == 2
    assert empty_modes.stderr.strip() == ("error: modes must be a comma-separated list of adversarial, uniform, none, "
                                          "worst, got ''")
    # Values are read as YAML: one it cannot read is named (not YAML's traceback), with the
    # quoting that passes it as text; blanks after "=" are the empty string, as "key=" is.
    for module, item, message in [
        ("admissable_jax.experiment", "modes=,", "cannot read 'modes=,': did not find expected node content (to pass it "
                                                 "as text, quote it: modes=\"','\")"),
        ("admissable_jax.train", "hidden_size=[1", "cannot read 'hidden_size=[1': did not find expected ',' or ']' (to "
                                                   "pass it as text, quote it: hidden_size=\"'[1'\")"),
        ("admissable_jax.video", "out=@home", "cannot read 'out=@home': found character that cannot start any token "
                                              "(to pass it as text, quote it: out=\"'@home'\")"),
        ("admissable_jax.train", "env=toy_envs:", "cannot read 'env=toy_envs:': YAML reads 'toy_envs:' as a mapping (to "
                                                  "pass it as text, quote it: env=\"'toy_envs:'\")"),
        ("admissable_jax.train", "env= ", "unknown env ''; valid names: hopper, walker2d, ant, halfcheetah, point_mass, "
                                          "Hopper-v5, Walker2d-v5, Ant-v5, HalfCheetah-v5, or package.module:Class for an "
                                          "env of your own"),
        ("admissable_jax.train", "env='[1'", "unknown env '[1'; valid names: hopper, walker2d, ant, halfcheetah, "
                                             "point_mass, Hopper-v5, Walker2d-v5, Ant-v5, HalfCheetah-v5, or "
                                             "package.module:Class for an env of your own"),
    ]:
        refused = _cli(module, item, f"out={tmp_path}/never", "progress=false")
        assert (refused.returncode, refused.stderr) == (2, f"error: {message}\n"), item
    assert not (tmp_path / "never").exists()
    missing = tmp_path / "never-started"
    resumed = _cli("admissable_jax.train", "env=point_mass", "resume=true", f"out={missing}", "progress=false")
    assert resumed.returncode == 1 and "nothing to resume" in resumed.stderr
    assert len(resumed.stderr.strip().splitlines()) == 1
    assert not missing.exists()  # a failed resume leaves nothing behind
    # resume=auto is decided by the folder (here: no checkpoint), and, as for every key, the
    # last item given wins.
    for items, resume in ((["resume=auto", "resume=true"], True), (["resume=true", "resume=auto"], False)):
        config = parse_args(TrainConfig, ["env=point_mass", f"out={missing}", *items], "admissable_jax.train", "",
                            config_file=config_file_of(TrainConfig))
        assert config.resume is resume, items
    # With fast_forward=true and nothing to rebuild, a new run: no fast-forward either.
    config = parse_args(TrainConfig, ["env=point_mass", f"out={missing}", "resume=auto", "fast_forward=true"],
                        "admissable_jax.train", "", config_file=config_file_of(TrainConfig))
    assert (config.resume, config.fast_forward) == (False, False)


def test_a_wandb_logger_that_cannot_start_is_one_line(tmp_path, monkeypatch):
    """No W&B account (or no network) stops the run before it trains, in one line saying
    what to do; wandb.init is replaced here, so nothing goes online."""
    import wandb

    def no_account(**_):
        raise wandb.errors.UsageError("No API key configured. Use `wandb login` to log in.")

    monkeypatch.setattr(wandb, "init", no_account)
    result = _cli("admissable_jax.train", "env=point_mass", "logger=wandb", f"out={tmp_path / 'w'}", "progress=false")
    assert result.returncode == 2
    assert result.stderr == ("error: logger=wandb could not start a W&B run (No API key configured. Use `wandb login` "
                             "to log in.); log in (wandb login or WANDB_API_KEY), or log offline with WANDB_MODE=offline\n")
    assert not (tmp_path / "w").exists()  # the folder it made is gone again, lock and all


def test_a_resumed_run_logs_on_into_its_wandb_run(tmp_path, monkeypatch):
    """resume=true goes on in the W&B run the first start made: its id, kept in the run
    directory, asked for again with resume="allow"; another run directory gets a W&B run of
    its own. wandb.init is replaced here, so nothing goes online."""
    import wandb

    from admissable_jax.loggers import WandbLogger

    started = []

    class Run:
        define_metric = log = finish = lambda self, *args, **kwargs: None

    monkeypatch.setattr(wandb, "init", lambda **kwargs: started.append(kwargs) or Run())
    first, other = tmp_path / "run", tmp_path / "other"
    for run_dir in (first, first, other):
        run_dir.mkdir(exist_ok=True)
        WandbLogger(str(run_dir), {"env": "point_mass"}).close()
    kept = (first / "wandb_run_id").read_text().strip()
    assert [kwargs["id"] for kwargs in started[:2]] == [kept, kept] and started[2]["id"] != kept
    assert [(kwargs["resume"], kwargs["name"]) for kwargs in started] == [("allow", "run"), ("allow", "run"), ("allow", "other")]


def test_the_package_lists_its_commands(capsys):
    from admissable_jax.__main__ import COMMANDS, main

    assert main([]) == 0
    listed = capsys.readouterr().out.splitlines()[1:]
    assert [line.split()[2] for line in listed] == [f"admissable_jax.{command}" for command in COMMANDS]
    assert listed[3].endswith("Which sensors break a policy? A robustness audit over every set of k hidden features.")
    assert main(["env=ant"]) == 2  # a command given as a word runs: test_unwritable_out_is_one_line
    assert capsys.readouterr().err == ("error: 'env=ant' is no command: run one of train, experiment, plot, audit, "
                                       "video, export, rollout, status, e.g. python -m admissable_jax train env=ant (python -m "
                                       "admissable_jax lists them)\n")
    # Output piped into a reader that stops early (`status runs | head`, over the pipe's 64 KB)
    # ends a command quietly with the shell's SIGPIPE status, not with a traceback; every
    # command starts through run_main.
    code = "from admissable_jax.cli import run_main; run_main(lambda argv: print('a row\\n' * 100_000) or 0)"
    with subprocess.Popen([sys.executable, "-c", code], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True) as shown:
        assert shown.stdout.readline() == "a row\n"
        shown.stdout.close()
        assert shown.wait() == 141 and shown.stderr.read() == ""
    import admissable_jax

    for command in COMMANDS:
        module = os.path.join(os.path.dirname(admissable_jax.__file__), command)
        with open(f"{module}.py" if os.path.isfile(f"{module}.py") else os.path.join(module, "__main__.py")) as file:
            assert file.read().rstrip().endswith("run_main(main)"), command
    # --version: what a bug report needs, read from the installed metadata (no JAX imported).
    import importlib.metadata

    assert main(["--version"]) == 0
    ours, libraries = capsys.readouterr().out.splitlines()
    assert ours.startswith(f"admissable_jax {importlib.metadata.version('admissable_jax')}")
    for name in ("jax", "mujoco", "mujoco-mjx"):
        assert f"{name} {importlib.metadata.version(name)}, " in libraries


def test_rollout_times_a_batched_random_policy_in_one_line(capsys):
    """``python -m admissable_jax.rollout``: compile, then run, num_envs envs for ``steps``
    steps each under random actions, with automatic resets; one line says how fast. Here
    30 steps of 20-step episodes: every env was reset once, 10 steps ago."""
    from admissable_jax import make_env
    from admissable_jax.rollout import main, random_rollout

    assert main(["env=point_mass", "num_envs=4", "steps=10", "physics=jax"]) == 0
    line = capsys.readouterr().out.strip()
    assert re.fullmatch(r"point_mass on cpu \(jax physics\): 4 envs x 10 steps, compile \d+\.\d s, run \d+\.\d\d s, "
                        r"[\d,]+ env steps/s, mean reward -?\d+\.\d{3}", line), line
    _, total_reward = jax.jit(random_rollout, static_argnums=(0, 1, 2))(make_env("point_mass"), 4, 10, jax.random.key(0))
    assert line.endswith(f"mean reward {float(total_reward) / 40:.3f}")  # per env step: 4 envs x 10 steps
    states, _ = jax.jit(random_rollout, static_argnums=(0, 1, 2))(make_env("point_mass", episode_length=20), 3, 30,
                                                                    jax.random.key(0))
    np.testing.assert_array_equal(states.step_count, [10, 10, 10])
    for args, message in ((["steps=0"], "num_envs and steps must be >= 1"), (["seed=-2"], "seed must be >= 0, got -2")):
        with pytest.raises(SystemExit) as refused:
            main(args)
        assert refused.value.code == 2 and capsys.readouterr().err.strip() == f"error: {message}"


@pytest.mark.parametrize("setting, message", [
    ("learning_rate=nan", "learning_rate must be a finite number, got nan"),
    ("learning_rate=-1", "learning_rate must be > 0, got -1.0"),
    ("lower_bound=nan", "lower_bound must be a finite number, got nan"),
    ("epsilon=inf", "epsilon must be a finite number, got inf"),
    ("utd=nan", "utd must be a finite number, got nan"),
])
def test_settings_that_would_train_nonsense_are_refused_before_anything_is_written(setting, message, tmp_path):
    """A NaN l or ε would make every p_miss NaN, a NaN or negative learning rate would train
    NaN or ascending networks: each is refused in one line, and no run directory is made."""
    out = tmp_path / "never-started"
    small = ("total_steps=500", "score_every=500", "num_envs=4", "learning_starts=500", "batch_size=32",
             "episode_length=50", "score_episodes=2", "hidden_size=32")  # were it accepted: a short run
    result = _cli("admissable_jax.train", "env=point_mass", *small, setting, f"out={out}", "progress=false")
    assert result.returncode == 2, result.stderr
    assert result.stderr.strip() == f"error: {message}"
    assert not out.exists()


def test_the_bar_moves_within_an_interval_and_names_what_runs(tmp_path, monkeypatch, capsys):
    """On a CPU one scoring interval can take many minutes. Its training runs as up to 10
    calls, and the bar advances after each one. The bar names the phase (training, scoring,
    saving: every checkpoint_every scorings and at the end), and its clock keeps running
    through calls that advance nothing. The metrics still cover the whole interval. Where
    stderr is no terminal (a job's log file), the bar is a line per scoring, not a bar redrawn
    in place."""
    assert [interval_pieces(n) for n in (1, 7, 10, 40, 125, 625, 1249)] == [1, 7, 10, 10, 5, 5, 1]
    said = []

    class RecordingBar(LogLines):
        def update(self, n=1):
            said.append(n)
            return super().update(n)

        def set_description_str(self, desc=None, refresh=True):
            said.append(desc)
            return super().set_description_str(desc, refresh)

    assert progress_bar("env steps", disable=True).__class__ is LogLines  # pytest's stderr is no terminal
    with monkeypatch.context() as patched:
        patched.setattr(sys.stderr, "isatty", lambda: True)
        assert progress_bar("env steps", disable=True).__class__ is PacedBar
    # The time left at the pace its owner sets (the host loop: its last intervals that trained
    # SAC), '?' while it is 0 (the warm-up); unset, tqdm's mean since the start.
    log = io.StringIO()
    paced = LogLines("env steps", total=1500, unit="step", file=log)
    paced.update(500)
    paced.pace = 0.0
    paced.set_postfix(scored=1)
    paced.pace = 100.0
    paced.set_postfix(scored=2)
    paced.close()
    assert [line.split("elapsed, ")[1] for line in log.getvalue().splitlines()] == [
        "about ? left at ?step/s, scored=1", "about 00:10 left at 100.00step/s, scored=2"]
    # An audit's episodes in a log: a line at most once per `every` seconds as they finish, and at the end.
    log = io.StringIO()
    episodes = LogLines("episodes", every=3600, total=40, unit="episode", file=log, smoothing=0)
    episodes.update(10)  # within the hour: no line
    episodes.lined_at -= 3600  # an hour on
    episodes.update(10)
    episodes.update(10)
    episodes.close()
    assert [line.split(" (")[0] for line in log.getvalue().splitlines()] == ["20 of 40 episodes", "30 of 40 episodes"]
    # A long scoring round in a log: the clock's redraws write nothing until ten minutes pass
    # without a line, then one that names what runs, and again ten minutes on.
    log = io.StringIO()
    steps = LogLines("env steps", total=1000, unit="step", file=log, smoothing=0)
    steps.update(500)
    steps.set_description_str("scoring")
    steps.refresh()
    steps.lined_at -= LogLines.HEARTBEAT
    steps.refresh()
    steps.refresh()
    steps.close()
    assert [line.split(" (")[0] for line in log.getvalue().splitlines()] == ["still scoring: 500 of 1,000 env steps"]
    monkeypatch.setattr(host_loop, "progress_bar", RecordingBar)
    result = train_fn(dataclasses.replace(RUN, total_steps=1500, checkpoint_every=2, progress=True, out=str(tmp_path / "r")))
    # 500 env steps per interval over 4 envs: 125 iterations, as 5 calls of 100 env steps;
    # saved after the second scoring (checkpoint_every=2) and the third (the last).
    interval = ["training", *[100] * 5, "scoring"]
    assert said == [*interval, "", *interval, "saving", "", *interval, "saving", ""]
    logged = capsys.readouterr().err
    lines = [line for line in logged.splitlines() if " env steps (" in line]
    assert "\r" not in logged and len(lines) == 3, logged
    # The first interval, before learning_starts=500, says no time left: its pace is not SAC's.
    for line, steps, share, row, pace in zip(lines, ("500", "1,000", "1,500"), (33, 67, 100), result.scores,
                                             (r"\? left at \?", r"00:\d\d left at [\d.]+", r"00:00 left at [\d.]+")):
        assert re.fullmatch(rf"{steps} of 1,500 env steps \({share}%\), 00:\d\d elapsed, about {pace}step/s, "
                            rf"min_a_u={row['min_score']:.1f}, clean={row['clean_score']:.1f}, train_sps=\d+",
                            line), line
    assert sorted(os.listdir(os.path.join(result.run_dir, "checkpoints"))) == ["1000", "1500"]
    with open(os.path.join(result.run_dir, "metrics.jsonl")) as file:
        rows = [json.loads(line) for line in file]
    # The gradient steps the metrics saw in each interval: none before learning_starts=500,
    # then 4 in each of the 125 iterations of all 5 calls.
    assert [round(row["grad_steps_per_s"] / row["env_steps_per_s"] * 500) for row in rows] == [0, 500, 500]

    class Clock:
        def __init__(self, disable):
            self.disable, self.refreshed = disable, 0

        def refresh(self):
            self.refreshed += 1

    running, disabled = Clock(disable=False), Clock(disable=True)
    for clock in (running, disabled):
        with ticking(clock, seconds=0.01):
            time.sleep(0.2)
    ticks = running.refreshed
    time.sleep(0.05)
    assert ticks >= 3 and running.refreshed == ticks and disabled.refreshed == 0


@pytest.mark.parametrize("stop, on_chunk", [("ctrl-c", 2), ("sigterm", 2), ("sigterm twice", 2), ("ctrl-c", 1)])
def test_ctrl_c_says_where_to_resume_and_exits_130(stop, on_chunk, tmp_path, monkeypatch, capsys):
    """Ctrl-C, or SIGTERM (a job scheduler's stop), during the second chunk: the run ends
    with one line naming its last checkpoint, its lock given back. A signal (SIGTERM here,
    Ctrl-C's SIGINT alike) first lets the interval finish and keeps it as a checkpoint, though
    none was due (checkpoint_every=10); a second stops at once. During the first chunk, before
    any checkpoint, it says there is nothing to resume, and the folder it made is gone."""
    train_interval, calls = TrainingLoop.train_interval, []

    def interrupted_in_interval(self, state, bar):
        calls.append(1)
        if len(calls) == on_chunk and stop == "ctrl-c":
            raise KeyboardInterrupt
        if len(calls) == on_chunk:
            for _ in range(2 if stop == "sigterm twice" else 1):
                signal.raise_signal(signal.SIGTERM)  # the loop's handler, or the default: death
        return train_interval(self, state, bar)

    monkeypatch.setattr(TrainingLoop, "train_interval", interrupted_in_interval)
    out = str(tmp_path / "interrupted")
    checkpoint_every = 1 if stop == "ctrl-c" else 10
    result, status = run_from_cli(train_fn, dataclasses.replace(RUN, out=out, checkpoint_every=checkpoint_every))
    assert status == INTERRUPTED and result is None
    err = capsys.readouterr().err
    said = err.strip().splitlines()[-1]
    if stop == "sigterm":  # said at once, then the interval finished and kept
        assert "SIGTERM: stopping at the end of this scoring interval, with a checkpoint; press Ctrl-C again" in err
        assert _steps(out) == [500, 1000] and os.listdir(os.path.join(out, "checkpoints")) == ["1000"]
        assert LOCK_NAME not in os.listdir(out)
        assert said == f"interrupted: last checkpoint (step 1000) kept in {out}/checkpoints; continue with resume=true"
        return
    if stop == "sigterm twice":  # at once: nothing was due yet
        assert said == (f"interrupted: no checkpoint yet in {out}/checkpoints; nothing to resume from: "
                        f"run the same command again to start over")
        return
    if on_chunk == 1:
        assert said == (f"interrupted: no checkpoint yet in {out}/checkpoints; nothing to resume from: "
                        f"run the same command again to start over")
        assert not os.path.exists(out)
        return
    assert _steps(out) == [500]
    assert LOCK_NAME not in os.listdir(out)
    assert said == f"interrupted: last checkpoint (step 500) kept in {out}/checkpoints; continue with resume=true"
    assert signal.getsignal(signal.SIGTERM) is signal.SIG_DFL  # given back after the run


@pytest.mark.parametrize("stop", [signal.SIGINT, signal.SIGTERM], ids=["ctrl-c", "sigterm"])
def test_a_ctrl_c_while_compiling_is_answered_at_once(stop, tmp_path, monkeypatch, capsys):
    """A Ctrl-C during the compile (a minute for Hopper on a small CPU, as long on a GPU) ends
    the run at once: the loop compiles on worker threads and waits where a Ctrl-C is heard,
    and leaves the compiles to end in the background. SIGTERM (a job scheduler's stop) ends
    it the same way: the command line takes it as a Ctrl-C before training starts too."""
    compiling, released, compiled = threading.Semaphore(0), threading.Event(), []

    def slow_compile(lowered):
        compiling.release()
        released.wait(60)
        compiled.append(lowered)

    def ctrl_c_once_both_compile():
        for _ in range(2):
            compiling.acquire(timeout=60)
        time.sleep(0.1)  # the loop waiting for them
        signal.pthread_kill(threading.main_thread().ident, stop)

    def not_taken(signum, frame):  # where the command line left SIGTERM to its default (death), fail instead
        raise AssertionError("SIGTERM was not taken as a Ctrl-C")

    monkeypatch.setattr(jax.stages.Lowered, "compile", slow_compile)
    ctrl_c = threading.Thread(target=ctrl_c_once_both_compile)
    previous = signal.signal(signal.SIGINT, signal.default_int_handler)
    previous_term = signal.signal(signal.SIGTERM, not_taken)
    out = tmp_path / "compiling"
    try:
        ctrl_c.start()
        _, status = run_from_cli(train_fn, dataclasses.replace(RUN, out=str(out)))
        assert (status, compiled) == (INTERRUPTED, [])  # answered while the compiles still ran
    finally:
        released.set()
        ctrl_c.join()
        signal.signal(signal.SIGINT, previous)
        signal.signal(signal.SIGTERM, previous_term)
    assert capsys.readouterr().err.strip().splitlines()[-1] == "interrupted before training started; nothing to resume from"
    assert not out.exists()


# A command interrupted the way a second Ctrl-C leaves it: its line said (on stdout here,
# which a pipe buffers), and device work it queued still running (for hours: each iteration
# a 256 x 256 matmul, enough for XLA:CPU to run it asynchronously; a reference kept, as the
# loop keeps its state).
_INTERRUPTED_WITH_WORK_IN_FLIGHT = """
import runpy, sys, types
import jax, jax.numpy as jnp
from admissable_jax import cli
from admissable_jax.errors import INTERRUPTED

in_flight = []

def interrupted(function, config, interrupted="interrupted"):
    endless = jax.jit(lambda x: jax.lax.fori_loop(0, 2**31 - 1, lambda i, x: jnp.tanh(x @ x), x))
    in_flight.append(endless(jnp.ones((256, 256))))
    print("interrupted: " + sys.argv[1])
    return None, INTERRUPTED

cli.run_from_cli = interrupted
cli.parse_args = lambda *args, **kwargs: types.SimpleNamespace(run_dir="", policy=None, steps=0, fail_at="0")
runpy.run_module(sys.argv[1], run_name="__main__")
"""


def test_an_interrupted_command_ends_at_once_with_device_work_in_flight():
    """After a second Ctrl-C the command's files are written and closed, but device work it
    queued may run on for minutes, and Python's own exit would wait for it (freeing the
    arrays it writes blocks). Every command ends at once instead, status 130, its output
    flushed."""
    commands = ("admissable_jax.train", "admissable_jax.experiment", "admissable_jax.audit", "admissable_jax.video",
                "admissable_jax.rollout")
    buffered = {name: value for name, value in os.environ.items() if name != "PYTHONUNBUFFERED"}
    running = [subprocess.Popen([sys.executable, "-c", _INTERRUPTED_WITH_WORK_IN_FLIGHT, command],
                                stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                                env={**buffered, "JAX_PLATFORMS": "cpu"}) for command in commands]
    try:
        for command, process in zip(commands, running):
            out, err = process.communicate(timeout=120)  # waiting for the work would take hours
            assert (process.returncode, out) == (INTERRUPTED, f"interrupted: {command}\n"), err
    finally:
        for process in running:
            process.kill()


def test_resume_rules_corrupt_checkpoints_and_moved_directories(tmp_path, capsys):
    first = str(tmp_path / "first")
    straight = train_fn(dataclasses.replace(RUN, out=first))
    assert _steps(first) == [500, 1000, 1500, 2000]
    # The policy kept as the best: its best scoring's (here before its last: not simply the last).
    assert best_kept(first) == _best_of(straight.scores) and _best_of(straight.scores)[0] < 2000

    # A shorter total than the run reached is refused; config.yaml keeps the truth.
    with open(os.path.join(first, "config.yaml")) as file:
        saved = file.read()
    with pytest.raises(ValueError, match="cannot resume with total_steps=1000: .* already reached 2000 env steps"):
        train_fn(dataclasses.replace(RUN, out=first, resume=True, total_steps=1000))
    with open(os.path.join(first, "config.yaml")) as file:
        assert file.read() == saved

    # A run directory moved elsewhere resumes where it now is.
    moved = str(tmp_path / "moved")
    shutil.move(first, moved)
    grown = train_fn(dataclasses.replace(RUN, out=moved, resume=True, total_steps=2500))
    assert _steps(moved) == [500, 1000, 1500, 2000, 2500]
    assert grown.scores[:4] == straight.scores

    # A corrupt latest checkpoint is named, with the newest intact one; resume_step takes it,
    # and the run repeats what the corrupt checkpoint held.
    checkpoints = os.path.join(moved, "checkpoints")
    assert sorted(os.listdir(checkpoints)) == ["2000", "2500"]
    for root, _, files in os.walk(os.path.join(checkpoints, "2500")):
        for name in files:
            with open(os.path.join(root, name), "wb") as file:
                file.write(b"garbage")
    with pytest.raises(CheckpointError, match="checkpoint 2500 .* is corrupt .*; checkpoint 2000 is intact: resume with resume_step=2000") as error:
        train_fn(dataclasses.replace(RUN, out=moved, resume=True, total_steps=2500))
    assert "\n" not in str(error.value)
    # The best policy kept, made here to read highest of all at 2500, goes aside with the rows
    # of that branch; a policy is kept again only for a scoring that beats every one kept (the
    # best of those, if before 2000, had been replaced by the made one: none is kept then).
    best = _best_of(grown.scores)
    assert best_kept(moved) == best
    branch = load_policy(moved, "best")
    write_best_policy(moved, KeptPolicy(2500, 1e9, branch.actor_params, branch.critic_params))
    again = train_fn(dataclasses.replace(RUN, out=moved, resume=True, total_steps=2500, resume_step=2000))
    assert again.scores == grown.scores
    assert best_kept(moved) == (best if best[0] > 2000 else None)
    with np.load(os.path.join(moved, "best_policy-superseded-step2500.npz")) as aside:
        assert float(aside["min_score"]) == 1e9
    # A command that continues a run weighs each new scoring against all the run's records.
    run = RunDirectory(dataclasses.replace(RUN, out=moved, resume=True, total_steps=2500).resolved(),
                       os.path.join(moved, "checkpoints"))
    try:
        recorded_best = _best_of(again.scores)[1]
        assert not run.beats_best({"env_steps": RUN.learning_starts, "min_score": 1e9})  # an untrained actor's
        assert not run.beats_best({"env_steps": 3000, "min_score": recorded_best})
        assert run.beats_best({"env_steps": 3000, "min_score": recorded_best + 1})
    finally:
        run.close()
    assert os.listdir(checkpoints + "-superseded") == ["2500"]  # set aside, not deleted
    with open(os.path.join(moved, "scores-superseded.jsonl")) as file:  # and so is what it had scored
        assert [{key: value for key, value in json.loads(line).items() if key != "set_aside_at"}
                for line in file] == grown.scores[4:]


def test_a_corrupt_checkpoint_offers_the_newest_intact_one(tmp_path):
    """Of several older checkpoints, the one a corrupt checkpoint's message offers is the
    newest that reads: the least finished work lost."""
    from admissable_jax.checkpointing import Checkpoints

    checkpoints = Checkpoints(str(tmp_path / "checkpoints"), max_to_keep=3)
    for step in (500, 1000, 1500):
        checkpoints.save(step, {"weights": jnp.full(3, float(step))})
    for root, _, files in os.walk(tmp_path / "checkpoints" / "1500"):
        for name in files:
            with open(os.path.join(root, name), "wb") as file:
                file.write(b"garbage")
    like = {"weights": jnp.zeros(3)}
    with pytest.raises(CheckpointError, match="checkpoint 1500 .* is corrupt .*; checkpoint 1000 is intact: "
                                              "resume with resume_step=1000$"):
        checkpoints.read(like)
    assert checkpoints.read(like, 1000)[1]["weights"].tolist() == [1000.0] * 3
    checkpoints.close()


def test_a_full_disks_reason_is_found_however_the_error_chains_it():
    """The one line of a failed checkpoint save names the OSError's reason, whether the error
    orbax raises was raised from it (``__cause__``) or while handling it (``__context__``),
    else the error's own first line."""
    import errno

    def raised(context: bool) -> BaseException:
        try:
            try:
                raise OSError(errno.ENOSPC, "No space left on device")
            except OSError as disk:
                if context:
                    raise RuntimeError("write failed")
                raise RuntimeError("write failed") from disk
        except RuntimeError as error:
            return error
    assert _reason(raised(context=False)) == _reason(raised(context=True)) == "No space left on device"
    assert _reason(ValueError("shape mismatch\nmore")) == "shape mismatch"


def test_faults_of_long_runs_cost_nothing_finished(tmp_path, monkeypatch, capsys):
    """A torn last jsonl line, a config.yaml that is not YAML, a full disk during a
    checkpoint, a finished run resumed, and a time limit: one line each, nothing lost."""
    import errno

    import orbax.checkpoint as ocp

    from admissable_jax.plot import main as plot_main

    straight = train_fn(dataclasses.replace(RUN, out=str(tmp_path / "straight")))

    # A time limit pauses before a scoring interval that would pass it, with a checkpoint
    # though none is due; resume goes on to the same history as the uninterrupted run. On a
    # stand-in clock each interval takes 10 s: after the first, 10 s spent and 10 more would
    # pass 15 s.
    paused_dir, clock, train_interval = str(tmp_path / "paused"), [0.0], TrainingLoop.train_interval

    def ten_seconds_each(self, state, bar):
        clock[0] += 10.0
        return train_interval(self, state, bar)

    with monkeypatch.context() as patched:
        patched.setattr(TrainingLoop, "train_interval", ten_seconds_each)
        patched.setattr(host_loop, "time", types.SimpleNamespace(perf_counter=lambda: clock[0]))
        paused = train_fn(dataclasses.replace(RUN, out=paused_dir, time_limit=15, checkpoint_every=10))
    assert not paused.finished and _steps(paused_dir) == [500]
    assert "paused at 500 of 2000 env steps: another scoring interval would pass time_limit=15 s" in capsys.readouterr().err
    assert sorted(os.listdir(os.path.join(paused_dir, "checkpoints"))) == ["500"]
    check_where_runs_stand(tmp_path, straight, paused_dir, capsys)

    # A crash mid-append leaves a torn last line: resume drops it and says so; plot skips it
    # with a warning naming the file.
    for name in ("scores.jsonl", "metrics.jsonl"):
        with open(os.path.join(paused_dir, name), "a") as file:
            file.write('{"env_steps": 1000, "min_score": 12.')
    assert plot_main([paused_dir, f"out={tmp_path / 'figs'}", "formats=png"]) == 0
    with pytest.raises(SystemExit) as refused:
        plot_main([paused_dir, "out=/dev/null/x"])
    assert refused.value.code == 2
    said = capsys.readouterr().err
    assert f"warning: {os.path.join(paused_dir, 'scores.jsonl')}: the last line is cut off" in said
    assert said.strip().splitlines()[-1] == "error: cannot create the figures folder /dev/null/x: Not a directory"
    # A bad line before the last is no crash's trace but a corrupt file: refused in one line
    # naming the file and line, not read up to it.
    corrupt = tmp_path / "corrupt"
    shutil.copytree(paused_dir, corrupt, ignore=shutil.ignore_patterns("checkpoints"))
    first, torn = (corrupt / "scores.jsonl").read_text().splitlines()
    (corrupt / "scores.jsonl").write_text("\n".join([first, '{"env_steps": 1000, "min_score": }', torn]))
    with pytest.raises(SystemExit) as refused:
        plot_main([str(corrupt), f"out={tmp_path / 'corrupt_figs'}"])
    assert refused.value.code == 2 and capsys.readouterr().err.strip().splitlines()[-1] == (
        f"error: {corrupt / 'scores.jsonl'} line 2 is not valid JSON (Expecting value); the file is corrupt")
    # So is valid JSON that is no scoring row (an edit by hand, another tool's line): named,
    # not a KeyError's "'scores'" or NumPy's words.
    row = json.loads(first)
    for line, what in [(json.dumps({"env_steps": 1000}), "line 2 holds no 'scores'"),
                       ("[1, 2]", "line 2 is a JSON list, not an object"),
                       (json.dumps({**row, "scores": row["scores"][:-1]}), ": the rows' 'scores' are not numbers of one "
                                                                             "shape")]:
        (corrupt / "scores.jsonl").write_text("\n".join([first, line]) + "\n")
        with pytest.raises(SystemExit) as refused:
            plot_main([str(corrupt), f"out={tmp_path / 'corrupt_figs'}"])
        assert refused.value.code == 2 and capsys.readouterr().err.strip().splitlines()[-1] == (
            f"error: {corrupt / 'scores.jsonl'}{' ' * what.startswith('line')}{what}; the file is corrupt")
    # The records a resume sets aside, or a fast-forward reads: each row at its env step.
    (corrupt / "metrics.jsonl").write_text('{"grad_steps": 10}\n')
    with pytest.raises(ValueError, match=f"^{re.escape(str(corrupt / 'metrics.jsonl'))} line 1 holds no 'env_steps'; "
                                         f"the file is corrupt$"):
        read_run_file(str(corrupt), "metrics.jsonl")
    # And plot's "Trained on" line reads where each command trained.
    (corrupt / "scores.jsonl").write_text(first + "\n")
    invocations = (corrupt / "invocations.jsonl").read_text().splitlines()
    (corrupt / "invocations.jsonl").write_text("\n".join([*invocations, '{"command": ["python"]}']) + "\n")
    with pytest.raises(SystemExit) as refused:
        plot_main([str(corrupt), f"out={tmp_path / 'corrupt_figs'}"])
    assert refused.value.code == 2 and capsys.readouterr().err.strip().splitlines()[-1] == (
        f"error: {corrupt / 'invocations.jsonl'} line {len(invocations) + 1} holds no 'device'; the file is corrupt")
    # Ctrl-C while plot draws: one line saying where the figures drawn so far are; a folder
    # it made and drew nothing into is gone.
    import admissable_jax.plot

    def ctrl_c(*args):
        raise KeyboardInterrupt
    for where, said in (("write_tables", f"the figures drawn so far are in {tmp_path / 'stopped'}"),  # after the figures
                        ("draw_curves", "nothing written")):  # in the folder it made, before any figure
        shutil.rmtree(tmp_path / "stopped", ignore_errors=True)
        with monkeypatch.context() as patched:
            patched.setattr(admissable_jax.plot, where, ctrl_c)
            try:
                status = plot_main([paused_dir, f"out={tmp_path / 'stopped'}", "formats=png"])
            except KeyboardInterrupt:
                status = "a traceback"
        assert status == INTERRUPTED
        assert capsys.readouterr().err.strip().splitlines()[-1] == f"interrupted: {said}; the runs are untouched"
        assert (tmp_path / "stopped").exists() == (where == "write_tables")
    # A job that a scheduler starts again runs one unchanging command: resume=auto continues
    # where its folder holds a checkpoint (a run without one starts over: below).
    resumed = _cli("admissable_jax.train", *_items(RUN), f"out={paused_dir}", "resume=auto")
    assert resumed.returncode == 0, resumed.stderr
    assert f"resume=auto: {paused_dir} holds a checkpoint: resume=true\n" in resumed.stderr
    assert read_run_file(paused_dir, "scores.jsonl") == straight.scores
    assert f"dropped the cut-off last line of {os.path.join(paused_dir, 'scores.jsonl')}" in resumed.stderr

    # Each command that trained here says so in invocations.jsonl, from the step it started at;
    # one that found nothing left to train (below) adds nothing.
    invocations = [json.loads(line) for line in open(os.path.join(paused_dir, "invocations.jsonl"))]
    assert [record["from_env_steps"] for record in invocations] == [0, 500]

    # Resuming a finished run says so at once, compiles nothing, and returns its state.
    again = train_fn(dataclasses.replace(RUN, out=paused_dir, resume=True))
    said = capsys.readouterr().err
    assert "nothing left to train: the run reached 2000 of 2000 env steps" in said and "compiling" not in said
    for a, b in zip(jax.tree.leaves(again.state), jax.tree.leaves(straight.state)):
        np.testing.assert_array_equal(np.asarray(a), np.asarray(b))
    assert len(open(os.path.join(paused_dir, "invocations.jsonl")).readlines()) == 2

    # A run stopped before its first checkpoint leaves rows and no checkpoint: a new run in
    # its directory starts afresh and sets the earlier rows aside, stamped, never deleted,
    # before it writes its config.yaml: even if it then stops (here: refused for memory),
    # no earlier row stands beside the new settings.
    unsaved = tmp_path / "unsaved"
    shutil.copytree(straight.run_dir, unsaved)
    shutil.rmtree(unsaved / "checkpoints")

    def refused(loop):
        raise MemoryBudgetExceeded("does not fit: (the test's)")

    with monkeypatch.context() as patched:
        patched.setattr(TrainingLoop, "compile", refused)
        with pytest.raises(MemoryBudgetExceeded):
            train_fn(dataclasses.replace(RUN, out=str(unsaved), total_steps=500))
    assert (unsaved / "scores.jsonl").read_text() == "" and (unsaved / "metrics.jsonl").read_text() == ""
    fresh = _cli("admissable_jax.train", *_items(dataclasses.replace(RUN, total_steps=500)), f"out={unsaved}",
                 "resume=auto")
    assert fresh.returncode == 0 and f"resume=auto: {unsaved} holds no checkpoint: resume=false\n" in fresh.stderr
    assert _steps(str(unsaved)) == [500] and read_run_file(str(unsaved), "scores.jsonl") == straight.scores[:1]
    for name, earlier in (("scores", straight.scores), ("metrics", straight.metrics)):
        kept = [json.loads(line) for line in (unsaved / f"{name}-superseded.jsonl").read_text().splitlines()]
        assert [{key: value for key, value in row.items() if key != "set_aside_at"} for row in kept] == earlier
        assert all(row["set_aside_at"] for row in kept)
    assert (f"set aside 4 row(s) of scores.jsonl and 4 row(s) of metrics.jsonl from after env step 0 in {unsaved} "
            "(*-superseded.jsonl): this run writes those steps again") in capsys.readouterr().err

    # config.yaml that is not YAML: one line naming it, from train and from plot.
    broken = tmp_path / "broken"
    shutil.copytree(paused_dir, broken)
    (broken / "config.yaml").write_text("env: [point_mass\nseed: 0\n")
    for result in (_cli("admissable_jax.train", "env=point_mass", "resume=true", f"out={broken}", "progress=false"),
                   _cli("admissable_jax.plot", str(broken), subprocess_run=True)):
        lines = result.stderr.strip().splitlines()
        assert result.returncode == 2 and len(lines) == 1, result.stderr
        assert lines[0].startswith(f"error: {broken / 'config.yaml'} is not valid YAML"), lines[0]

    # A disk that fills during a checkpoint: one line naming the directory and the intact
    # checkpoint, orbax's temporary folder removed, and resume works once there is space.
    real_save = ocp.CheckpointManager.save

    def full_disk_at_1000(manager, step, *args, **kwargs):
        if step == 1000:
            partial = os.path.join(str(manager.directory), "1000.orbax-checkpoint-tmp-1")
            os.makedirs(partial)
            raise RuntimeError("write failed") from OSError(errno.ENOSPC, "No space left on device")
        return real_save(manager, step, *args, **kwargs)

    monkeypatch.setattr(ocp.CheckpointManager, "save", full_disk_at_1000)
    full_dir = str(tmp_path / "full")
    result, status = run_from_cli(train_fn, dataclasses.replace(RUN, out=full_dir))
    lines = capsys.readouterr().err.strip().splitlines()
    assert status == 1 and result is None
    checkpoints = os.path.join(full_dir, "checkpoints")
    assert lines[-1] == (f"error: cannot write checkpoint 1000 in {checkpoints}: No space left on device; the partial "
                         "write was removed and checkpoint 500 is intact; free space, then continue with resume=true")
    assert os.listdir(checkpoints) == ["500"]
    monkeypatch.setattr(ocp.CheckpointManager, "save", real_save)
    assert train_fn(dataclasses.replace(RUN, out=full_dir, resume=True)).scores == straight.scores


def check_where_runs_stand(tmp_path, straight, paused_dir: str, capsys) -> None:
    """``status``: each run's state read from its folder, and the command that continues a
    stopped one: from its checkpoint (an experiment's pair: the experiment's), from its
    records where the checkpoints are gone, or from its settings where it never scored."""
    from admissable_jax.status import main as status_main
    from admissable_jax.status import run_status

    stand = tmp_path / "stand"
    running, copied, unscored, broken = (stand / name for name in ("running", "copied", "unscored", "broken"))
    shutil.copytree(paused_dir, running)
    (running / LOCK_NAME).write_text(json.dumps({"pid": 1, "host": os.uname().nodename}))  # init: always alive
    with open(running / "scores.jsonl", "a") as file:  # a row the run is writing as status reads
        file.write('{"env_steps": 1000, "min_sc')
    with open(running / "metrics.jsonl", "a") as file:  # its pace: the last five intervals' that trained SAC
        file.write("".join(json.dumps({"env_steps": 1000, "env_steps_per_s": rate, "score_seconds": 0.0}) + "\n"
                           for rate in (1, 2, 3, 4, 5, 6)))
    shutil.copytree(paused_dir, copied, ignore=shutil.ignore_patterns("checkpoints"))
    gone = subprocess.Popen(["true"])
    gone.wait()  # as a killed run's process: the lock it held is left, naming a pid no longer running
    (copied / LOCK_NAME).write_text(json.dumps({"pid": gone.pid, "host": os.uname().nodename}))
    unscored.mkdir()
    shutil.copy(os.path.join(paused_dir, "config.yaml"), unscored)
    shutil.copytree(unscored, broken)
    (broken / "config.yaml").write_text("env: [point_mass\n")
    newer = stand / "newer"  # settings of a key this version does not know (a newer version's run)
    shutil.copytree(unscored, newer)
    with open(newer / "config.yaml", "a") as file:
        file.write("a_newer_key: 1\n")
    archived = stand / "archived"  # a finished run brought back without its checkpoints (as the GPU campaign's are)
    shutil.copytree(straight.run_dir, archived, ignore=shutil.ignore_patterns("checkpoints", "best_policy.npz"))
    with np.load(os.path.join(straight.run_dir, "best_policy.npz")) as kept:  # another scoring's policy
        np.savez(archived / "best_policy.npz", **{**kept, "env_steps": np.int64(1500)})
    pair = stand / "experiment" / "adversarial-s0"  # a pair: the experiment's checkpoints hold it
    shutil.copytree(paused_dir, pair, ignore=shutil.ignore_patterns("checkpoints"))
    shutil.copytree(os.path.join(paused_dir, "checkpoints"), stand / "experiment" / "checkpoints")
    (stand / "experiment" / "experiment.yaml").write_text("env: point_mass\n")
    # A pace from the intervals that trained SAC: none yet where a run stopped in its random-action warm-up.
    metrics = [row for row in read_run_file(straight.run_dir, "metrics.jsonl") if row["env_steps"] > RUN.learning_starts]
    pace = sum(500 / row["env_steps_per_s"] + row["score_seconds"] for row in metrics) / len(metrics)
    shutil.copy(os.path.join(straight.run_dir, "metrics.jsonl"), copied)  # the warm-up's interval and three that trained

    stopped = run_status(paused_dir)
    assert (stopped.state, stopped.scored_steps, stopped.checkpoint_steps, stopped.planned_steps) == ("stopped", 500, 500, 2000)
    assert stopped.seconds_left is None and stopped.min_score == straight.scores[0]["min_score"]
    assert stopped.best_score is None and not os.path.exists(os.path.join(paused_dir, "best_policy.npz"))  # untrained
    assert 0 <= stopped.seconds_since_scoring < 600
    finished = run_status(straight.run_dir)
    assert finished.state == "finished" and finished.seconds_left is None
    # Its best scoring, whose policy it keeps; one copied without that policy says so.
    assert (finished.best_steps, finished.best_score, finished.best_policy_kept) == (*_best_of(straight.scores), True)
    assert not run_status(str(archived)).best_policy_kept
    live = run_status(str(running))
    assert live.holder == f"process 1 on {os.uname().nodename}" and live.scored_steps == 500
    assert live.seconds_left == pytest.approx(3 * sum(500 / rate for rate in (2, 3, 4, 5, 6)) / 5)
    assert run_status(str(copied)).seconds_left == pytest.approx(4 * pace)  # from the start: no checkpoint
    assert status_main([straight.run_dir, paused_dir, str(stand)]) == 0
    table = capsys.readouterr().out
    rows = {line.split()[0]: line for line in table.split("\n\n")[0].splitlines()[1:]}
    assert re.search(rf"point_mass  adversarial  0     2,000 / 2,000  finished +\d+\.\d +\d+\.\d +"
                     rf"{finished.best_score:.1f} at {finished.best_steps:,} +\d+ s ago$", rows[straight.run_dir]), table
    assert "500 / 2,000    stopped (checkpoint 500)" in rows[paused_dir] and re.search(r" ago +—$", rows[paused_dir])
    assert f"running (process 1 on {os.uname().nodename})" in rows[str(running)]
    assert "0 / 2,000      stopped (no checkpoint)" in rows[str(unscored)] and rows[str(broken)].endswith("unreadable")
    assert "500 / 2,000    stopped (killed; no checkpoint)" in rows[str(copied)]
    assert "2,000 / 2,000  finished (no checkpoint)" in rows[str(archived)] and rows[str(archived)].endswith(" ago")
    assert f"{finished.best_score:.1f} at {finished.best_steps:,} *  " in rows[str(archived)]
    assert table.endswith(
        "\n9 run(s): 1 running, 2 finished, 4 stopped, 2 unreadable\n*: best_policy.npz does not hold that scoring's "
        "policy (a run of an older version, records copied without it, or a run resumed from a checkpoint before its "
        "best scoring)\nkilled: its process ended without giving back its "
        "lock, as no exit of Python does (SIGKILL, the out-of-memory killer, a machine that went down)\n"
        "to continue the stopped runs:\n"
        f"  python -m admissable_jax.train resume=true out={paused_dir}\n"
        f"  python -m admissable_jax.train resume=true fast_forward=true out={copied}\n"
        f"  python -m admissable_jax.experiment resume=true out={stand / 'experiment'}\n"
        f"  python -m admissable_jax.train config={unscored / 'config.yaml'} out={unscored}\n"
        f"{broken}: {broken / 'config.yaml'} is not valid YAML (line 2): did not find expected ',' or ']'\n"
        f"{newer}: Key 'a_newer_key' not in 'TrainConfig'\n"), table
    # For scripts: one JSON object per run, of the states asked for.
    assert status_main([str(stand), "state=stopped,unreadable", "format=jsonl"]) == 0
    listed = [json.loads(line) for line in capsys.readouterr().out.splitlines()]
    assert [(row["path"], row["state"]) for row in listed] == [
        (str(broken), "unreadable"), (str(copied), "stopped"), (str(pair), "stopped"), (str(newer), "unreadable"),
        (str(unscored), "stopped")]
    assert listed[2]["experiment"] == str(stand / "experiment") and listed[2]["checkpoint_steps"] == 500
    assert [row["killed"] for row in listed] == [False, True, False, False, False]  # a clean stop gives its lock back
    for argv, said in (([str(stand), "state=paused"], "state=paused: 'paused' is no state; the states are running, "
                                                        "finished, stopped, unreadable"),
                       ([os.path.join(paused_dir, "config.yaml")], f"{os.path.join(paused_dir, 'config.yaml')} is a file: "
                                                                   f"give a run's folder (or a folder of runs), such as "
                                                                   f"{paused_dir}"),
                       ([str(tmp_path / "nothing")], f"no such directory: {tmp_path / 'nothing'}")):
        with pytest.raises(SystemExit) as refused:
            status_main(argv)
        assert refused.value.code == 2 and capsys.readouterr().err == f"error: {said}\n"
