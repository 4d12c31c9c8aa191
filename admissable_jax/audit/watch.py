"""Where the audit compiles and runs its rollout, so that a Ctrl-C is answered at once and
the process exits cleanly.

The rollout runs from the host in segments, a compiled program of at most 20 loop steps
each (:class:`~admissable_jax.scoring.rollout_scores.RolloutInSegments`), and reports the
episodes finished after each. XLA:CPU runs a program on the calling thread, and Python
hears a Ctrl-C only when that call returns (a Hopper audit on 2 cores that ran as one
program answered one after 29 s, when its rollout ended). So :func:`watched_rollout` makes
the calls on a worker thread while the main thread waits, where a Ctrl-C is heard at once;
the rollout's next report then raises :class:`RolloutStopped`, which ends it, and the
Ctrl-C goes on up from the main thread. And XLA stops a compile on the main thread when a
Ctrl-C comes, after which the process crashed at exit (SIGSEGV, in 5 of 5 tries); the audit
compiles on a worker instead (:func:`admissable_jax.cli.compiled_in_background`). The
command line then ends at once (:func:`admissable_jax.cli.exit_with`); a Python caller's
process waits for the worker before it exits.
"""

from __future__ import annotations

import concurrent.futures
import threading
from typing import Any, Callable

from admissable_jax.cli import in_background, progress_bar

LOG_LINE_SECONDS = 60.0  # a line this often where stderr is no terminal (a job's log file), and one at the end


class RolloutStopped(Exception):
    """Raised from a rollout's report to end the rollout (a Ctrl-C in the main thread)."""


class _Watch:
    """What the running rollout reports to: a bar over its ``total`` episodes (drawn from the
    first report on, so that its clock and rate leave the compile out) and a stop flag."""

    def __init__(self, total: int, draw: bool):
        self.total, self.draw, self.bar = total, draw, None
        self.stop = threading.Event()

    def report(self, finished: int) -> None:
        if self.stop.is_set():
            raise RolloutStopped
        if self.draw:
            if self.bar is None:  # smoothing=0: the rate and time left over the audit so far, not its last burst
                self.bar = progress_bar("episodes", every=LOG_LINE_SECONDS, total=self.total, unit="episode",
                                        dynamic_ncols=True, smoothing=0)
            self.bar.update(max(0, finished - self.bar.n))

    def close(self) -> None:
        if self.bar is not None:
            self.bar.close()


def watched_rollout(rollout: Callable[[Callable[[int], None]], Any], total: int, draw: bool) -> Any:
    """``rollout(report)`` (a rollout that tells ``report`` the episodes finished so far, as
    it goes) on a worker thread: its result, with a bar over its ``total`` episodes if
    ``draw``. A Ctrl-C meanwhile stops the rollout at its next report, then raises
    KeyboardInterrupt."""
    watch = _Watch(total, draw)

    def run() -> Any:  # its bar stays until the rollout ends, even if a second Ctrl-C leaves it
        try:
            return rollout(watch.report)
        finally:
            watch.close()

    future = in_background(run)
    try:
        return future.result()
    except KeyboardInterrupt:
        watch.stop.set()  # the rollout's next report ends it
        try:
            concurrent.futures.wait([future])
        except KeyboardInterrupt:  # a second Ctrl-C: the rollout stops on its own; its bar's line ends here
            watch.close()
            raise
        raise
