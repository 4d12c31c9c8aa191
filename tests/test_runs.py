"""Run directories as a user meets them: one owner at a time, one-line errors, Ctrl-C,
checkpoint recovery, moved directories. All on the point mass (seconds to compile)."""

from __future__ import annotations

import dataclasses
import json
import os
import re
import shutil
import subprocess
import sys

import pytest

from admissable_jax import TrainConfig, train_fn
from admissable_jax.checkpointing import CheckpointError
from admissable_jax.cli import run_from_cli
from admissable_jax.errors import INTERRUPTED
from admissable_jax.host_loop import TrainingLoop
from admissable_jax.locks import LOCK_NAME, RunDirectoryLocked

RUN = TrainConfig(
    env="point_mass", total_steps=2000, score_every=500, num_envs=4, learning_starts=500, episode_length=50,
    score_episodes=2, batch_size=32, buffer_size=4000, checkpoint_every=1, progress=False,
)


def _cli(module: str, *args: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", module, *args, "progress=false"], capture_output=True, text=True,
                          env={**os.environ, "JAX_PLATFORMS": "cpu"})


def _steps(run_dir: str) -> list[int]:
    with open(os.path.join(run_dir, "scores.jsonl")) as file:
        return [json.loads(line)["env_steps"] for line in file]


def test_a_run_directory_has_one_owner_and_a_stale_lock_is_taken_over(tmp_path, capsys):
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
    # The owner is gone: its lock is stale, and the next run takes it over and gives it back.
    result = train_fn(dataclasses.replace(RUN, total_steps=500, out=str(out)))
    assert _steps(result.run_dir) == [500]
    assert LOCK_NAME not in os.listdir(out)
    # With progress=false too, the run says what it compiles and how long that took.
    said = capsys.readouterr().err
    assert "compiling the training step for point_mass (jax physics) on cpu..." in said
    assert re.search(r"compiling the scoring round for point_mass \(jax physics\) on cpu: done in \d+\.\d s", said)


@pytest.mark.parametrize("out, message", [("/proc/x", "cannot create the run directory /proc/x"),
                                          ("/dev/null/x", "cannot create the run directory /dev/null/x")])
def test_unwritable_out_is_one_line(out, message):
    result = _cli("admissable_jax.train", "env=point_mass", f"out={out}")
    assert result.returncode == 2, result.stderr
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith(f"error: {message}: "), result.stderr


def test_cli_edge_cases_are_one_line(tmp_path):
    empty_modes = _cli("admissable_jax.experiment", "env=point_mass", "modes=", f"out={tmp_path}/e")
    assert empty_modes.returncode == 2
    assert empty_modes.stderr.strip() == "error: modes must be a comma-separated list of adversarial, uniform, none, got ''"
    missing = tmp_path / "never-started"
    resumed = _cli("admissable_jax.train", "env=point_mass", "resume=true", f"out={missing}")
    assert resumed.returncode == 1 and "nothing to resume" in resumed.stderr
    assert len(resumed.stderr.strip().splitlines()) == 1
    assert not missing.exists()  # a failed resume leaves nothing behind


def test_ctrl_c_says_where_to_resume_and_exits_130(tmp_path, monkeypatch):
    compile_loop = TrainingLoop.compile

    def compile_then_interrupt_second_chunk(self):
        budget = compile_loop(self)
        chunk, calls = self.run_chunk, []

        def interrupted_on_second_call(state):
            calls.append(1)
            if len(calls) == 2:
                raise KeyboardInterrupt
            return chunk(state)

        self.run_chunk = interrupted_on_second_call
        return budget

    monkeypatch.setattr(TrainingLoop, "compile", compile_then_interrupt_second_chunk)
    out = str(tmp_path / "interrupted")
    result, status = run_from_cli(train_fn, dataclasses.replace(RUN, out=out))
    assert status == INTERRUPTED and result is None
    assert _steps(out) == [500]
    assert LOCK_NAME not in os.listdir(out)


def test_resume_rules_corrupt_checkpoints_and_moved_directories(tmp_path, capsys):
    first = str(tmp_path / "first")
    straight = train_fn(dataclasses.replace(RUN, out=first))
    assert _steps(first) == [500, 1000, 1500, 2000]

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
    again = train_fn(dataclasses.replace(RUN, out=moved, resume=True, total_steps=2500, resume_step=2000))
    assert again.scores == grown.scores
    assert os.listdir(checkpoints + "-superseded") == ["2500"]  # set aside, not deleted
