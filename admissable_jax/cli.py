"""``key=value`` command lines parsed into typed dataclass configs (OmegaConf).

Every entry point (``python -m admissable_jax.<tool> key=value ...``) goes through
:func:`parse_args`: ``--help`` lists every key with its type and default, and an unknown
key or a badly typed value ends the program with a one-line message and exit status 2.
"""

from __future__ import annotations

import concurrent.futures
import contextlib
import dataclasses
import difflib
import gc
import math
import os
import signal
import sys
import threading
import time
from typing import Any, Callable, Iterable, NoReturn, TypeVar

from omegaconf import DictConfig, OmegaConf
from omegaconf.errors import OmegaConfBaseException
from tqdm import auto as tqdm_auto
from tqdm.auto import tqdm

from admissable_jax.errors import BROKEN_PIPE, INTERRUPTED, USAGE_ERROR, RunFailed

ConfigT = TypeVar("ConfigT")
T = TypeVar("T")


def setting(default, help_text: str):
    """A config dataclass field with the line ``--help`` prints for it."""
    return dataclasses.field(default=default, metadata={"help": help_text})


def _type_name(field: dataclasses.Field) -> str:
    return getattr(field.type, "__name__", str(field.type))


@dataclasses.dataclass(frozen=True)
class ConfigFile:
    """What ``config=FILE`` may set for a command: the file's keys in ``taken`` are defaults
    that ``key=value`` items override; those in ``skipped`` say which run the file came from
    (``out``, ``resume``, another command's own keys) and are left out, in one line; any
    other key in the file is an error. ``resumed`` names the settings file of the run a
    ``resume=true`` command continues (its ``config.yaml``), read as ``config=`` is when the
    command gives none, less :data:`PER_INVOCATION`; ``holds_checkpoint``, whether that run
    has a checkpoint to continue from, decides ``resume=auto``."""

    taken: frozenset[str]
    skipped: frozenset[str]
    resumed: Callable[[Any], str] | None = None
    holds_checkpoint: Callable[[Any], bool] | None = None


def help_text(config_cls: type, program: str, summary: str, config_file: ConfigFile | None = None) -> str:
    """Usage line, summary and one line per key: name, type, default and description.
    ``program`` is a module (``admissable_jax.train``: ``python -m``) or a script's path
    (``benchmarks/campaign.py plan``: ``python``)."""
    runner = "python" if program.split()[0].endswith(".py") else "python -m"
    lines = [f"usage: {runner} {program} [key=value ...]", "", summary, "", "keys:"]
    defaults = config_cls()
    for field in dataclasses.fields(config_cls):
        default = getattr(defaults, field.name)
        doc = field.metadata.get("help", "")
        setting = f"{field.name}={default}"
        lines.append(f"  {setting:<28} ({_type_name(field)}) {doc}")
    if config_file is not None:
        lines.append(f"  {'config=FILE':<28} (str) take the keys from a YAML file (a run's config.yaml, an experiment's "
                     f"experiment.yaml, your own); key=value items override them; never {', '.join(sorted(RUN_LOCATION))}")
    return "\n".join(lines)


# Keys that say where a run is and whether it continues: never taken from a config file.
RUN_LOCATION = ("out", "resume", "resume_step", "fast_forward")
# Keys of a resumed run's settings that belong to the invocation and machine that wrote them,
# not to the run: its wall-time budget, progress bar and budget-only look, and the devices,
# scoring envs and physics pieces sized for that machine.
PER_INVOCATION = ("time_limit", "progress", "budget_only", "devices", "score_envs", "worlds_per_call")


def check_at_least_one(config: Any, names: tuple[str, ...]) -> None:
    """ValueError in one line for the first of ``config``'s counts ``names`` below 1 (a
    ``validate`` of :func:`parse_args` calls it for its own counts)."""
    for name in names:
        if getattr(config, name) < 1:
            raise ValueError(f"{name} must be >= 1, got {getattr(config, name)}")


def parse_args(
    config_cls: type[ConfigT],
    argv: list[str],
    program: str,
    summary: str,
    validate: Callable[[ConfigT], None] | None = None,
    positional: str | None = None,
    config_file: ConfigFile | None = None,
) -> ConfigT:
    """The config given by ``argv`` (``key=value`` items) over ``config_cls``'s defaults.

    With ``positional``, a first item without ``=`` is that key's value
    (``python -m admissable_jax.video RUN_DIR ...``). With ``config_file``, a ``config=FILE``
    item sets the file's keys between the defaults and the other items; without one, a
    ``resume=true`` command reads the resumed run's own settings file the same way
    (``ConfigFile.resumed``), so that ``resume=true out=DIR`` needs no other key. Exits with status 0
    after printing help for ``-h``/``--help``, and with status 2 and a one-line message on
    stderr for anything malformed, unknown, mistyped or rejected by ``validate`` (which
    raises ``ValueError``/``TypeError``).
    """
    if any(arg in ("-h", "--help") for arg in argv):
        print(help_text(config_cls, program, summary, config_file))
        raise SystemExit(0)
    if positional is not None and argv and "=" not in argv[0]:
        argv = [f"{positional}={argv[0]}", *argv[1:]]
    malformed = [arg for arg in argv if "=" not in arg or arg.startswith("=")]
    if malformed:
        fail(f"expected key=value, got {malformed[0]!r} (see --help)")
    schema = OmegaConf.structured(config_cls)
    int_keys = {field.name for field in dataclasses.fields(config_cls) if field.type in (int, "int")}
    files: list[str] = []
    if config_file is not None:
        files = [arg.split("=", 1)[1] for arg in argv if arg.startswith("config=")]
        argv = [arg for arg in argv if not arg.startswith("config=")]
        if len(files) > 1:
            fail(f"config= given {len(files)} times; give one file and override its keys with key=value")
        if files:
            schema = _with_config_file(schema, files[0], config_file, int_keys)
        argv = _decide_auto_resume(schema, argv, int_keys, config_file)
    config = _config_of(schema, argv, int_keys)
    resumed = None if files or config_file is None else _resumed_settings(config, config_file)
    if resumed is not None:
        run_only = dataclasses.replace(config_file, taken=config_file.taken - set(PER_INVOCATION),
                                       skipped=config_file.skipped | set(PER_INVOCATION))
        schema = _with_config_file(schema, resumed, run_only, int_keys, resumed=True)
        report(f"resume=true: the run's settings from {resumed}; keys given here override them")
        config = _config_of(schema, argv, int_keys)
    if validate is not None:
        try:
            validate(config)
        except (ValueError, TypeError) as error:
            fail(str(error))
    return config


def _decide_auto_resume(schema: Any, argv: list[str], int_keys: set[str], config_file: ConfigFile) -> list[str]:
    """``argv`` with a last ``resume=auto`` decided, said in one line: ``resume=true`` where the
    run the command names (its ``out``) holds a checkpoint; with ``fast_forward=true`` also where
    it holds only its records (its settings file: checkpoints on a node's own disk, lost when
    the job moved), which the run is rebuilt from; else ``resume=false`` (and no fast-forward:
    nothing to rebuild). So a job that a scheduler starts again after a time limit or a
    preemption is one unchanging command: the first start trains from scratch, every later one
    continues (a run that stopped before its first checkpoint starts over, its rows set aside)."""
    resumes = [arg.split("=", 1)[1] for arg in argv if arg.split("=", 1)[0] == "resume"]
    if not resumes or resumes[-1] != "auto" or config_file.holds_checkpoint is None:
        return argv
    rest = [arg for arg in argv if arg.split("=", 1)[0] != "resume"]
    config = _config_of(schema, rest, int_keys)
    try:
        settings, checkpointed = config_file.resumed(config), config_file.holds_checkpoint(config)
    except ValueError:  # no run to find (an unknown env): left for validate to say
        return [*rest, "resume=false"]
    rebuilt = not checkpointed and config.fast_forward and os.path.isfile(settings)
    run = os.path.dirname(settings)
    if checkpointed or rebuilt:
        report(f"resume=auto: {run} holds {'a checkpoint' if checkpointed else 'records and no checkpoint'}: resume=true")
        return [*rest, "resume=true"]
    report(f"resume=auto: {run} holds no checkpoint{' and no records' * config.fast_forward}: resume=false"
           + " (fast_forward=false: nothing to rebuild)" * config.fast_forward)
    return [*rest, "resume=false", "fast_forward=false"]


def _resumed_settings(config: Any, config_file: ConfigFile) -> str | None:
    """The settings file of the run a ``resume=true`` command continues, where it exists
    (none for another command, or where there is no run: the resume says so)."""
    if config_file.resumed is None or not getattr(config, "resume", False):
        return None
    try:
        path = config_file.resumed(config)
    except ValueError:  # no run to find (an unknown env): left for validate to say
        return None
    return path if os.path.isfile(path) else None


def _with_config_file(schema: Any, path: str, config_file: ConfigFile, int_keys: set[str], resumed: bool = False) -> Any:
    """``schema`` with the keys the settings file ``path`` sets as its defaults (``resumed``:
    the resumed run's own, see :func:`_read_config_file`)."""
    try:
        from_file = _whole_numbers_as_ints(_read_config_file(path, config_file, resumed), int_keys)
        return OmegaConf.merge(schema, OmegaConf.create(from_file))
    except OmegaConfBaseException as error:
        fail(f"in {_file_label(path, resumed)}: {_one_line(error, schema.keys())}")


def _file_label(path: str, resumed: bool) -> str:
    """How an error names a settings file: ``config=FILE`` as the command gave it, or the
    resumed run's own file by its path."""
    return path if resumed else f"config={path}"


def _config_of(schema: Any, argv: list[str], int_keys: set[str]) -> Any:
    """The dataclass of ``schema`` with the ``key=value`` items ``argv`` set; exit 2 in one
    line for an unknown key or a mistyped value."""
    try:
        overrides = _whole_numbers_as_ints(OmegaConf.to_container(_read_items(argv)), int_keys)
        return OmegaConf.to_object(OmegaConf.merge(schema, OmegaConf.create(overrides)))
    except OmegaConfBaseException as error:
        fail(_one_line(error, schema.keys()))


def _read_items(argv: list[str]) -> Any:
    """OmegaConf's reading of ``key=value`` items, each value read as YAML, ``key=`` (or blanks
    after ``=``) as the empty string (OmegaConf would read None, which no key accepts); one
    line and exit 2 naming an item whose value YAML cannot read (``hidden=[1``, ``modes=,``,
    ``out=@home``), where YAML's own error would end the command in a traceback, or reads as
    a mapping (``env=toy_envs:``, where every key takes a number, a flag or a text)."""
    import yaml

    items = OmegaConf.create()
    for arg in argv:
        key, value = arg.split("=", 1)
        if not value.strip():
            arg = f"{key}=''"
        quoted = f"(to pass it as text, quote it: {key}=\"'{value}'\")"
        try:
            items.merge_with_dotlist([arg])
        except yaml.YAMLError as error:
            fail(f"cannot read {arg!r}{yaml_problem(error, with_line=False)} {quoted}")
        if isinstance(items.get(key), DictConfig):
            fail(f"cannot read {arg!r}: YAML reads {value!r} as a mapping {quoted}")
    return items


def _whole_numbers_as_ints(items: dict[str, Any], int_keys: set[str]) -> dict[str, Any]:
    """``items`` with each int key's whole number written as a float taken as that int:
    ``total_steps=1e6`` (OmegaConf reads a float) or ``total_steps: 1e6`` in YAML (a string),
    as researchers write step counts. Anything else is left for OmegaConf to refuse."""

    def as_int(value: Any) -> Any:
        if isinstance(value, (bool, int)):
            return value
        try:
            number = float(value)
        except (TypeError, ValueError):
            return value
        return int(number) if math.isfinite(number) and number.is_integer() else value

    return {key: as_int(value) if key in int_keys else value for key, value in items.items()}


def _read_config_file(path: str, config_file: ConfigFile, resumed: bool = False) -> dict[str, Any]:
    """The keys ``config=path`` sets (see :class:`ConfigFile`); one line and exit 2 for a
    file that is missing, not YAML, not a mapping, or holds a key no command takes. The keys
    left out are said in one line, but for the resumed run's own file (``resumed``), whose
    keys of another run or invocation are left out as a matter of course."""
    import yaml

    label = _file_label(path, resumed)
    try:
        with open(path) as file:
            loaded = yaml.safe_load(file)
    except OSError as error:
        fail(f"cannot read {label}: {error.strerror or error}")
    except yaml.YAMLError as error:
        fail(f"{label} is not valid YAML{yaml_problem(error)}")
    if not isinstance(loaded, dict):
        fail(f"{label} must hold key: value lines, got {type(loaded).__name__}")
    unknown = sorted(str(key) for key in loaded if key not in config_file.taken | config_file.skipped)
    if unknown:
        fail(unknown_key(unknown[0], config_file.taken | config_file.skipped, f" in {label}"))
    skipped = sorted(key for key in loaded if key in config_file.skipped)
    if skipped and not resumed:
        report(f"config={path}: {', '.join(skipped)} not taken from it (they say which run it came from)")
    return {key: value for key, value in loaded.items() if key in config_file.taken}


def yaml_problem(error: Exception, with_line: bool = True) -> str:
    """A YAML parse error in one line: `` (line L): <problem>`` (``: <problem>`` without the
    line, for a one-line text)."""
    where = getattr(error, "problem_mark", None) if with_line else None
    line = f" (line {where.line + 1})" if where is not None else ""
    return f"{line}: {getattr(error, 'problem', None) or str(error).splitlines()[0]}"


# Names a researcher may bring from the paper (ζ, l) or other trainers, and our keys for them.
OTHER_NAMES = {"lr": "learning_rate", "zeta": "score_every", "l": "lower_bound", "steps": "total_steps"}


def unknown_key(key: str, keys: Iterable[str], where: str = "") -> str:
    """The error for a key no command takes, naming the valid keys closest to it: a typo,
    another tool's spelling (``n_episodes`` for ``episodes``) or name (:data:`OTHER_NAMES`)."""
    keys = sorted(keys)
    close = [OTHER_NAMES[key]] if OTHER_NAMES.get(key) in keys else difflib.get_close_matches(key, keys, 2, 0.7)
    guess = f"did you mean {' or '.join(close)}? " if close else ""
    return f"unknown key {key!r}{where} ({guess}see --help for the valid keys)"


def _one_line(error: OmegaConfBaseException, keys: Iterable[str]) -> str:
    """OmegaConf's error in one line, ``keys`` being those the command takes."""
    message = str(error).strip().splitlines()[0]
    key = getattr(error, "full_key", None)
    if "not in struct" in message or "Key '" in message and "not" in message:
        return unknown_key(str(key), keys)
    return f"bad value for {key!r}: {message}" if key else message


def run_from_cli(function: Callable[[Any], Any], config: Any,
                 interrupted: str = "interrupted before training started; nothing to resume from") -> tuple[Any, int]:
    """(result, exit status) of ``function(config)`` for a command line: bad settings (and a
    missing input file or directory) exit 2;
    a run that fails (:class:`~admissable_jax.errors.RunFailed`: a corrupt checkpoint, a
    diverged run, one too large for memory or for the physics buffers, an unusable run
    directory, Ctrl-C) exits with its own status; each prints one line on stderr, and
    finished work stays in the run directory. SIGTERM (a job scheduler's stop, ``kill``)
    is taken as Ctrl-C, so the run ends the same way: its lock released, its loggers closed.
    A Ctrl-C that reaches this function (a training loop says more itself) prints
    ``interrupted``: what the command leaves behind."""
    with _sigterm_as_ctrl_c():
        try:
            return function(config), 0
        except (ValueError, TypeError, FileExistsError, FileNotFoundError) as error:
            print(f"error: {error}", file=sys.stderr)
            return None, USAGE_ERROR
        except RunFailed as error:
            print(f"{error.label}: {error}", file=sys.stderr)
            return None, error.exit_status
        except KeyboardInterrupt:
            print(interrupted, file=sys.stderr)
            return None, INTERRUPTED


def in_background(call: Callable[[], T]) -> concurrent.futures.Future[T]:
    """``call()`` started on a thread of its own, for long work that a Ctrl-C should not have
    to wait for (a compile): Python hears signals in the main thread only, and not inside a
    long C call, so the main thread waits on the future instead, where a Ctrl-C raises
    KeyboardInterrupt at once. The work goes on; a command then ends at once
    (:func:`exit_with`), while a Python caller's process waits for it before exiting."""
    pool = concurrent.futures.ThreadPoolExecutor(max_workers=1)
    try:
        return pool.submit(call)
    finally:
        pool.shutdown(wait=False)


def compiled_in_background(lowered: Any) -> Any:
    """``lowered.compile()`` (a ``jax.stages.Lowered``) on a worker thread (:func:`in_background`),
    waited for where a Ctrl-C is heard: it raises KeyboardInterrupt at once, and the compile
    goes on in the background. XLA stops a compile on the main thread when a Ctrl-C comes,
    after which the process crashed at exit (SIGSEGV, the audit: 5 of 5 tries)."""
    return in_background(lowered.compile).result()


def exit_with(status: int) -> NoReturn:
    """End a command with ``status``; by then everything the command writes is written and
    closed. An interrupted command (a second Ctrl-C) can leave device work it queued still
    running, and Python's own exit would wait for it: freeing the arrays that work writes
    blocks until it ends (37 s on a 2-core CPU, two Hopper pairs: ``benchmarks/stop_latency.py
    second=5``), so it ends at once, with its output flushed. Any other exit is Python's
    (atexit handlers run, buffers are flushed) with every object frozen, so that its garbage
    collections skip them: a short Hopper run's exit took 2.20 s on a 2-core CPU before, 0.30 s
    frozen (``benchmarks/startup_time.py run=...``)."""
    if status == INTERRUPTED:
        sys.stdout.flush()
        sys.stderr.flush()
        os._exit(status)
    gc.freeze()
    raise SystemExit(status)


def run_main(main: Callable[[list[str]], int]) -> NoReturn:
    """A command's ``python -m`` start: ``main`` on the process's arguments, ended by
    :func:`exit_with`. Output piped into a reader that stopped early (``status runs | head``,
    over 64 KB) ends the command quietly with the shell's SIGPIPE status, as Unix tools do,
    not with a traceback."""
    try:
        status = main(sys.argv[1:])
    except BrokenPipeError:
        status = BROKEN_PIPE
    exit_with(status)


@contextlib.contextmanager
def _signals_handled_by(handler, numbers: tuple[signal.Signals, ...]):
    """While inside, ``handler`` takes the signals ``numbers``, in the main thread only
    (signals reach no other; elsewhere nothing changes); the previous handlers come back after."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    previous = {number: signal.signal(number, handler) for number in numbers}
    try:
        yield
    finally:
        for number, earlier in previous.items():
            signal.signal(number, earlier)


def _sigterm_as_ctrl_c():
    """While inside, SIGTERM raises KeyboardInterrupt in the main thread."""

    def interrupt(signum, frame):
        raise KeyboardInterrupt

    return _signals_handled_by(interrupt, (signal.SIGTERM,))


@dataclasses.dataclass
class StopRequest:
    """Set by the first Ctrl-C or SIGTERM inside :func:`stop_at_next_boundary`."""

    requested: bool = False


@contextlib.contextmanager
def stop_at_next_boundary(where: str):
    """While inside, the first Ctrl-C or SIGTERM (a scheduler's stop) only sets the request
    it yields and says on stderr that the loop stops ``where``; a second raises
    KeyboardInterrupt at once. A loop whose jitted steps donate their state can save it only
    between steps, so this is how it keeps the interval it was running. In the main thread
    only (signals reach no other): elsewhere nothing is deferred."""
    request = StopRequest()

    def defer(signum, frame):
        if request.requested:
            raise KeyboardInterrupt
        request.requested = True
        report(f"{signal.Signals(signum).name}: stopping {where}; press Ctrl-C again to stop now")

    with _signals_handled_by(defer, (signal.SIGINT, signal.SIGTERM)):
        yield request


def enable_compilation_cache() -> None:
    """Keep compiled XLA programs in ``~/.cache/admissable_jax/jax_cache`` (outside any repo)
    unless ``JAX_COMPILATION_CACHE_DIR`` says otherwise: MJX programs take a minute to build.
    Those that compile in under a second are not kept, unless
    ``JAX_PERSISTENT_CACHE_MIN_COMPILE_TIME_SECS`` says otherwise."""
    import jax

    default = os.path.join(os.path.expanduser("~"), ".cache", "admissable_jax", "jax_cache")
    jax.config.update("jax_compilation_cache_dir", os.environ.get("JAX_COMPILATION_CACHE_DIR", default))
    if "JAX_PERSISTENT_CACHE_MIN_COMPILE_TIME_SECS" not in os.environ:  # else JAX has read it already
        jax.config.update("jax_persistent_cache_min_compile_time_secs", 1.0)


def fail(message: str) -> None:
    """Print ``error: message`` on one line to stderr and exit with status 2."""
    print(f"error: {message}", file=sys.stderr)
    raise SystemExit(USAGE_ERROR)


def report(message: str) -> None:
    """A status line on stderr, with or without a progress bar."""
    tqdm.write(message, file=sys.stderr)


class PacedProgress:
    """A bar (tqdm's, or :class:`LogLines`) whose rate, and so the time it says is left, is
    the ``pace`` its owner sets (units per second; 0: not known yet, shown as '?'), where the
    mean since the command began misleads: a training run's random-action warm-up runs far
    faster than SAC's intervals, and its first scoring rounds, of short episodes, are shorter
    than its later ones. Unset (None), tqdm's own mean."""

    pace: float | None = None

    @property
    def format_dict(self) -> dict[str, Any]:
        values = super().format_dict
        if self.pace is not None:
            values["rate"] = self.pace
        return values


class PacedBar(PacedProgress, tqdm):
    """tqdm's bar (on a terminal, or a notebook's widget) with :class:`PacedProgress`'s rate."""


class LogLines(PacedProgress, tqdm):
    """Progress where stderr is no terminal (a batch job's log file, a pipe): not a bar
    redrawn in place, whose carriage returns would make a long run's log one line of
    megabytes, but a line of its own each time the scores are set (training: every scoring)
    and, with ``every`` > 0, as it moves, at most once per ``every`` seconds and once at its
    end (an audit's episodes): how far, the time spent and left at this command's pace, and
    the scores. A redraw (:func:`ticking`'s clock) after ``HEARTBEAT`` seconds without a
    line writes one anyway, naming what runs (``still scoring: ...``), so that a job's log
    shows the run alive through a scoring round of many minutes (an untrained Ant's on a CPU:
    1,060 episodes of 1,000 steps)."""

    LINE = ("{{n:,}} of {{total:,}} {what} ({{percentage:.0f}}%), {{elapsed}} elapsed, about {{remaining}} left at "
            "{{rate_fmt}}{{postfix}}")
    HEARTBEAT = 600.0

    def __init__(self, what: str, every: float = 0.0, **kwargs):
        self.lined_at = time.monotonic()  # before tqdm's first redraw
        super().__init__(bar_format=self.LINE.format(what=what), **kwargs)
        self.sp = None  # nothing is drawn, so close() has nothing to finish off
        self.every, self.lined_n = every, self.n

    def display(self, msg: str | None = None, pos: int | None = None) -> bool:
        """A redraw (tqdm's, under its lock): nothing is drawn but the heartbeat's line."""
        if msg is None and pos is None and time.monotonic() - self.lined_at >= self.HEARTBEAT:
            self.write_line(f"still {self.desc}: " if self.desc else "")
        return True

    def clear(self, nolock: bool = False) -> None:
        """Nothing is drawn, so nothing to clear (``tqdm.write`` clears every bar first: a '\\r' in the log)."""

    def update(self, n: float = 1) -> bool | None:
        moved = super().update(n)
        if self.every and time.monotonic() - self.lined_at >= self.every:
            self.write_line()
        return moved

    def set_postfix(self, ordered_dict=None, refresh: bool = True, **kwargs) -> None:
        super().set_postfix(ordered_dict, refresh=False, **kwargs)
        self.write_line()

    def close(self) -> None:
        if self.every and self.n != self.lined_n:
            self.write_line()
        super().close()

    def write_line(self, prefix: str = "") -> None:
        if not self.disable:
            self.fp.write(f"{prefix}{self}\n")
            self.fp.flush()
            self.lined_at, self.lined_n = time.monotonic(), self.n


def progress_bar(what: str, every: float = 0.0, **kwargs) -> PacedBar | LogLines:
    """A bar for long work over ``what`` (tqdm's keywords): tqdm's, redrawn in place, on a
    terminal and in a notebook's widget; elsewhere :class:`LogLines`. Either takes a
    ``pace`` (:class:`PacedProgress`)."""
    drawn_in_place = sys.stderr.isatty() or tqdm_auto.notebook_tqdm is not tqdm_auto.std_tqdm
    return PacedBar(**kwargs) if drawn_in_place else LogLines(what, every, **kwargs)


@contextlib.contextmanager
def ticking(bar: tqdm, seconds: float | None = None):
    """While inside, redraw ``bar`` every ``seconds`` (1 on a terminal, else 30), so that its
    clock runs on through device calls that advance nothing (a scoring round: minutes on a CPU)."""
    if bar.disable:
        yield
        return
    seconds = seconds or (1.0 if sys.stderr.isatty() else 30.0)
    stop = threading.Event()

    def tick():
        while not stop.wait(seconds):
            bar.refresh()

    ticker = threading.Thread(target=tick, name="progress-bar-clock", daemon=True)
    ticker.start()
    try:
        yield
    finally:
        stop.set()
        ticker.join()


@contextlib.contextmanager
def reporting(what: str):
    """Say what is about to happen (long work: a compile, a rollout), then how long it took."""
    report(f"{what}...")
    started = time.perf_counter()
    yield
    report(f"{what}: done in {time.perf_counter() - started:.1f} s")
