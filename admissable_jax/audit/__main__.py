"""``python -m admissable_jax.audit``: the command line of :mod:`admissable_jax.audit.command`."""

from admissable_jax.audit.command import main
from admissable_jax.cli import run_main

run_main(main)
