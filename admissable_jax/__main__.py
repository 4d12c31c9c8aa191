"""``python -m admissable_jax``: which command lines the package has, one line each;
``--version``: this package's version and source commit and those of the libraries a run's
numbers depend on, for a bug report; ``python -m admissable_jax COMMAND key=value ...``:
the command, as ``python -m admissable_jax.COMMAND key=value ...`` runs it.

Each line is the first line of the command's own module docstring, read from its source
(nothing is imported, so this answers at once, without JAX).
"""

from __future__ import annotations

import ast
import os
import runpy
import sys

from admissable_jax.errors import USAGE_ERROR
from admissable_jax.provenance import package_versions, source_commit

COMMANDS = ("train", "experiment", "plot", "audit", "video", "export", "rollout", "status")


def summary(command: str) -> str:
    """The first line of ``admissable_jax.<command>``'s module docstring (a package's: its ``__init__``'s)."""
    module = os.path.join(os.path.dirname(__file__), command)
    with open(f"{module}.py" if os.path.isfile(f"{module}.py") else os.path.join(module, "__init__.py")) as file:
        return ast.get_docstring(ast.parse(file.read())).splitlines()[0].replace("``", "")


def versions() -> str:
    """Two lines: this package (and its commit, where it runs from a checkout), then the
    installed versions of the libraries its numbers depend on, and Python's."""
    installed = package_versions()
    ours = installed.pop("admissable_jax", "not installed")
    commit = source_commit()
    return (f"admissable_jax {ours}" + (f", commit {commit}" if commit else "") + "\n"
            + ", ".join([f"{name} {version}" for name, version in installed.items()] + [f"Python {sys.version.split()[0]}"]))


def run_command(command: str, argv: list[str]) -> int:
    """Run ``admissable_jax.<command>`` as ``python -m admissable_jax.<command> *argv`` does:
    its module (a package's ``__main__``) executed as ``__main__``, so it is imported once. Our
    commands end the process with their own exit status; one that returned would exit 0."""
    sys.argv[1:] = argv
    runpy.run_module(f"admissable_jax.{command}", run_name="__main__", alter_sys=True)
    return 0


def main(argv: list[str]) -> int:
    if argv == ["--version"]:
        print(versions())
        return 0
    if argv and argv[0] in COMMANDS:
        return run_command(argv[0], argv[1:])
    if argv and argv not in (["--help"], ["-h"]):
        print(f"error: {argv[0]!r} is no command: run one of {', '.join(COMMANDS)}, e.g. python -m admissable_jax "
              f"train {' '.join(argv)} (python -m admissable_jax lists them)", file=sys.stderr)
        return USAGE_ERROR
    print("commands (each takes key=value settings; --help lists them; python -m admissable_jax COMMAND ... runs the same):")
    for command in COMMANDS:
        print(f"  python -m admissable_jax.{command:<11} {summary(command)}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main(sys.argv[1:]))
