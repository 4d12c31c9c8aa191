"""Which MuJoCo Warp MJX runs, and its deterministic mode.

Why: a GPU run of MuJoCo Warp is not repeatable as MJX 3.17.0 ships it. Its vendored copy
(``mujoco.mjx.third_party.mujoco_warp``) gives each contact a slot and each constraint its
rows from atomic counters, and sums floats with atomics, in whatever order the GPU's threads
arrive; so two runs of one program differ in float rounding, and a run's records cannot be
re-trained bit for bit on the next machine (:mod:`admissable_jax.fast_forward`). The
``mujoco-warp`` package of the same version (3.17.0, pinned with warp-lang) has an opt-in
deterministic mode (``Option.deterministic``, a ``DeterminismType`` bitmask). Of it, 3.17.0
implements ATOMICS: the kernels it marks as summing floats or taking slots with atomics are
built in Warp's ``RUN_TO_RUN`` mode, which reduces the sums and assigns the slots in a fixed
order. CONTACTS (a stable sort of the contacts) and CONSTRAINT (canonical constraint rows)
are declared but empty (``# TODO``, in 4.0.0 too), and two passes still take slots from
atomic counters outside that mode: the collision pass (broadphase candidates, contacts) and
the constraint pass (each contact's, joint limit's and friction's rows in ``efc``, from one
counter per world); so in the GPU's order a world where two contacts or two limits are
active at once could order its rows differently from run to run, and the solver sum them in
another order. We build both passes in that mode too (:data:`_RUN_TO_RUN_PASSES`). Then, of
a Hopper or Walker2d env step's 1,840 kernel launches 776 run in ``RUN_TO_RUN`` mode (Ant:
1,064 of 2,370), and the atomics left outside it are integer sums and float ``+=`` on
elements each thread owns, neither of which depends on the threads' order
(``benchmarks/warp_atomics.py`` reads them in the code Warp generates, counted on the CPU).
Whether a GPU then repeats our runs is what ``benchmarks/repeatability.py`` measures.

MJX's Warp bridge imports MuJoCo Warp by its vendored module names when ``mujoco.mjx`` is
first imported. So :func:`use_package`, called by :mod:`.physics` and :mod:`.contact_frames`
before they import MJX, puts the package's modules under those names; MJX then runs the
package. The bridge builds every call's ``Option`` on one shared object per bridge module
(``_o``) and never sets ``deterministic``, so :func:`set_deterministic` sets it there: one
setting per process, which :func:`set_deterministic` enforces.
"""

from __future__ import annotations

import functools
import importlib
import importlib.metadata
import os
import pkgutil
import sys

VENDORED = "mujoco.mjx.third_party.mujoco_warp"
PACKAGE = "mujoco_warp"
# MJX's bridge modules that each hold a shared Option (``_o``) for their calls.
_BRIDGE_MODULES = ("forward", "smooth", "collision_driver", "bvh", "render")
_NOT_FOR_MJX = ("cli",)  # the package's command line (absl flags), which MJX never imports
# MuJoCo Warp's passes whose kernels take slots from atomic counters outside the package's
# ATOMICS mode, as (module, function), each also exported by the package: the collision pass
# (broadphase candidates, contacts) and the constraint pass (each limit's, friction's and
# contact's rows in ``efc``, from one counter per world).
_RUN_TO_RUN_PASSES = (("collision_driver", "collision"), ("constraint", "make_constraint"))
# Set to 1 to keep MJX on its own copy (then deterministic_physics=false): MuJoCo Warp as MJX
# ships it, as every GPU record before the package was measured with; a fallback should the
# package fail where the CPU cannot show it (a GPU-only code path).
OWN_COPY_VARIABLE = "ADMISSABLE_MJX_OWN_WARP"

_process_setting: bool | None = None  # the deterministic setting this process's Warp envs run with
_package_refused: str | None = None  # why use_package() kept MJX's own copy though the package is installed


def install_hint() -> str:
    """How to install the package MJX runs: the mujoco-warp release of the installed mujoco-mjx."""
    return f"pip install mujoco-warp=={importlib.metadata.version('mujoco-mjx')}, or the 'cuda' extra"


def version_mismatch() -> str | None:
    """Why the installed mujoco-warp cannot stand in for MJX's copy (another release than
    mujoco-mjx's, whose bridge calls it by that release's names), or None."""
    try:
        package, mjx = (importlib.metadata.version(name) for name in ("mujoco-warp", "mujoco-mjx"))
    except importlib.metadata.PackageNotFoundError:  # a source checkout without its metadata: nothing to compare
        return None
    return None if package == mjx else f"mujoco-warp {package} is not mujoco-mjx {mjx}'s release ({install_hint()})"


def use_package() -> bool:
    """Put the ``mujoco_warp`` package under MJX's vendored MuJoCo Warp module names, unless MJX
    has imported its own copy already, ``ADMISSABLE_MJX_OWN_WARP=1`` keeps it, or the package is
    another release than mujoco-mjx's. True when MJX runs (or will run) the package."""
    global _package_refused
    if VENDORED in sys.modules:
        return runs_package()
    if os.environ.get(OWN_COPY_VARIABLE) == "1":
        return False
    try:
        package = importlib.import_module(PACKAGE)
        source = importlib.import_module(f"{PACKAGE}._src")
    except (ImportError, RuntimeError):  # not installed, or warp-lang missing
        return False
    _package_refused = version_mismatch()
    if _package_refused:
        return False
    for module in pkgutil.iter_modules(source.__path__):
        if not module.name.endswith("_test") and module.name not in _NOT_FOR_MJX:
            importlib.import_module(f"{PACKAGE}._src.{module.name}")
    sys.modules[VENDORED] = package
    for name, module in list(sys.modules.items()):
        if name.startswith(f"{PACKAGE}._src"):
            sys.modules[VENDORED + name[len(PACKAGE):]] = module
    return True


def runs_package() -> bool:
    """Whether MJX's MuJoCo Warp is the ``mujoco_warp`` package (not MJX's vendored copy)."""
    return getattr(sys.modules.get(VENDORED), "__name__", None) == PACKAGE


def which() -> str:
    """Which MuJoCo Warp MJX runs, for records and logs."""
    return "mujoco-warp package" if runs_package() else "MJX's own copy"


def set_deterministic(deterministic: bool) -> None:
    """Run every MuJoCo Warp call of this process in deterministic mode (``DeterminismType.ALL``,
    of which 3.17.0 implements ATOMICS, and the collision and constraint passes in ``RUN_TO_RUN`` mode) or
    not. Raises ``ValueError`` (one line) when the package does not run, or when this
    process's Warp envs were already built the other way."""
    global _process_setting
    if _process_setting is not None and _process_setting != deterministic:
        raise ValueError(f"this process already steps MuJoCo Warp with deterministic_physics={_process_setting} "
                         f"(one setting per process: MJX's Warp bridge shares one Option); "
                         f"build envs with deterministic_physics={deterministic} in a process of their own")
    if deterministic and not runs_package():
        needs = _package_refused or (f"{install_hint()}; import admissable_jax before mujoco.mjx or brax; "
                                     f"{OWN_COPY_VARIABLE} unset")
        raise ValueError(f"deterministic_physics=true needs the mujoco-warp package imported before MJX ({needs}), "
                         "or deterministic_physics=false")
    if runs_package():
        from mujoco_warp._src.types import DeterminismType

        mode = DeterminismType.ALL if deterministic else DeterminismType.NONE
        for name in _BRIDGE_MODULES:
            importlib.import_module(f"mujoco.mjx.warp.{name}")._o.deterministic = mode
        if deterministic:
            _passes_run_to_run()
    _process_setting = deterministic


def _passes_run_to_run() -> None:
    """Build the kernels of MuJoCo Warp's :data:`_RUN_TO_RUN_PASSES` in Warp's ``RUN_TO_RUN``
    mode, which the package's ATOMICS mode leaves out: their slot counters are then assigned
    in a fixed order. Warp gives a kernel module the mode ``warp.config.deterministic`` holds
    when it is created, and each pass creates its kernels (each in a module of its own) on
    its first call; so that call, and every later one, runs with the mode set. Idempotent."""
    import warp

    for module_name, function_name in _RUN_TO_RUN_PASSES:
        module = importlib.import_module(f"{PACKAGE}._src.{module_name}")
        function = getattr(module, function_name)
        if getattr(function, "run_to_run", False):
            continue

        @functools.wraps(function)
        def run_to_run(*args, _function=function, **kwargs):
            before = warp.config.deterministic
            warp.config.deterministic = warp.DeterministicMode.RUN_TO_RUN
            try:
                return _function(*args, **kwargs)
            finally:
                warp.config.deterministic = before

        run_to_run.run_to_run = True
        setattr(module, function_name, run_to_run)  # what the step's forward calls
        setattr(sys.modules[PACKAGE], function_name, run_to_run)  # what MJX's bridge calls by the package's name
