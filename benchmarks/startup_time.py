"""How long our commands take to start and to end: each module imported in fresh interpreters.

    python benchmarks/startup_time.py [modules=admissable_jax.plot,...] [repeats=3]

For each module, one warm-up process (it writes Python's bytecode caches) and then
``repeats`` fresh processes import it and end as our commands end
(``admissable_jax.cli.exit_with``), and ``repeats`` more end the same with its freeze undone
(Python's plain exit); the record holds the median seconds of the import alone, of the whole
process (interpreter start, import, exit), of the exit alone both ways (``exit_s``,
``plain_exit_s``: from the line printed before it to the process's end), and whether the
import loaded MJX. What
steps no MuJoCo env (configs, ``plot``, ``--help``, the point mass) should not: names,
sizes and feature names come from ``envs/catalog.py``, and ``admissable_jax.envs.physics``
(MJX with MuJoCo Warp's kernels and our contact-frame patches, listed last) is the cost
they avoid. With ``run=``, one command (its module and settings; ``out=`` is added) runs
once each way instead, and the record holds the seconds from its last line to its end.
Appends to ``benchmarks/results/startup_time.jsonl``.

    python benchmarks/startup_time.py run="admissable_jax.train env=hopper physics=jax total_steps=80 score_every=40 ..."
"""

from __future__ import annotations

import dataclasses
import os
import shlex
import statistics
import subprocess
import sys
import tempfile
import time

from admissable_jax.cli import check_at_least_one, parse_args
from common import append_record, run_benchmark

MODULES = ("admissable_jax", "admissable_jax.config", "admissable_jax.train", "admissable_jax.experiment",
           "admissable_jax.plot", "admissable_jax.audit", "admissable_jax.wrappers", "admissable_jax.envs.physics")
# The two ways a process ends, as code run before anything else: as our commands end
# (``exit_with``), and the same with its freeze undone (Python's plain exit).
EXITS = {"command": "", "plain": "import gc; gc.freeze = lambda: None; "}
# Prints the import's seconds, whether it loaded MJX and the moment it starts to exit, then exits.
PROBE = ("{undo}import sys, time; start = time.perf_counter(); import {module}; imported = time.perf_counter() - start; "
         "from admissable_jax.cli import exit_with; print(imported, 'mujoco.mjx' in sys.modules, time.time(), flush=True); "
         "exit_with(0)")


@dataclasses.dataclass
class StartupConfig:
    modules: str = dataclasses.field(default=",".join(MODULES), metadata={"help": "comma-separated modules to import"})
    repeats: int = dataclasses.field(default=3, metadata={"help": "fresh processes per module (median reported)"})
    run: str = dataclasses.field(default="", metadata={
        "help": "instead of the imports: a command's module and key=value settings, run once ending as commands do "
                "and once with Python's plain exit (the freeze undone), e.g. 'admissable_jax.train env=point_mass'"})


def _validate(config: StartupConfig) -> None:
    check_at_least_one(config, ("repeats",))


def measure(module: str, repeats: int) -> dict:
    environment = {key: value for key, value in os.environ.items() if key != "PYTHONDONTWRITEBYTECODE"}
    imports, walls, loads_mjx, exits = [], [], set(), {way: [] for way in EXITS}
    # The first process writes the bytecode caches, uncounted; then the two exits alternate.
    for attempt, way in enumerate(["command"] + [way for _ in range(repeats) for way in EXITS]):
        started = time.perf_counter()
        shown = subprocess.run([sys.executable, "-c", PROBE.format(undo=EXITS[way], module=module)],
                               capture_output=True, text=True, env=environment, check=True)
        wall, ended = time.perf_counter() - started, time.time()
        seconds, mjx, exiting = shown.stdout.split()[-3:]
        loads_mjx.add(mjx == "True")
        if attempt:
            exits[way].append(ended - float(exiting))
            if way == "command":
                imports.append(float(seconds))
                walls.append(wall)
    return {"module": module, "repeats": repeats, "import_s": round(statistics.median(imports), 2),
            "process_s": round(statistics.median(walls), 2), "exit_s": round(statistics.median(exits["command"]), 2),
            "plain_exit_s": round(statistics.median(exits["plain"]), 2), "loads_mjx": loads_mjx == {True}}


def measure_run(command: str) -> dict:
    """Seconds from ``command``'s last line to its end: as it ends (``exit_with``), and with
    the freeze undone (Python's plain exit)."""
    module, *settings = shlex.split(command)
    exits = {}
    for way in EXITS:
        with tempfile.TemporaryDirectory() as directory:
            argv = [module, *settings, f"out={directory}/run"]
            code = f"{EXITS[way]}import runpy, sys; sys.argv = {argv!r}; runpy.run_module({module!r}, run_name='__main__', alter_sys=True)"
            process = subprocess.Popen([sys.executable, "-u", "-c", code], stdout=subprocess.PIPE,
                                       stderr=subprocess.STDOUT, text=True)
            last_line = time.time()
            for _ in process.stdout:
                last_line = time.time()
            if process.wait():
                raise SystemExit(f"error: {command} exited {process.returncode}")
            exits[way] = time.time() - last_line
    return {"run": command, "exit_s": round(exits["command"], 2), "plain_exit_s": round(exits["plain"], 2)}


def main(argv: list[str]) -> int:
    config = parse_args(StartupConfig, argv, "benchmarks/startup_time.py", __doc__.splitlines()[0], _validate)
    if config.run:
        record = measure_run(config.run)
        append_record("startup_time", record)
        print(f"{config.run}: exit {record['exit_s']:.2f} s after its last line "
              f"(Python's plain exit {record['plain_exit_s']:.2f} s)")
        return 0
    for module in (name.strip() for name in config.modules.split(",") if name.strip()):
        record = measure(module, config.repeats)
        append_record("startup_time", record)
        print(f"{module:32s} import {record['import_s']:5.2f} s, process {record['process_s']:5.2f} s, exit "
              f"{record['exit_s']:4.2f} s (Python's plain exit {record['plain_exit_s']:4.2f} s)"
              f"{', loads MJX' if record['loads_mjx'] else ''}")
    return 0


if __name__ == "__main__":
    run_benchmark(main)
