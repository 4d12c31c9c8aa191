"""Exit statuses and the errors a run ends with, for the command lines.

Every failure a user can cause or meet is one of these (or a ValueError/TypeError for a
bad setting); :func:`admissable_jax.cli.run_from_cli` prints it as one line and exits
with its status, never with a traceback.
"""

USAGE_ERROR = 2  # a bad setting or a run directory that cannot be used
RUN_FAILED = 1  # the run itself failed (its finished work is kept)
INTERRUPTED = 130  # the shell's status for a program ended by SIGINT (Ctrl-C)


class RunFailed(RuntimeError):
    """A run that stopped; ``exit_status`` and ``label`` say how the command line ends."""

    exit_status = RUN_FAILED
    label = "error"


class UnusableRunDirectory(RunFailed):
    """``out`` cannot be created or is owned by another process."""

    exit_status = USAGE_ERROR


class Interrupted(RunFailed):
    """Ctrl-C during training; says where the last checkpoint is."""

    exit_status = INTERRUPTED
    label = "interrupted"
