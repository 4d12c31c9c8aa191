"""The pair axis over several devices and processes (``admissable_jax.placement``), on the CPU.

JAX fixes its CPU device count when it starts, so the multi-device runs are processes of
their own with ``XLA_FLAGS=--xla_force_host_platform_device_count=N``: the 4-device
scenarios of tests/sharded_experiment.py in one, and a 2-process ``jax.distributed`` run
on localhost (2 devices each) in two more, started together.
"""

from __future__ import annotations

import json
import os
import signal
import socket
import subprocess
import sys

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from admissable_jax.branching import while_any
from admissable_jax.placement import PairPlacement, initialize_distributed

REPO = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
sys.path.insert(0, os.path.join(REPO, "tests"))
from sharded_experiment import EXPERIMENT  # noqa: E402

PAIRS = ["adversarial-s0", "adversarial-s1", "uniform-s0", "uniform-s1"]


def _environment(devices: int, **extra: str) -> dict[str, str]:
    """A subprocess's environment with ``devices`` CPU devices. XLA:CPU aborts a process whose
    devices' threads do not all reach a collective within 40 s. The one collective program left
    (refilling the padding after a restore onto 3 devices) runs while three such processes share
    2 cores with the other pytest worker, so the limit is raised to 3 minutes; nothing checked
    depends on it."""
    environment = {**os.environ, "JAX_PLATFORMS": "cpu", **extra}
    environment["XLA_FLAGS"] = (f"{environment.get('XLA_FLAGS', '')} --xla_force_host_platform_device_count={devices} "
                                "--xla_cpu_collective_call_terminate_timeout_seconds=180")
    return environment


def _rows(root: str, pair: str) -> list[dict]:
    with open(os.path.join(root, pair, "scores.jsonl")) as file:
        return [json.loads(line) for line in file]


def _free_port() -> int:
    with socket.socket() as probe:
        probe.bind(("localhost", 0))
        return probe.getsockname()[1]


def test_pairs_over_devices_and_processes(tmp_path):
    port = _free_port()
    settings = [f"{key}={value}" for key, value in EXPERIMENT.items()] + ["total_steps=2000"]
    distributed = [
        subprocess.Popen(
            [sys.executable, "-m", "admissable_jax.experiment", *settings, f"out={tmp_path / 'two_processes'}"],
            env=_environment(2, JAX_COORDINATOR_ADDRESS=f"localhost:{port}", JAX_NUM_PROCESSES="2",
                             JAX_PROCESS_ID=str(process)),
            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, cwd=REPO,
        )
        for process in range(2)
    ]
    try:
        scenarios = subprocess.run([sys.executable, os.path.join(REPO, "tests", "sharded_experiment.py"),
                                    str(tmp_path)], env=_environment(4), capture_output=True, text=True, cwd=REPO,
                                   timeout=600)
        outputs = [process.communicate(timeout=600) for process in distributed]
    finally:  # a hung run must not outlive the test
        for process in distributed:
            process.kill()
    assert scenarios.returncode == 0, scenarios.stderr[-3000:]
    for process, (stdout, stderr) in zip(distributed, outputs):
        assert process.returncode == 0, stderr[-3000:]
    report = json.loads((tmp_path / "report.json").read_text())
    four, one = tmp_path / "four", tmp_path / "one"

    # 4 devices (1 pair each) against 1 device (4 pairs): the same pairs, in the same
    # directories; the first scoring agrees to float round-off (a batch of 1 and one of 4
    # compile to different code) amplified by its 500 SAC updates (measured: 1.4e-4 relative
    # at most), later ones drift further apart.
    for pair in PAIRS:
        rows_four, rows_one = _rows(four, pair)[:2], _rows(one, pair)
        assert [row["env_steps"] for row in rows_four] == [row["env_steps"] for row in rows_one] == [1000, 2000]
        np.testing.assert_allclose(rows_four[0]["scores"], rows_one[0]["scores"], rtol=1e-3)
        np.testing.assert_allclose(rows_four[0]["p_miss"], rows_one[0]["p_miss"], rtol=1e-3)
    assert _rows(four, "adversarial-s0")[0]["scores"] != _rows(four, "adversarial-s1")[0]["scores"]
    # Each pair's returned state is read from its own device's shard, with no program in which
    # the devices talk (a gather over the global array all-reduces, and XLA:CPU deadlocked on those).
    assert report["result_devices"] == [[0], [1], [2], [3]]

    # Saved on 4 devices, restored onto 3 (padded to 6): every leaf of every pair bitwise.
    assert report["restored_pairs"] == PAIRS
    assert report["restored_vs_saved"] == 0.0
    assert "4 pair(s) on 3 cpu device(s), 2 per device" in report["stderr"]
    assert "2 copy(ies) of the last pair pad the batch" in report["stderr"]
    assert report["resumed_steps"] == [[1000, 2000, 3000]] * 4 and report["resumed_finite"]
    assert report["refilled"] == [0.0, 1.0, 2.0, 2.0]
    assert report["placed"] == [5.0, 6.0, 7.0, 7.0]  # a fresh batch is padded with the last pair too
    # The empty leaf went around the shard_map (in and out), and came back in its place.
    assert report["shard_map_operand_sizes"] == [4, 4]
    assert report["spread_out"] == {"pool": [[4, 0], []], "doubled": [[4], [0.0, 2.0, 4.0, 6.0]]}
    assert report["resumed_pairs"] == PAIRS and report["policy_vs_resumed"] == 0.0

    # Two processes of 2 devices each, 1 pair per device as on 4 devices in one process:
    # the same histories, bitwise; each process reports only the pairs it holds.
    for pair in PAIRS:
        assert _rows(tmp_path / "two_processes", pair) == _rows(four, pair)[:2]
    held = [[os.path.basename(line.rsplit("run in ", 1)[1]) for line in stdout.splitlines() if "run in " in line]
            for stdout, _ in outputs]
    assert held == [PAIRS[:2], PAIRS[2:]]
    # Process 0 sees every pair's folder (one file system here) and ends with their summary; process 1 does not.
    assert "| point_mass | uniform | 2 | 2000 |" in outputs[0][0] and "Adversarial − uniform" in outputs[0][0]
    assert "| point_mass |" not in outputs[1][0]


def test_placement_pads_or_refuses_with_one_line(monkeypatch):
    placement = PairPlacement.over(3, 1)
    assert (placement.num_devices, placement.pairs_per_device, placement.padded_pairs) == (1, 3, 3)
    assert "pad" not in placement.describe()
    values = placement.place(np.array([5, 6, 7]))
    assert values.shape == (3,) and placement.local_pairs == [0, 1, 2]
    np.testing.assert_array_equal(placement.local_rows({"v": values})["v"], [5, 6, 7])
    # Pairs whose loops run for 1, 3 and 7 steps: vmapped, every pair steps while any runs
    # (branching.while_any, as a scoring round); in turn (a CPU's scoring rounds), each its own.
    def count_steps(limit):
        body = lambda carry, limit: {"own": carry["own"] + (carry["own"] < limit), "every": carry["every"] + 1}
        return while_any(lambda carry, limit: carry["own"] < limit, body, {"own": 0, "every": 0}, limit)

    limits = placement.place(np.array([1, 3, 7]))
    for in_turn, steps in ((False, [7, 7, 7]), (True, [1, 3, 7])):
        counted = placement.local_rows(jax.jit(placement.spread(count_steps, in_turn))(limits))
        assert (counted["own"].tolist(), counted["every"].tolist()) == ([1, 3, 7], steps), in_turn
    # While it waits for the device, a signal (Ctrl-C, SIGTERM) is handled at once: the
    # handler runs before the result is there, not after (as during NumPy's own fetch).
    slow = jax.jit(lambda x: jax.lax.fori_loop(0, 800, lambda _, a: jnp.tanh(a @ a), x))
    matrices = placement.place(np.full((3, 300, 300), 1e-3, np.float32))
    slow(matrices).block_until_ready()
    result_ready_when_handled = []
    previous = signal.signal(signal.SIGALRM, lambda *_: result_ready_when_handled.append(result.is_ready()))
    try:
        result = slow(matrices)  # dispatched: the device works on for about a second
        signal.setitimer(signal.ITIMER_REAL, 0.05)
        placement.local_rows(result)
    finally:
        signal.setitimer(signal.ITIMER_REAL, 0)
        signal.signal(signal.SIGALRM, previous)
    assert result_ready_when_handled == [False]
    with pytest.raises(ValueError, match=f"devices must be 0 \\(all\\) or 1..{jax.device_count()} here"):
        PairPlacement.over(4, jax.device_count() + 1)
    # A SLURM step of one task is one process: nothing to join (JAX's own detection is not asked).
    monkeypatch.setattr(jax.distributed, "initialize", lambda *args, **kwargs: pytest.fail("joined a job of one"))
    monkeypatch.delenv("JAX_COORDINATOR_ADDRESS", raising=False)
    for name, value in (("SLURM_NTASKS", "1"), ("SLURM_STEP_NODELIST", "node1")):
        monkeypatch.setenv(name, value)
    assert initialize_distributed() is False
    monkeypatch.setenv("JAX_COORDINATOR_ADDRESS", "localhost:1")
    monkeypatch.delenv("JAX_PROCESS_ID", raising=False)
    monkeypatch.setenv("JAX_NUM_PROCESSES", "2")
    with pytest.raises(ValueError, match="JAX_COORDINATOR_ADDRESS is set, so JAX_PROCESS_ID must be too"):
        initialize_distributed()
