"""benchmarks/campaign.py's plans from the speed records on main (no training, no GPU)."""

import importlib.util
import os
import sys

BENCHMARKS = os.path.join(os.path.dirname(__file__), "..", "benchmarks")
sys.path.insert(0, BENCHMARKS)  # campaign.py imports its neighbour common.py
_spec = importlib.util.spec_from_file_location("campaign", os.path.join(BENCHMARKS, "campaign.py"))
campaign = sys.modules["campaign"] = importlib.util.module_from_spec(_spec)  # its dataclasses look it up there
_spec.loader.exec_module(campaign)


def test_the_next_lease_is_planned_from_the_committed_h100_record(capsys):
    """The hopper step's fallback as the next lease will plan it, from the H100 speed record
    on main (read through speed_device here, as on an H200 that has none): 1,650 s hold 156
    scorings once the first run's 58 s (Warp's kernels built and loaded) are counted."""
    status = campaign.main(["plan", "env=hopper", "modes=adversarial,uniform,none", "physics=warp", "seeds=5",
                            "num_envs=125", "score_every=5000", "checkpoint_every=20", "total_steps=0",
                            "min_steps=200000", "max_steps=1000000", "deadline=1650",
                            "speed_device=gpu:NVIDIA H100 80GB HBM3"])
    shown = capsys.readouterr().out
    assert status == 0, shown
    assert "compile 50 s + first run 58 s + 156 scorings x (chunk 2.2 s + full-length scoring 7.5 s)" in shown
    assert shown.strip().splitlines()[-1] == "total_steps=780000"
