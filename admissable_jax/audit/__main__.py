"""``python -m admissable_jax.audit``: the command line of :mod:`admissable_jax.audit.command`."""

import sys

from admissable_jax.audit.command import main
from admissable_jax.cli import exit_with

exit_with(main(sys.argv[1:]))
