"""``python -m admissable_jax.audit``: the command line of :mod:`admissable_jax.audit.command`."""

import sys

from admissable_jax.audit.command import main

raise SystemExit(main(sys.argv[1:]))
