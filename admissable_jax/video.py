"""A video of a trained policy: nothing hidden, beside the same start with u hidden.

``python -m admissable_jax.video RUN_DIR hidden=worst out=FILE.mp4``
(``policy=FILE.npz hidden=...``: a policy ``export`` wrote, without its run)

The run's deterministic policy (:func:`~admissable_jax.policies.load_policy`) acts in
Gymnasium's own C-MuJoCo env, the client every trained policy is for: two copies reset with
the same seed, one seeing everything, one with the features of u zeroed and flagged (the
paper's m_u). The default u is the worst set of the checkpoint's own scoring (argmin_u a_u).
Frames come from MuJoCo's renderer through Gymnasium: ``MUJOCO_GL=egl`` (the default here;
a GPU, or Mesa's software EGL on a headless CPU: Debian/Ubuntu ``libegl1 libgl1-mesa-dri``)
or ``MUJOCO_GL=osmesa`` (``libosmesa6``). The file is written by imageio-ffmpeg (H.264) at
the env's real-time frame rate, whole or not at all, and records what it shows (its mp4
comment: the policy's source as ``export`` records it, u, ``fail_at``, the reset seed). A file
at ``out`` that holds another video, or no record of one, is never written over; the same
video's is (its run moved, linked or copied since, too).
"""

from __future__ import annotations

import os

os.environ.setdefault("MUJOCO_GL", "egl")  # read by MuJoCo when it is first imported

import contextlib  # noqa: E402
import dataclasses  # noqa: E402
import importlib.util  # noqa: E402
import json  # noqa: E402
import re  # noqa: E402
import subprocess  # noqa: E402
import warnings  # noqa: E402
from typing import Any, Callable, Iterator  # noqa: E402

import numpy as np  # noqa: E402

from admissable_jax.cli import parse_args, run_from_cli, run_main, setting  # noqa: E402
from admissable_jax.envs import observation_names, settotalmass_warning_dropped  # noqa: E402
from admissable_jax.errors import RunFailed, make_directory  # noqa: E402
from admissable_jax.method import check_fail_at, parse_set  # noqa: E402
from admissable_jax.run_directory import SCORING_KEYS, read_jsonl, same_policy_record  # noqa: E402

PANEL_WIDTH, PANEL_HEIGHT, LABEL_HEIGHT = 480, 352, 32  # multiples of 16, as H.264 wants


@dataclasses.dataclass
class VideoConfig:
    run_dir: str = setting("", "a train run directory or an experiment pair's (may be given first, without run_dir=)")
    policy: str = setting("", "instead of a run: a policy python -m admissable_jax.export wrote (FILE.npz), shown in its "
                              "run's Gymnasium env; name hidden= (it holds no scorings)")
    hidden: str = setting("worst", "u: feature indices or names, comma separated (e.g. 2 or 'thigh joint angle'); "
                                   "worst = argmin_u a_u of the checkpoint's scoring")
    out: str = setting("", "the .mp4 to write (default RUN_DIR/videos/step<STEP>-hidden<u>[-fail<T>][-seed<S>].mp4; "
                           "best=true: best-step<STEP>-...; policy=: videos/<its name>-hidden<u>.mp4 beside the file); "
                           "another video's file is never written over")
    step: int = setting(-1, "the checkpoint (env step); -1 = the latest")
    best: bool = setting(False, "the policy the run kept at its best scoring (best_policy.npz) instead of a checkpoint")
    seed: int = setting(0, "reset seed of the start state both sides share (the default file ends in -seed<S> where "
                           "it is not 0)")
    frames: int = setting(1000, "frames at most: the start, then one per env step (Gymnasium's episodes end at 1000 "
                                "steps, or when the agent falls; the end is then held for a second)")
    fail_at: int = setting(0, "the env step at which u's sensors fail, every feature seen before it (a sensor "
                              "that dies mid-run); 0 = hidden from the start. The default file ends in -fail<T>")


class RenderingUnavailable(RunFailed):
    """MuJoCo's renderer could not open an OpenGL context (no EGL or OSMesa)."""


def check_video_config(config: VideoConfig) -> None:
    missing = [name for name in ("imageio", "imageio_ffmpeg") if importlib.util.find_spec(name) is None]
    if missing:  # (Gymnasium's renderer imports imageio too)
        raise ValueError(f"video needs the video extra ({', '.join(missing)} not installed): pip install -e '.[video]'")
    if bool(config.run_dir) == bool(config.policy):
        raise ValueError("give the run directory, or an exported policy's file: python -m admissable_jax.video RUN_DIR "
                         "[hidden=...] [out=FILE.mp4], or policy=FILE.npz hidden=...")
    if config.policy and (config.hidden.strip() == "worst" or config.best or config.step >= 0):
        raise ValueError("an exported policy holds no scorings nor checkpoints: name the features to hide (hidden=0,3 "
                         "or hidden='thigh joint angle'; hidden= for none), without best= or step=")
    if config.best and config.step >= 0:
        raise ValueError(f"best=true shows the policy the run kept at its best scoring: give no step= (got {config.step})")
    if config.frames < 1:
        raise ValueError(f"frames must be at least 1, got {config.frames}")
    if config.seed < 0:  # (Gymnasium's reset takes none below 0)
        raise ValueError(f"seed must be >= 0, got {config.seed}")
    if config.out and not config.out.endswith(".mp4"):
        raise ValueError(f"out must be an .mp4 file, got {config.out!r}")
    check_fail_at(config.fail_at)


@dataclasses.dataclass
class Video:
    """What :func:`render_video` wrote: the file, the set, and each side's return and length."""

    path: str
    hidden: tuple[int, ...]
    hidden_names: tuple[str, ...]
    step: int
    clean_return: float
    hidden_return: float
    clean_length: int
    hidden_length: int
    frames: int


def resolve_hidden(hidden: str, env_name: str, names: list[str], scores: list[dict], step: int) -> tuple[int, ...]:
    """u from ``hidden``: ``worst`` (argmin of the scoring row at ``step``), or indices and
    feature ``names`` (env ``env_name``'s), comma separated."""
    if hidden.strip() == "worst":
        rows = [row for row in scores if row["env_steps"] == step]
        if not rows:
            raise ValueError(f"hidden=worst needs the scoring at env step {step}, which scores.jsonl does not hold; "
                             "name the features instead (hidden=0,3)")
        return tuple(parse_set(rows[-1]["argmin_set"]))
    lower = [name.lower() for name in names]
    chosen = []
    for item in (part.strip() for part in hidden.split(",") if part.strip()):
        if item.isdigit() and int(item) < len(names):
            chosen.append(int(item))
        elif item.lower() in lower:
            chosen.append(lower.index(item.lower()))
        else:
            raise ValueError(f"hidden: {item!r} is neither a feature index below {len(names)} nor a feature name of "
                             f"{env_name} ({', '.join(names[:4])}, ...; see observation_names)")
    return tuple(sorted(set(chosen)))


@dataclasses.dataclass
class _Shown:
    """What the video shows: the policy, its Gymnasium env, u, and the default file's path."""

    act: Callable[..., np.ndarray]  # policy(obs, hidden=()) -> action
    source: dict[str, Any]  # where the policy came from (ExportedPolicy.source)
    gymnasium_id: str | None
    env_name: str
    hidden: tuple[int, ...]
    names: tuple[str, ...]
    step: int
    out: str


def _shown(config: VideoConfig) -> _Shown:
    """The run's policy (:func:`~admissable_jax.policies.load_policy`) or the exported one."""
    if config.policy:
        from admissable_jax.exported_policy import ExportedPolicy

        exported = ExportedPolicy.load(config.policy)
        env_name, names = exported.source.get("env"), list(exported.observation_names)
        hidden = resolve_hidden(config.hidden, env_name, names, [], -1)
        stem = os.path.splitext(os.path.basename(config.policy))[0]
        out = os.path.join(os.path.dirname(config.policy), "videos", f"{stem}-{_file_ending(hidden, config)}")
        return _Shown(exported, exported.source, exported.source.get("gymnasium_id"), env_name, hidden,
                      tuple(names[i] for i in hidden), exported.source.get("env_steps"), out)
    from admissable_jax.policies import load_policy, requested_step

    policy = load_policy(config.run_dir, requested_step(config.step, config.best))
    train = policy.config
    scorings = read_jsonl(os.path.join(config.run_dir, "scores.jsonl"), required=SCORING_KEYS)
    names = observation_names(train.env)
    hidden = resolve_hidden(config.hidden, train.env, names, scorings, policy.step)
    best = "best-" * (policy.best_min_score is not None)
    out = os.path.join(config.run_dir, "videos", f"{best}step{policy.step}-{_file_ending(hidden, config)}")
    return _Shown(policy, policy.source, policy.trainer.env.gymnasium_id, train.env, hidden,
                  tuple(names[i] for i in hidden), policy.step, out)


def panel_titles(hidden: tuple[int, ...], names: tuple[str, ...], fail_at: int) -> list[str]:
    """The two panels' titles: nothing hidden, and u (its indices and names; from which step)."""
    failing = f" from step {fail_at}" if fail_at else ""
    indices = "{" + ",".join(map(str, hidden)) + "}"  # (as describe_set writes a set's 0/1 row)
    return ["nothing hidden", f"hidden {indices}{failing}: {', '.join(names) or 'nothing'}"]


def _file_ending(hidden: tuple[int, ...], config: VideoConfig) -> str:
    """The default file name's end: u, when its sensors fail where not at the start, and the
    reset seed where not 0 (each another video)."""
    return (f"hidden{'-'.join(map(str, hidden)) or 'none'}{f'-fail{config.fail_at}' * bool(config.fail_at)}"
            f"{f'-seed{config.seed}' * bool(config.seed)}.mp4")


def video_record(source: dict[str, Any], hidden: tuple[int, ...], config: VideoConfig) -> dict[str, Any]:
    """What a video shows, as its file records it: the policy's source, u, when u's sensors
    fail, and the reset seed of the start both sides share."""
    return {**source, "hidden": list(hidden), "fail_at": config.fail_at, "reset_seed": config.seed}


def recorded_video(path: str) -> dict[str, Any] | None:
    """The record of the video in ``path`` (its mp4 comment, :func:`render_video`), or None
    where it holds none: a video of another program, or of this one before videos recorded
    theirs, or no video."""
    import imageio_ffmpeg

    try:
        with ffmpeg_forks_quietly():
            metadata = subprocess.run([imageio_ffmpeg.get_ffmpeg_exe(), "-v", "error", "-i", path, "-f", "ffmetadata",
                                       "-"], capture_output=True, text=True, timeout=60, check=True).stdout
    except (OSError, subprocess.SubprocessError):
        return None
    comments = [line[len("comment="):] for line in metadata.splitlines() if line.startswith("comment=")]
    try:  # ffmetadata escapes =, ;, # and \ with a backslash
        record = json.loads(re.sub(r"\\(.)", r"\1", comments[0])) if comments else None
    except ValueError:
        return None
    return record if isinstance(record, dict) else None


@contextlib.contextmanager
def video_writer(path: str, fps: float, record: dict[str, Any]) -> Iterator[Any]:
    """imageio-ffmpeg's H.264 writer of ``path``, ``record`` in its mp4 comment
    (:func:`recorded_video`), closed on leaving: its own exit leaves ffmpeg running after an
    exception, to write the file on after it has been removed; ``close()`` waits for it."""
    import imageio.v2 as imageio

    comment = ["-metadata", f"comment={json.dumps(record)}"]
    with contextlib.closing(imageio.get_writer(path, fps=fps, codec="libx264", macro_block_size=16,
                                               output_params=comment)) as writer:
        yield writer


def _check_free_for(out: str, record: dict[str, Any]) -> None:
    """FileExistsError in one line where ``out`` holds a file that is not the video ``record``
    describes (another policy's, set's, failure step's or start's, or one with no record):
    never written over, as its policy's checkpoint may be gone. The same video's is, also
    from its run moved, linked or copied since."""
    if not os.path.exists(out):
        return
    earlier = recorded_video(out)
    if earlier is None:
        raise FileExistsError(f"{out} exists and holds no record of a video of this command (another program's, or "
                              "one written before videos recorded theirs): it is left as it is; give another out=")
    if not same_policy_record(earlier, record, out):
        hidden = "{" + ",".join(map(str, earlier.get("hidden", []))) + "}"
        raise FileExistsError(f"{out} holds another video ({earlier.get('run')}, env step {earlier.get('env_steps')}, "
                              f"hidden {hidden}, fail_at {earlier.get('fail_at')}, seed {earlier.get('reset_seed')}): "
                              "it is left as it is; give another out=")


def _labelled(frame: np.ndarray, text: str) -> np.ndarray:
    from PIL import Image, ImageDraw  # Pillow comes with matplotlib

    image = Image.new("RGB", (frame.shape[1], frame.shape[0] + LABEL_HEIGHT), "white")
    image.paste(Image.fromarray(frame), (0, LABEL_HEIGHT))
    ImageDraw.Draw(image).text((8, 9), text, fill="black")
    return np.asarray(image)


@contextlib.contextmanager
def ffmpeg_forks_quietly() -> Iterator[None]:
    """JAX's warning of any ``os.fork()`` silenced, and no other: imageio-ffmpeg forks only to
    exec ffmpeg (the writer's first frame; a reader, with ``os.setpgrp``), which runs no JAX thread."""
    with warnings.catch_warnings():
        warnings.filterwarnings("ignore", r"os\.fork\(\) was called", RuntimeWarning)
        yield


def render_video(config: VideoConfig) -> Video:
    """Render ``config``'s video; see the module docstring."""
    import gymnasium

    check_video_config(config)
    shown = _shown(config)
    if shown.gymnasium_id is None:
        raise ValueError(f"{shown.env_name} has no Gymnasium env to render")
    hidden, names, policy = shown.hidden, shown.names, shown.act
    out = config.out or shown.out
    record = video_record(shown.source, hidden, config)
    _check_free_for(out, record)
    make_directory(os.path.dirname(os.path.abspath(out)), "video folder")
    partial = f"{out}.partial.mp4"  # renamed over out once whole: a stop mid-way leaves out as it was

    sides = [(), hidden]
    with settotalmass_warning_dropped():
        envs = [gymnasium.make(shown.gymnasium_id, render_mode="rgb_array", width=PANEL_WIDTH,
                               height=PANEL_HEIGHT) for _ in sides]  # Gymnasium's own env: its 1000-step limit
    try:
        observations = [env.reset(seed=config.seed)[0] for env in envs]
        try:
            last = [env.render() for env in envs]
        except Exception as error:  # MuJoCo's GL errors are long and say little
            raise RenderingUnavailable(
                f"MuJoCo could not render with MUJOCO_GL={os.environ.get('MUJOCO_GL')}: {type(error).__name__}; install "
                "libegl1 and libgl1-mesa-dri (EGL), or libosmesa6 and set MUJOCO_GL=osmesa") from None
        returns, lengths, running, held = [0.0, 0.0], [0, 0], [True, True], 0
        fps = envs[0].metadata.get("render_fps", 30)
        titles = panel_titles(hidden, names, config.fail_at)
        with ffmpeg_forks_quietly(), video_writer(partial, fps, record) as writer:
            for frame in range(config.frames):
                panels = []
                for side, env in enumerate(envs):
                    state = "" if running[side] else " (episode over)"
                    text = f"{titles[side]}  |  return {returns[side]:.1f} after {lengths[side]} steps{state}"
                    panels.append(_labelled(last[side], text))
                writer.append_data(np.concatenate(panels, axis=1))
                if not any(running):  # hold the end about a second, so that its returns can be read
                    held += 1
                    if held > fps:
                        break
                    continue
                for side, env in enumerate(envs):
                    if running[side]:
                        failed = lengths[side] >= config.fail_at  # (u seen until its sensors fail)
                        action = policy(observations[side], hidden=sides[side] if failed else ())
                        observations[side], reward, terminated, truncated, _ = env.step(action)
                        returns[side] += float(reward)
                        lengths[side] += 1
                        running[side] = not (terminated or truncated)
                        last[side] = env.render()
        os.replace(partial, out)
    finally:
        for env in envs:
            env.close()
        if os.path.exists(partial):
            os.remove(partial)
    return Video(out, hidden, names, shown.step, returns[0], returns[1], lengths[0], lengths[1], frame + 1)


def main(argv: list[str]) -> int:
    config = parse_args(VideoConfig, argv, "admissable_jax.video",
                        "A video of a trained policy: nothing hidden beside the same start with u hidden.",
                        validate=check_video_config, positional="run_dir")
    video, status = run_from_cli(render_video, config, interrupted="interrupted: no video written")
    if status:
        return status
    print(f"wrote {video.path}: {video.frames} frames of step {video.step}; nothing hidden: return "
          f"{video.clean_return:.1f} in {video.clean_length} steps; hidden {list(video.hidden)}"
          f"{f' from step {config.fail_at}' if config.fail_at else ''} "
          f"({', '.join(video.hidden_names)}): return {video.hidden_return:.1f} in {video.hidden_length} steps")
    return 0


if __name__ == "__main__":
    run_main(main)
