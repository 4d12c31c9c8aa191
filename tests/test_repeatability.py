"""benchmarks/repeatability.py: a short experiment, then its records alone fast-forwarded in a
fresh process, and the verdict (on the CPU, which repeats runs bit for bit)."""

from __future__ import annotations

import json
import os

import common  # benchmarks/ is on the tests' path (conftest.py)
import repeatability


def test_a_cpu_experiment_repeats_from_its_records_alone(tmp_path, monkeypatch, capsys):
    monkeypatch.setattr(common, "RESULTS_DIR", str(tmp_path / "results"))
    # Every compiled program cached, so that the caches show which process compiled what.
    monkeypatch.setenv("JAX_PERSISTENT_CACHE_MIN_COMPILE_TIME_SECS", "0")
    monkeypatch.setenv("JAX_COMPILATION_CACHE_DIR", str(tmp_path / "recording-cache"))
    out = tmp_path / "runs"
    status = repeatability.main([
        "env=point_mass", "total_steps=2000", "learning_starts=1000", f"out={out}",
        "extra=score_every=1000 num_envs=4 score_episodes=2 episode_length=50 batch_size=64 buffer_size=5000 hidden_size=32",
    ])
    said = capsys.readouterr().out
    assert status == 0, said
    assert "point_mass, 2000 env steps: repeated bit for bit" in said
    # The rebuild re-trained every interval: no checkpoint went with the records.
    assert repeatability.FROM_THE_START + "2000" in said
    # ...and compiled its programs anew, in a cache of its own, as the next machine would.
    assert os.listdir(out / "rebuild-jax-cache") and os.listdir(tmp_path / "recording-cache")
    rebuilt_pairs = [name for name in os.listdir(out / "rebuilt") if (out / "rebuilt" / name / "scores.jsonl").is_file()]
    assert len(rebuilt_pairs) == 2
    record = json.loads((tmp_path / "results" / "repeatability.jsonl").read_text().splitlines()[-1])
    assert record["repeated"] is True and record["diverged_at"] is None and record["total_steps"] == 2000


def test_commands_keep_the_compile_time_floor_the_environment_sets(monkeypatch):
    """With JAX_PERSISTENT_CACHE_MIN_COMPILE_TIME_SECS set, a command keeps the floor JAX read
    from it (the check above counts on every program cached: at 0, a program compiled in under
    a second is kept too); unset, programs compiled in under a second are not kept."""
    import jax

    from admissable_jax import cli

    floor = "jax_persistent_cache_min_compile_time_secs"
    before = {name: getattr(jax.config, name) for name in ("jax_compilation_cache_dir", floor)}
    try:
        jax.config.update(floor, 0.0)  # as JAX reads the variable when imported
        monkeypatch.setenv("JAX_PERSISTENT_CACHE_MIN_COMPILE_TIME_SECS", "0")
        cli.enable_compilation_cache()
        assert getattr(jax.config, floor) == 0.0
        monkeypatch.delenv("JAX_PERSISTENT_CACHE_MIN_COMPILE_TIME_SECS")
        cli.enable_compilation_cache()
        assert getattr(jax.config, floor) == 1.0
    finally:
        for name, value in before.items():
            jax.config.update(name, value)
