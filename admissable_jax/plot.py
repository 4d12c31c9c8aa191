"""``python -m admissable_jax.plot RUN_DIR ... [window=40] [out=DIR]``: see :mod:`admissable_jax.plots`."""

import sys

from admissable_jax.plots import main

if __name__ == "__main__":
    raise SystemExit(main(sys.argv[1:]))
