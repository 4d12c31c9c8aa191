"""Where the audit compiles and runs its rollout, so that a Ctrl-C is answered at once and
the process exits cleanly.

The rollout reports the episodes finished so far from inside the compiled program
(``score_missingness``'s ``progress``). XLA:CPU runs a program with such host callbacks on
the calling thread from start to end, and Python hears a Ctrl-C only when that call
returns: a Hopper audit on 2 cores answered one after 29 s, when its rollout ended. So
:func:`watched_rollout` makes the call on a worker thread while the main thread waits, where
a Ctrl-C is heard at once; the rollout's next report then raises :class:`RolloutStopped`,
which ends the program, and the Ctrl-C goes on up from the main thread. And XLA stops a
compile on the main thread when a Ctrl-C comes, after which the process crashed at exit
(SIGSEGV, in 5 of 5 tries); the audit compiles on a worker instead
(:func:`admissable_jax.cli.compiled_in_background`). The command line then ends at once
(:func:`admissable_jax.cli.exit_with`); a Python caller's process waits for the worker before
it exits.
"""

from __future__ import annotations

import concurrent.futures
import logging
import threading
from typing import Any, Callable

from admissable_jax.cli import in_background, progress_bar

LOG_LINE_SECONDS = 60.0  # a line this often where stderr is no terminal (a job's log file), and one at the end


class RolloutStopped(Exception):
    """Raised from a rollout's report to end its program (a Ctrl-C in the main thread)."""


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


_WATCHES: list[_Watch] = []  # the running rollout's (innermost last)


def report_from_rollout(finished) -> None:
    """The rollout's ``progress``: the episodes finished so far, to the running rollout's
    watch. One module function, not a watch's own method, so that the rollout compiles once
    for every audit (a new callable would be a new static argument)."""
    if _WATCHES:
        _WATCHES[-1].report(int(finished))


class _HideStops(logging.Filter):
    """JAX logs a traceback for an exception raised in a callback; a stop is no error."""

    def filter(self, record: logging.LogRecord) -> bool:
        return not (record.exc_info and isinstance(record.exc_info[1], RolloutStopped))


def watched_rollout(rollout: Callable[[], Any], total: int, draw: bool) -> Any:
    """``rollout()`` (a compiled rollout with ``progress=report_from_rollout``, waited for)
    on a worker thread: its result, with a bar over its ``total`` episodes if ``draw``. A
    Ctrl-C meanwhile stops the rollout at its next report, then raises KeyboardInterrupt."""
    watch, quiet = _Watch(total, draw), _HideStops()
    jax_debugging_log = logging.getLogger("jax._src.debugging")

    def run() -> Any:  # everything it sets up stays until the rollout ends, even if a second Ctrl-C leaves it
        _WATCHES.append(watch)
        jax_debugging_log.addFilter(quiet)
        try:
            return rollout()
        finally:
            jax_debugging_log.removeFilter(quiet)
            _WATCHES.remove(watch)
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
