"""One process at a time per run directory: a lock file holding the owner's pid and host.

Two runs writing into one directory would interleave their rows in ``scores.jsonl`` and
``metrics.jsonl`` and overwrite each other's checkpoints, so a run takes ``<dir>/.lock``
(created exclusively) before it writes anything and removes it when it ends, however it
ends. A lock whose owner no longer runs on this host (a killed run) is stale and is taken
over; a lock held by a live process, or by another host, is refused in one line.
"""

from __future__ import annotations

import json
import os
import socket

from admissable_jax.errors import UnusableDirectory

LOCK_NAME = ".lock"


class RunDirectoryLocked(UnusableDirectory):
    """Another live process owns the run directory."""


class RunLock:
    def __init__(self, directory: str):
        self.path = os.path.join(directory, LOCK_NAME)
        self.held = False

    def acquire(self) -> None:
        """Take the lock, taking over a stale one; RunDirectoryLocked if another process holds it."""
        owner = {"pid": os.getpid(), "host": socket.gethostname()}
        for _ in range(2):  # a stale lock is removed once, then taken
            try:
                with open(self.path, "x") as file:
                    json.dump(owner, file)
                self.held = True
                return
            except FileExistsError:
                holder = live_holder(os.path.dirname(self.path))
                if holder is not None:
                    raise RunDirectoryLocked(
                        f"{os.path.dirname(self.path)} is in use by process {holder.get('pid')} on "
                        f"{holder.get('host')}; wait for it or choose another out"
                    ) from None
                os.remove(self.path)
        raise RunDirectoryLocked(f"could not take the lock {self.path}")

    def release(self) -> None:
        if self.held and os.path.exists(self.path):
            os.remove(self.path)
        self.held = False


def live_holder(directory: str) -> dict | None:
    """The owner (``{"pid", "host"}``) of ``directory``'s lock where it still runs; None where
    the directory is free or its lock is stale (its owner ended, or a killed process left it
    half written). A lock taken on another host is taken to be live: its owner cannot be
    asked from here."""
    try:
        with open(os.path.join(directory, LOCK_NAME)) as file:
            holder = json.load(file)
    except (OSError, ValueError):
        return None
    return holder if isinstance(holder, dict) and _is_alive(holder, socket.gethostname()) else None


def _is_alive(holder: dict, this_host: str) -> bool:
    """Whether the lock's owner still runs (a lock from another host is assumed live)."""
    if holder.get("host") != this_host:
        return True
    pid = holder.get("pid")
    # This process's own pid: not a lock it took (acquire saw the file there), so one left by
    # a run killed before; in a container the new process often gets the old one's pid.
    if not isinstance(pid, int) or pid == os.getpid():
        return False
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    return True
