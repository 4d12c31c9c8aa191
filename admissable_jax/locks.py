"""One process at a time per run directory: a lock file holding the owner's pid and host.

Two runs writing into one directory would interleave their rows in ``scores.jsonl`` and
``metrics.jsonl`` and overwrite each other's checkpoints, so a run takes ``<dir>/.lock``
(created exclusively) before it writes anything and removes it when it ends, however it
ends. A lock whose owner no longer runs on this host (a killed run) is stale and is taken
over; a lock held by a live process is refused in one line. The owner of another host cannot
be asked, so its run renews the lock's time every :data:`RENEW_SECONDS` while it holds it: a
lock of another host not renewed for :data:`STALE_AFTER_SECONDS` is a dead owner's (a cluster
job killed on one node, its run continued on another, over a shared file system).
"""

from __future__ import annotations

import json
import os
import socket
import threading
import time

from admissable_jax.errors import UnusableDirectory

LOCK_NAME = ".lock"
RENEW_SECONDS = 30.0  # how often a held lock's time is renewed
STALE_AFTER_SECONDS = 600.0  # another host's renewed lock left this long is a dead owner's (clocks may differ a bit)


class RunDirectoryLocked(UnusableDirectory):
    """Another live process owns the run directory."""


class RunLock:
    def __init__(self, directory: str):
        self.path = os.path.join(directory, LOCK_NAME)
        self.held = False
        self._stop_renewing = threading.Event()  # a new one each time the lock is taken

    def acquire(self) -> None:
        """Take the lock, taking over a stale one; RunDirectoryLocked if another process holds it."""
        owner = {"pid": os.getpid(), "host": socket.gethostname(), "renewed_every": RENEW_SECONDS}
        for _ in range(2):  # a stale lock is removed once, then taken
            try:
                with open(self.path, "x") as file:
                    json.dump(owner, file)
                self.held, self._stop_renewing = True, threading.Event()
                threading.Thread(target=self._renew, args=(self._stop_renewing,), name="run-lock-renewal",
                                 daemon=True).start()
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
        self._stop_renewing.set()
        if self.held and os.path.exists(self.path):
            os.remove(self.path)
        self.held = False

    def _renew(self, stop: threading.Event) -> None:
        """Renew the lock's time until ``stop`` (its release), so that another host sees its owner live."""
        while not stop.wait(RENEW_SECONDS):
            try:
                os.utime(self.path)
            except OSError:  # released meanwhile, or the disk is gone: nothing to renew
                return


def live_holder(directory: str) -> dict | None:
    """The owner (``{"pid", "host"}``) of ``directory``'s lock where it still runs; None where
    the directory is free or its lock is stale (its owner ended, or a killed process left it
    half written). The owner of a lock taken on another host cannot be asked from here: it is
    taken to be live while it renews the lock (one written by a version that did not renew
    its lock: always)."""
    path = os.path.join(directory, LOCK_NAME)
    try:
        with open(path) as file:
            holder = json.load(file)
        unrenewed_for = time.time() - os.path.getmtime(path)
    except (OSError, ValueError):
        return None
    return holder if isinstance(holder, dict) and _is_alive(holder, socket.gethostname(), unrenewed_for) else None


def _is_alive(holder: dict, this_host: str, unrenewed_for: float) -> bool:
    """Whether the lock's owner still runs (on another host: while it renews the lock)."""
    if holder.get("host") != this_host:
        return "renewed_every" not in holder or unrenewed_for < STALE_AFTER_SECONDS
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
