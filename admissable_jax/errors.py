"""Exit statuses and the errors a run ends with, for the command lines.

Every failure a user can cause or meet is one of these (or a ValueError/TypeError for a
bad setting); :func:`admissable_jax.cli.run_from_cli` prints it as one line and exits
with its status, never with a traceback.
"""

import os
from typing import BinaryIO, Callable

USAGE_ERROR = 2  # a bad setting or an output folder that cannot be used
RUN_FAILED = 1  # the run itself failed (its finished work is kept)
INTERRUPTED = 130  # the shell's status for a program ended by SIGINT (Ctrl-C)
BROKEN_PIPE = 141  # the shell's status for a program ended by SIGPIPE: its reader stopped (`| head`)


class RunFailed(RuntimeError):
    """A run that stopped; ``exit_status`` and ``label`` say how the command line ends."""

    exit_status = RUN_FAILED
    label = "error"


class UnusableDirectory(RunFailed):
    """An output folder (``out``: a run's, an experiment's, figures', an audit's) cannot be
    created, or a run directory is owned by another process."""

    exit_status = USAGE_ERROR


def make_directory(path: str, what: str) -> None:
    """Create the folder ``path`` (and its parents) if missing; :class:`UnusableDirectory`
    in one line naming ``what`` it is for and why not (``/proc/x``, ``/dev/null/x``, no
    permission), before any work goes into it."""
    try:
        os.makedirs(path, exist_ok=True)
    except OSError as error:
        raise UnusableDirectory(f"cannot create the {what} {path}: {error.strerror}") from None


def write_whole(path: str, write: Callable[[BinaryIO], None]) -> None:
    """Write the file ``path`` by ``write(file)`` whole or not at all: into ``<path>.partial``,
    then renamed over ``path``, so that a crash mid-write leaves the earlier file in place. A
    write that fails (OSError: a full disk, no permission) removes what it wrote and raises,
    for the caller to say in one line what was not written."""
    partial = f"{path}.partial"
    try:
        with open(partial, "wb") as file:
            write(file)
        os.replace(partial, path)
    except OSError:
        if os.path.exists(partial):
            os.remove(partial)
        raise


def remove_if_unused(path: str, own_files: tuple[str, ...]) -> None:
    """Remove the folder ``path`` that this command made, if it holds nothing but
    ``own_files`` (what the command itself wrote there, its settings) and empty folders: a
    command that stopped before any work (refused, a dry run, interrupted while compiling)
    leaves nothing behind. Anything else in it keeps it, as it is."""
    try:
        entries = [os.path.join(path, name) for name in os.listdir(path)]
        if not all((os.path.isfile(entry) and os.path.basename(entry) in own_files)
                   or (os.path.isdir(entry) and not os.listdir(entry)) for entry in entries):
            return
        for entry in entries:
            (os.remove if os.path.isfile(entry) else os.rmdir)(entry)
        os.rmdir(path)
    except OSError:  # gone already, or filled by another process meanwhile: leave it
        return


class Interrupted(RunFailed):
    """Ctrl-C during training; says where the last checkpoint is."""

    exit_status = INTERRUPTED
    label = "interrupted"
