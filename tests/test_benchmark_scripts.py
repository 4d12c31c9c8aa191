"""Every benchmark script imports and explains itself (``--help``). Most scripts are run by
hand, on a GPU lease or at a size no test affords; a name they import from the package that
moved, or a key table that no longer builds, fails here instead of on the lease."""

from __future__ import annotations

import json
import os
import subprocess
import sys

BENCHMARKS = os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "benchmarks")
IMPORTED_ONLY = {"common.py", "profile_trace.py", "toy_envs.py"}  # modules the scripts import, not commands
HELP_ARGS = {"campaign.py": ["measure", "--help"]}  # its keys follow a verb

# One process for all scripts (each imports JAX, some Brax or SciPy): the script run as
# ``__main__`` with ``--help``, its exit status (or the traceback that stopped it) and what it
# printed.
CHILD = """
import contextlib, io, json, runpy, sys, traceback
sys.path.insert(0, sys.argv[1])
results = {}
for script, args in json.loads(sys.argv[2]).items():
    sys.argv = [script, *args]
    printed, status = io.StringIO(), 0
    with contextlib.redirect_stdout(printed), contextlib.redirect_stderr(printed):
        try:
            runpy.run_path(f"{sys.path[0]}/{script}", run_name="__main__")
        except SystemExit as stop:
            status = stop.code or 0
        except Exception:  # an import that fails: the script is named with its traceback
            status = traceback.format_exc()
    results[script] = [status, printed.getvalue()]
print(json.dumps(results))
"""


def test_every_benchmark_script_imports_and_explains_itself():
    scripts = sorted(name for name in os.listdir(BENCHMARKS) if name.endswith(".py") and name not in IMPORTED_ONLY)
    assert {"sim_to_sim.py", "score_estimators.py", "step_compile.py", "brax_sac.py"} <= set(scripts)
    child = subprocess.run([sys.executable, "-c", CHILD, BENCHMARKS,
                            json.dumps({name: HELP_ARGS.get(name, ["--help"]) for name in scripts})],
                           capture_output=True, text=True, timeout=300)
    assert child.returncode == 0, child.stderr[-3000:]
    results = json.loads(child.stdout.strip().splitlines()[-1])
    for name in scripts:
        status, printed = results[name]
        assert status == 0, (name, printed[-2000:])
        # A usage line (or the docstring's own example) naming the script.
        assert f"benchmarks/{name}" in printed, (name, printed[:500])
