"""What produced a run: each command that trains in a run directory adds one line to its
``invocations.jsonl`` (when, the command line, host, device, physics, library versions,
source commit, and the env step it started from), so a run resumed on another machine, or
after an upgrade, says so in its own folder. JAX-free: the caller names the device.
"""

from __future__ import annotations

import datetime
import importlib.metadata
import os
import platform
import subprocess
import sys
from typing import Any

INVOCATIONS = "invocations.jsonl"
INVOCATION_KEYS = ("device", "devices", "physics", "versions", "commit")  # what plot's "Trained on" line reads
PACKAGES = ("admissable_jax", "jax", "jaxlib", "mujoco", "mujoco-mjx", "mujoco-warp", "warp-lang", "flax", "optax", "orbax-checkpoint",
            "brax", "numpy", "gymnasium")


def package_versions() -> dict[str, str]:
    """The installed versions of the packages a run's numbers depend on (absent ones left out)."""
    versions = {}
    for name in PACKAGES:
        try:
            versions[name] = importlib.metadata.version(name)
        except importlib.metadata.PackageNotFoundError:
            continue
    return versions


def source_commit(exclude: tuple[str, ...] = ()) -> str | None:
    """The git commit of the checkout this package runs from (short), marked ``+changes``
    where tracked files differ from it (paths under ``exclude``, relative to the repository
    root, not counted); None outside a git checkout (an installed wheel) or without git."""
    def git(*args: str) -> str:
        try:
            return subprocess.run(["git", *args], capture_output=True, text=True, timeout=10,
                                  cwd=os.path.dirname(os.path.abspath(__file__))).stdout.strip()
        except (OSError, subprocess.SubprocessError):
            return ""

    commit = git("rev-parse", "--short", "HEAD")
    if not commit:
        return None
    excluded = [f":(top,exclude){path}" for path in exclude]
    changed = git("status", "--porcelain", "--untracked-files=no", "--", ":(top)", *excluded)
    return commit + ("+changes" if changed else "")


def command_line() -> list[str]:
    """This process's command as one would type it again: ``python -m admissable_jax.train
    env=ant`` for our commands (whose ``sys.argv[0]`` Python sets to the module's file,
    ``.../admissable_jax/train.py``, which run as a script would not find its package), else
    the interpreter and ``sys.argv`` as they are (a script calling ``train_fn``)."""
    python = os.path.basename(sys.executable)
    package = os.path.dirname(os.path.abspath(__file__))
    script = os.path.abspath(sys.argv[0]) if sys.argv and sys.argv[0] else ""
    if not (script.startswith(package + os.sep) and script.endswith(".py")):
        return [python, *sys.argv]
    module = os.path.relpath(script, os.path.dirname(package))[:-len(".py")].replace(os.sep, ".")
    return [python, "-m", module.removesuffix(".__main__"), *sys.argv[1:]]


def invocation_record(from_env_steps: int, fast_forward_to: int | None, device: str, devices: int, physics: str,
                      runs_in_program: int) -> dict[str, Any]:
    """One ``invocations.jsonl`` line for the command now training (``fast_forward_to``: the
    env step to which it re-trains from the records, None without ``fast_forward``;
    ``device``: the kind, e.g. ``gpu:NVIDIA H100 80GB HBM3``, of the ``devices`` it runs on;
    ``runs_in_program``: the pairs trained together)."""
    return {
        "started": datetime.datetime.now(datetime.timezone.utc).isoformat(timespec="seconds"),
        "from_env_steps": from_env_steps,
        "fast_forward_to": fast_forward_to,
        "command": command_line(),
        "host": platform.node(),
        "device": device,
        "devices": devices,
        "physics": physics,
        "runs_in_program": runs_in_program,
        "python": platform.python_version(),
        "versions": package_versions(),
        "commit": source_commit(),
    }
