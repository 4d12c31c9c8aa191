"""How long our commands take to start: each module imported in fresh interpreters.

    python benchmarks/startup_time.py [modules=admissable_jax.plot,...] [repeats=3]

For each module, one warm-up process (it writes Python's bytecode caches) and then
``repeats`` fresh processes import it; the record holds the median seconds of the import
alone and of the whole process (interpreter start, import, exit), and whether the import
loaded MJX. What steps no MuJoCo env (configs, ``plot``, ``--help``, the point mass) should
not: names, sizes and feature names come from ``envs/catalog.py``, and
``admissable_jax.envs.physics`` (MJX with MuJoCo Warp's kernels and our contact-frame
patches, listed last) is the cost they avoid. Appends to
``benchmarks/results/startup_time.jsonl``.
"""

from __future__ import annotations

import dataclasses
import os
import statistics
import subprocess
import sys
import time

from admissable_jax.cli import parse_args
from common import append_record

MODULES = ("admissable_jax", "admissable_jax.config", "admissable_jax.train", "admissable_jax.experiment",
           "admissable_jax.plot", "admissable_jax.audit", "admissable_jax.wrappers", "admissable_jax.envs.physics")
# Prints the import's seconds and whether it loaded MJX.
PROBE = ("import sys, time; start = time.perf_counter(); import {module}; "
         "print(time.perf_counter() - start, 'mujoco.mjx' in sys.modules)")


@dataclasses.dataclass
class StartupConfig:
    modules: str = dataclasses.field(default=",".join(MODULES), metadata={"help": "comma-separated modules to import"})
    repeats: int = dataclasses.field(default=3, metadata={"help": "fresh processes per module (median reported)"})


def measure(module: str, repeats: int) -> dict:
    environment = {key: value for key, value in os.environ.items() if key != "PYTHONDONTWRITEBYTECODE"}
    imports, walls, loads_mjx = [], [], set()
    for attempt in range(repeats + 1):  # the first writes the bytecode caches, uncounted
        started = time.perf_counter()
        shown = subprocess.run([sys.executable, "-c", PROBE.format(module=module)], capture_output=True, text=True,
                               env=environment, check=True)
        wall = time.perf_counter() - started
        seconds, mjx = shown.stdout.split()[-2:]
        loads_mjx.add(mjx == "True")
        if attempt:
            imports.append(float(seconds))
            walls.append(wall)
    return {"module": module, "repeats": repeats, "import_s": round(statistics.median(imports), 2),
            "process_s": round(statistics.median(walls), 2), "loads_mjx": loads_mjx == {True}}


def main(argv: list[str]) -> int:
    config = parse_args(StartupConfig, argv, "benchmarks/startup_time.py", __doc__.splitlines()[0])
    if config.repeats < 1:
        raise SystemExit("error: repeats must be >= 1")
    for module in (name.strip() for name in config.modules.split(",") if name.strip()):
        record = measure(module, config.repeats)
        append_record("startup_time", record)
        print(f"{module:32s} import {record['import_s']:5.2f} s, process {record['process_s']:5.2f} s"
              f"{', loads MJX' if record['loads_mjx'] else ''}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main(sys.argv[1:]))
