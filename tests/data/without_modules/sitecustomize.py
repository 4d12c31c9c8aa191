"""Loaded at the start of every Python process that has this folder on ``PYTHONPATH``: makes the
modules named in ``WITHOUT_MODULES`` (comma-separated; ``mujoco.experimental`` and what is
under it, ``OpenGL`` and what is under it) unimportable, as on a device
machine whose packs left their wheels out, and logs to ``WITHOUT_MODULES_LOG`` that it was
loaded and each import it refused (an import caught by its importer, as MuJoCo catches its
renderer's, is no failure)."""

import importlib.abc
import os
import sys

_WITHOUT = frozenset(filter(None, os.environ.get("WITHOUT_MODULES", "").split(",")))
_LOG = os.environ.get("WITHOUT_MODULES_LOG")


def _log(line: str) -> None:
    if _LOG:
        with open(_LOG, "a") as file:
            file.write(f"{os.getpid()} {line}\n")


class _Without(importlib.abc.MetaPathFinder):
    def find_spec(self, name, path, target=None):
        if any(name == left_out or name.startswith(left_out + ".") for left_out in _WITHOUT):
            _log(f"refused {name}")
            raise ModuleNotFoundError(f"No module named {name!r} (left out of the device packs)", name=name)
        return None


sys.meta_path.insert(0, _Without())
_log("loaded")
