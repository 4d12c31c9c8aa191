"""How soon a running experiment answers a stop: SIGTERM (a job scheduler's stop; Ctrl-C's
SIGINT alike) sent while a scoring interval trains.

    python benchmarks/stop_latency.py [env=hopper] [seeds=1] [after=10] [second=-1]

Starts ``python -m admissable_jax.experiment`` (modes adversarial and uniform, 10,000 env
steps, learning from 1,000) with its progress bar on, waits until the bar says ``training``,
then ``after`` seconds more, and sends SIGTERM. The record holds the seconds until the run
said "SIGTERM: stopping at the end of this scoring interval" (its handler ran) and until it
exited, having finished and checkpointed the interval, and its last line. Python runs signal
handlers only between bytecodes, so a wait inside a long device call can hold them back.
With ``second`` ≥ 0, a second SIGTERM follows the first by that many seconds (a user's
"stop now"), and the record holds the seconds from it until the process ended.
Appends to ``benchmarks/results/stop_latency.jsonl``.
"""

from __future__ import annotations

import dataclasses
import os
import select
import signal
import subprocess
import sys
import tempfile
import time

from admissable_jax.cli import check_at_least_one, parse_args
from common import append_record, run_benchmark


@dataclasses.dataclass
class StopLatencyConfig:
    env: str = dataclasses.field(default="hopper", metadata={"help": "the experiment's env"})
    seeds: int = dataclasses.field(default=1, metadata={"help": "seeds per mode (2 modes)"})
    after: float = dataclasses.field(default=10.0, metadata={"help": "seconds into training to send SIGTERM"})
    second: float = dataclasses.field(default=-1.0, metadata={
        "help": "seconds after the first SIGTERM to send a second (stop now); < 0: none"})


def _validate(config: StopLatencyConfig) -> None:
    check_at_least_one(config, ("seeds",))
    if config.after < 0:
        raise ValueError(f"after must be >= 0 seconds, got {config.after}")


def measure(config: StopLatencyConfig) -> dict:
    with tempfile.TemporaryDirectory() as directory:
        command = [sys.executable, "-m", "admissable_jax.experiment", f"env={config.env}", f"seeds={config.seeds}",
                   "modes=adversarial,uniform", "total_steps=10000", "learning_starts=1000",
                   f"out={os.path.join(directory, 'run')}", "progress=true"]
        run = subprocess.Popen(command, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
        said, sent, handled, second_sent = b"", None, None, None
        while run.poll() is None:
            if select.select([run.stderr], [], [], 0.05)[0]:
                said += os.read(run.stderr.fileno(), 1 << 16)
            if sent is None and b"training:" in said:
                time.sleep(config.after)
                run.send_signal(signal.SIGTERM)
                sent = time.perf_counter()
            if sent is not None and handled is None and b"SIGTERM: stopping" in said:
                handled = time.perf_counter() - sent
            if handled is not None and second_sent is None and 0 <= config.second <= time.perf_counter() - sent:
                run.send_signal(signal.SIGTERM)
                second_sent = time.perf_counter()
        ended = time.perf_counter()
        exited = ended - sent if sent is not None else None
        said += run.stderr.read()
    lines = said.decode().replace("\r", "\n").strip().splitlines()
    return {"env": config.env, "pairs": 2 * config.seeds, "after_s": config.after,
            "handled_s": None if handled is None else round(handled, 2),
            "exited_s": None if exited is None else round(exited, 1), "exit_status": run.returncode,
            **({"second_after_s": config.second,
                "exited_after_second_s": None if second_sent is None else round(ended - second_sent, 2)}
               if config.second >= 0 else {}),
            "last_line": lines[-1] if lines else ""}


def main(argv: list[str]) -> int:
    record = measure(parse_args(StopLatencyConfig, argv, program="benchmarks/stop_latency.py",
                                summary="How soon a running experiment answers SIGTERM.", validate=_validate))
    second = f" ({record['exited_after_second_s']} s after the second)" if "second_after_s" in record else ""
    print(f"SIGTERM handled after {record['handled_s']} s; exited after {record['exited_s']} s{second} "
          f"(status {record['exit_status']}): {record['last_line']}")
    append_record("stop_latency", record)
    return 0


if __name__ == "__main__":
    run_benchmark(main)
