"""Does this machine repeat a run bit for bit? A short experiment, then its records alone
fast-forwarded in a fresh process.

    python benchmarks/repeatability.py [env=hopper] [seeds=1] [modes=adversarial,uniform] [total_steps=20000] [learning_starts=10000] [extra='KEY=VALUE ...'] [out=runs/repeatability]

A run continues on another machine (the GPU campaign's ``CAMPAIGN_RECORDS``) only where that
machine re-trains it from its records bit for bit (``resume=true fast_forward=true``, which
checks every rebuilt state against its recorded fingerprint). This measures the half of it
one machine can: ``experiment`` trains ``total_steps`` (past ``learning_starts``, so the SAC
updates are in it, not only the physics) into ``out/recorded``; its records, without their
checkpoints, are copied to ``out/rebuilt``, and a second process fast-forwards them,
compiling its programs anew (a JAX compilation cache of its own), as the next machine would. Every
fingerprint matching says this machine repeats the run; a divergence says at which env step
(5,000 points at the physics: nothing is learnt before ``learning_starts``). A GPU run needs
MuJoCo Warp's deterministic mode (``deterministic_physics=true``, the default) and XLA's
deterministic ops (``XLA_FLAGS``, as ``gpu_campaign.sh`` sets them). ``extra`` goes to both
commands (e.g. ``extra='deterministic_physics=false'`` to see the GPU's own order diverge).

Appends a record to ``repeatability.jsonl`` (whether it repeated, where it diverged, each
command's wall seconds, XLA_FLAGS) and exits 0 where it repeated, 1 where it did not. On a
2-core CPU the default takes about ten minutes; on an H100/H200 about two (projected from the
campaign's records, not yet measured).
"""

from __future__ import annotations

import dataclasses
import os
import re
import shlex
import shutil
import subprocess
import sys
import time

from common import append_record, run_benchmark

from admissable_jax.cli import check_at_least_one, parse_args

DIVERGED = re.compile(r"fast-forward diverged at env step ([0-9,]+)")
FROM_THE_START = "fast-forward: re-training env steps 0 to "  # a rebuild that re-trained every interval


@dataclasses.dataclass
class RepeatabilityConfig:
    env: str = dataclasses.field(default="hopper", metadata={"help": "env of the experiment"})
    seeds: int = dataclasses.field(default=1, metadata={"help": "seeds per mode"})
    modes: str = dataclasses.field(default="adversarial,uniform", metadata={"help": "the experiment's modes"})
    total_steps: int = dataclasses.field(default=20000, metadata={"help": "env steps recorded, then rebuilt"})
    learning_starts: int = dataclasses.field(default=10000, metadata={"help": "env steps before SAC learns (below total_steps)"})
    extra: str = dataclasses.field(default="", metadata={"help": "more experiment keys for both commands, 'key=value ...'"})
    out: str = dataclasses.field(default="runs/repeatability", metadata={"help": "folder for both experiments (emptied first)"})


def _validate(config: RepeatabilityConfig) -> None:
    check_at_least_one(config, ("seeds",))  # (the experiments check the rest, once started)
    if not 0 < config.learning_starts < config.total_steps:
        raise ValueError(f"learning_starts must be in (0, total_steps = {config.total_steps}), got {config.learning_starts}")


def _experiment(config: RepeatabilityConfig, out: str, *more: str,
                environment: dict[str, str] | None = None) -> tuple[subprocess.CompletedProcess, float]:
    command = [sys.executable, "-m", "admissable_jax.experiment", f"env={config.env}", f"seeds={config.seeds}",
               f"modes={config.modes}", f"total_steps={config.total_steps}", f"learning_starts={config.learning_starts}",
               "progress=false", f"out={out}", *shlex.split(config.extra), *more]
    print("$", shlex.join(command[1:]), flush=True)
    start = time.perf_counter()
    done = subprocess.run(command, capture_output=True, text=True, env=environment)
    seconds = time.perf_counter() - start
    print(done.stdout + done.stderr, end="", flush=True)
    return done, seconds


def main(argv: list[str]) -> int:
    config = parse_args(RepeatabilityConfig, argv, "benchmarks/repeatability.py", __doc__.strip().splitlines()[0], _validate)
    recorded, rebuilt = os.path.join(config.out, "recorded"), os.path.join(config.out, "rebuilt")
    shutil.rmtree(config.out, ignore_errors=True)
    first, record_seconds = _experiment(config, recorded)
    if first.returncode != 0:
        raise ValueError(f"the recorded experiment failed (exit {first.returncode}); its output is above")
    shutil.copytree(recorded, rebuilt, ignore=shutil.ignore_patterns("checkpoints*"))
    # Compiled anew, as on the next machine: a JAX compilation cache of its own, empty.
    fresh_cache = {**os.environ, "JAX_COMPILATION_CACHE_DIR": os.path.abspath(os.path.join(config.out, "rebuild-jax-cache"))}
    second, rebuild_seconds = _experiment(config, rebuilt, "resume=true", "fast_forward=true", environment=fresh_cache)
    said = second.stdout + second.stderr
    diverged = DIVERGED.search(said)
    if second.returncode != 0 and not diverged:
        raise ValueError(f"the fast-forward failed (exit {second.returncode}) other than by diverging; its output is above")
    if FROM_THE_START not in said:
        raise ValueError("the fast-forward did not re-train the run from its start (a checkpoint was copied?): no verdict")
    repeated = second.returncode == 0
    path = append_record("repeatability", {
        "env": config.env, "seeds": config.seeds, "modes": config.modes, "total_steps": config.total_steps,
        "learning_starts": config.learning_starts, "extra": config.extra, "xla_flags": os.environ.get("XLA_FLAGS", ""),
        "repeated": repeated, "diverged_at": int(diverged.group(1).replace(",", "")) if diverged else None,
        "record_seconds": round(record_seconds, 1), "rebuild_seconds": round(rebuild_seconds, 1),
    })
    verdict = "repeated bit for bit" if repeated else f"diverged at env step {diverged.group(1)}"
    print(f"{config.env}, {config.total_steps} env steps: {verdict} (record {record_seconds:.0f} s, "
          f"rebuild {rebuild_seconds:.0f} s); record appended to {path}")
    return 0 if repeated else 1


if __name__ == "__main__":
    run_benchmark(main)
