"""The GPU campaign's packages, packed so that each of its first two device calls fits one transfer.

    python benchmarks/device_pack.py [pack=true] [margin_mb=0.25]

``../shared/device/pack.sh`` packs what a device machine lacks into ``.dev/a`` (the wheels and
warp-lang's first part, 60 MB) and ``.dev/b`` (warp-lang's rest, 64.1 MB on 2026-12-03). A
device call carries the working tree as well, and tree and carried folders together may
not pass 64 MiB (67.1 MB). With the 5.0 MB tree of 2026-12-03 the second call would carry
69.1 MB, and the device would refuse it with the machine already started by the first.

So this runs ``pack.sh`` (keeping ``.dev/kernels``, which ``pack.sh`` deletes with the rest
of ``.dev``), repacks warp-lang without its test suite (never imported at run time) at
``xz -9e`` (79.4 MB instead of 84.2), and splits it anew: warp-lang's first part fills the
first call (``.dev/a``) up to the limit less the tree and ``margin_mb`` (every size as a tar
archive of the files would take it: :func:`archived_bytes`), and the rest goes in ``.dev/b``,
which the second call carries with ``.dev/kernels``. The kernels go second because the second
call starts the campaign's worker, which unpacks them: a device call's carried folders do not
stay for the next call (the H200 lease of 2026-12-04 carried them first, and its worker found
none). ``pack.sh``'s own
``stage.sh`` and ``finish.sh`` join the two parts as before. It adds the wheels ``pack.sh``'s
list lacks (:data:`EXTRA_WHEELS`: mujoco-warp, 2.3 MB), which ``stage.sh`` installs with the
rest. Of ``pack.sh``'s wheels it leaves out
those that only MuJoCo's viewer and renderer and Brax's web viewer import
(:data:`LEFT_OUT_WHEELS`: 3.8 MB, pyopengl's 3.2 MB the most): MuJoCo imports its renderer
in a ``try``, and no campaign step renders. From the wheels it keeps it drops the folders no
step reads (:data:`UNUSED_IN_WHEELS`: MuJoCo's experimental apps, MJX's and MuJoCo Warp's test
data; 23.9 MB). ``tests/test_hopper_pipelines.py`` runs the campaign's smoke chain with those
modules unimportable (:data:`LEFT_OUT_MODULES`). When the two calls cannot hold
it all, it says by how much in one line and exits 2, before any device time is spent.

It writes what it packed to ``benchmarks/results/device_pack.json``; ``tests/test_device_pack.py``
checks from that record that the tree as committed still leaves room for the packs.
``pack=false`` repacks and splits the ``.dev`` there is (after ``warp_kernels.py`` rebuilt the
kernels, say) without downloading again.
"""

from __future__ import annotations

import dataclasses
import datetime
import json
import os
import shlex
import shutil
import subprocess
import sys
import tempfile
import tomllib
import zipfile

TRANSFER_LIMIT = 64 * 2**20  # bytes one device call may carry: the working tree and its carried folders
FIRST_PART, REST = "a/warp.part0", "b/warp.part1"  # pack.sh's names, which its stage.sh and finish.sh join
KERNELS = "kernels"  # benchmarks/warp_kernels.py's archive, carried with .dev/b by the call that starts the worker
UNUSED_AT_RUN_TIME = ("warp/tests",)
# Folders of pack.sh's wheels that no campaign step reads: MuJoCo's experimental apps (MuJoCo
# Studio and its GUI libraries, 15.8 MB of the mujoco wheel's 26.7 MB) and the test data of
# MJX (6.5 MB of its 7.3 MB) and of MuJoCo Warp (1.6 MB): 23.9 MB on 2026-12-07, which the
# tree may then take (it had grown to within 0.17 MB of the room the packs left).
UNUSED_IN_WHEELS = ("mujoco/experimental/", "mujoco/mjx/test_data/", "mujoco_warp/test_data/")
REPO = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


def _cuda_extra_pins(*names: str) -> tuple[str, ...]:
    """The pyproject.toml 'cuda' extra's requirements of these distributions, as pinned there."""
    with open(os.path.join(REPO, "pyproject.toml"), "rb") as file:
        extra = tomllib.load(file)["project"]["optional-dependencies"]["cuda"]
    return tuple(requirement for requirement in extra if requirement.split("==")[0] in names)


# Wheels the campaign needs that pack.sh's default list lacks, added to its .dev/a/whl:
# MuJoCo Warp's own package, for its deterministic mode (envs/warp_package.py).
EXTRA_WHEELS = _cuda_extra_pins("mujoco-warp")
# pack.sh's wheels no campaign step imports, by distribution name (as in a wheel's file name,
# lower case) and the top-level module each installs.
LEFT_OUT_WHEELS = {"pyopengl": "OpenGL", "glfw": "glfw", "flask": "flask", "flask_cors": "flask_cors",
                   "websockets": "websockets"}
# The modules a device lacks: those of the wheels left out, and MuJoCo's experimental apps.
LEFT_OUT_MODULES = (*LEFT_OUT_WHEELS.values(), "mujoco.experimental")
BLOCK, ARCHIVE_END = 512, 10240  # tar's block, and the most its end takes
RECORD = os.path.join(REPO, "benchmarks", "results", "device_pack.json")


@dataclasses.dataclass
class DevicePackConfig:
    pack: bool = dataclasses.field(default=True, metadata={"help": "run ../shared/device/pack.sh first (downloads)"})
    margin_mb: float = dataclasses.field(default=0.25, metadata={"help": "MB left free in each call"})


def _validate(config: DevicePackConfig) -> None:
    if not 0 <= config.margin_mb < 10:
        raise ValueError(f"margin_mb must be in [0, 10), got {config.margin_mb}")


def entry_bytes(name: str, size: int) -> int:
    """What one file (or, with size 0, a folder) takes in a tar archive: a 512-byte header
    (two more blocks for a name of over 99 characters) and its data in 512-byte blocks."""
    return BLOCK * (1 + (2 if len(name) > 99 else 0) + -(-size // BLOCK))


def archived_bytes(root: str, files: list[str]) -> int:
    """The tar entries of ``files`` (paths relative to ``root``) and of the folders that hold them.

    How the device counts what a call carries is not written down; a tar archive's size
    bounds the plain bytes and any compressed form, so the packs are sized by it."""
    folders = set()
    for name in files:
        folder = os.path.dirname(name)
        while folder and folder not in folders:
            folders.add(folder)
            folder = os.path.dirname(folder)
    return (sum(entry_bytes(name, os.lstat(os.path.join(root, name)).st_size) for name in files)
            + sum(entry_bytes(folder + "/", 0) for folder in folders))


def folder_bytes(path: str, root: str = REPO) -> int:
    """:func:`archived_bytes` of a folder under ``root`` (0 where it does not exist)."""
    return archived_bytes(root, [os.path.relpath(os.path.join(folder, name), root)
                                 for folder, _, names in os.walk(path) for name in names])


def tree_bytes(repo: str = REPO) -> int:
    """:func:`archived_bytes` of the working tree a device call takes: tracked files and
    untracked ones git does not ignore."""
    listed = subprocess.run(["git", "ls-files", "-z", "--cached", "--others", "--exclude-standard"], cwd=repo,
                            capture_output=True, check=True).stdout.split(b"\0")
    return archived_bytes(repo, sorted({os.fsdecode(name) for name in listed
                                        if name and os.path.lexists(os.path.join(repo, os.fsdecode(name)))}))


@dataclasses.dataclass(frozen=True)
class Payload:
    """What the first two device calls carry besides the tree, as archived bytes."""

    first_call_fixed: int  # .dev/a without warp-lang's first part
    second_call_fixed: int  # .dev/b without warp-lang's rest, and .dev/kernels
    warp: int  # warp-lang's archive, both parts (plain bytes)


def _usable(margin: int) -> int:
    """A call's bytes for its entries: the limit less the margin and a tar archive's end (two
    zero blocks, padded to tar's 10,240-byte record)."""
    return TRANSFER_LIMIT - margin - ARCHIVE_END


def room_for_tree(payload: Payload, margin: int) -> int:
    """The largest tree with which both calls fit: each carries the tree, and together they carry
    the payload (the two parts' entries take at most 4 blocks more than warp-lang's archive)."""
    both = 2 * _usable(margin) - payload.first_call_fixed - payload.second_call_fixed - payload.warp - 4 * BLOCK
    first_alone = _usable(margin) - payload.first_call_fixed - BLOCK
    return min(both // 2, first_alone)


def split_point(payload: Payload, tree: int, margin: int) -> int:
    """Bytes of warp-lang's archive in the first call: as many as fit, so the second carries the least.

    Raises ``ValueError`` (one line, by how much) when the two calls cannot hold everything.
    """
    room = room_for_tree(payload, margin)
    if tree > room:
        raise ValueError(f"the working tree ({tree / 1e6:.2f} MB) leaves too little room for the device packs: "
                         f"both calls fit with a tree of at most {room / 1e6:.2f} MB; commit less (or smaller) results")
    first_part_entry = _usable(margin) - tree - payload.first_call_fixed
    return min(payload.warp, (first_part_entry // BLOCK - 1) * BLOCK)


def _bash(command: str, stdout=None) -> None:
    subprocess.run(["bash", "-o", "pipefail", "-c", command], stdout=stdout, check=True)


def slim_warp(dev: str, scratch: str) -> str:
    """warp-lang's archive from ``pack.sh``'s two parts, without what it never imports at run time, at ``xz -9e``.

    Parts already slimmed (a second run) are joined as they are.
    """
    parts = " ".join(shlex.quote(os.path.join(dev, part)) for part in (FIRST_PART, REST))
    unpacked = os.path.join(scratch, "warp")
    os.makedirs(unpacked)
    _bash(f"cat {parts} | xz -d | tar -x -C {shlex.quote(unpacked)}")
    archive = os.path.join(scratch, "warp.tar.xz")
    unused = [os.path.join(unpacked, path) for path in UNUSED_AT_RUN_TIME if os.path.exists(os.path.join(unpacked, path))]
    with open(archive, "wb") as out:
        if not unused:
            _bash(f"cat {parts}", stdout=out)
            return archive
        for path in unused:
            shutil.rmtree(path)
        # The paths as pack.sh archives them (./warp/...), for its finish.sh's tar -x.
        _bash(f"tar -C {shlex.quote(unpacked)} -cf - . | xz -T0 -9e", stdout=out)
    return archive


def add_extra_wheels(wheels: str) -> None:
    """Download the :data:`EXTRA_WHEELS` (pure Python, so any platform's) into the folder ``wheels``
    unless there already."""
    present = {name.split("-")[0].lower() for name in os.listdir(wheels) if name.endswith(".whl")}
    for requirement in EXTRA_WHEELS:
        if requirement.split("==")[0].replace("-", "_").lower() not in present:
            subprocess.run([sys.executable, "-m", "pip", "download", "-q", "--no-deps", "-d", wheels, requirement], check=True)


def leave_out_wheels(wheels: str) -> None:
    """Delete the :data:`LEFT_OUT_WHEELS` from the folder ``wheels``."""
    for name in os.listdir(wheels):
        if name.endswith(".whl") and name.split("-")[0].lower() in LEFT_OUT_WHEELS:
            os.remove(os.path.join(wheels, name))


def slim_wheels(wheels: str) -> None:
    """Rewrite each wheel in the folder ``wheels`` without its files under :data:`UNUSED_IN_WHEELS`
    and their lines in its ``RECORD``, every other file as it was (pip installs it as before);
    a wheel without such files is left untouched, so a second run changes nothing."""
    for name in sorted(os.listdir(wheels)):
        if not name.endswith(".whl"):
            continue
        path = os.path.join(wheels, name)
        with zipfile.ZipFile(path) as source:
            members = source.infolist()
            kept = [member for member in members if not member.filename.startswith(UNUSED_IN_WHEELS)]
            if len(kept) == len(members):
                continue
            with zipfile.ZipFile(path + ".slim", "w") as slimmed:
                for member in kept:
                    data = source.read(member)
                    if member.filename.endswith(".dist-info/RECORD"):
                        data = b"".join(line for line in data.splitlines(keepends=True)
                                        if not line.decode().startswith(UNUSED_IN_WHEELS))
                    slimmed.writestr(member, data)
        os.replace(path + ".slim", path)


def repack(dev: str, tree: int, margin: int) -> dict:
    """Rewrite ``dev``'s two warp-lang parts (slimmed, split at :func:`split_point`) after leaving
    out the wheels no step imports and slimming the rest (:func:`slim_wheels`); returns the record. Sizes count as archived
    (:func:`archived_bytes`), names relative to ``dev``'s parent."""
    root = os.path.dirname(os.path.abspath(dev))
    for part in (FIRST_PART, REST):
        if not os.path.isfile(os.path.join(dev, part)):
            raise ValueError(f"{os.path.join(dev, part)} is missing: run this with pack=true (it runs ../shared/device/pack.sh first)")
    leave_out_wheels(os.path.join(dev, "a", "whl"))
    slim_wheels(os.path.join(dev, "a", "whl"))
    with tempfile.TemporaryDirectory() as scratch:
        archive = slim_warp(dev, scratch)
        part_entry = lambda part, size: entry_bytes(os.path.relpath(os.path.join(dev, part), root), size)
        packed_entry = lambda part: part_entry(part, os.path.getsize(os.path.join(dev, part)))
        payload = Payload(
            first_call_fixed=folder_bytes(os.path.join(dev, "a"), root) - packed_entry(FIRST_PART),
            second_call_fixed=folder_bytes(os.path.join(dev, "b"), root) - packed_entry(REST)
            + folder_bytes(os.path.join(dev, KERNELS), root),
            warp=os.path.getsize(archive),
        )
        first = split_point(payload, tree, margin)
        with open(archive, "rb") as source:
            for part, size in ((FIRST_PART, first), (REST, None)):
                with open(os.path.join(dev, part), "wb") as out:
                    out.write(source.read(size if size is not None else -1))
    return {
        "date": datetime.datetime.now(datetime.timezone.utc).isoformat(timespec="seconds"),
        "transfer_limit": TRANSFER_LIMIT, "margin": margin, "tree": tree,
        **dataclasses.asdict(payload),
        "first_call": tree + payload.first_call_fixed + part_entry(FIRST_PART, first) + ARCHIVE_END,
        "second_call": tree + payload.second_call_fixed + part_entry(REST, payload.warp - first) + ARCHIVE_END,
        "room_for_tree": room_for_tree(payload, margin),
    }


def _run_pack_sh(dev: str) -> None:
    """``pack.sh`` from the repository root, with ``.dev/kernels`` kept across its ``rm -rf .dev``."""
    kernels = os.path.join(dev, KERNELS)
    with tempfile.TemporaryDirectory() as keep:
        if os.path.isdir(kernels):
            shutil.move(kernels, os.path.join(keep, KERNELS))
        try:
            subprocess.run(["bash", os.path.join(REPO, "..", "shared", "device", "pack.sh")], cwd=REPO, check=True)
        finally:
            if os.path.isdir(os.path.join(keep, KERNELS)):
                os.makedirs(dev, exist_ok=True)
                shutil.move(os.path.join(keep, KERNELS), kernels)


def main(argv: list[str]) -> None:
    from admissable_jax.cli import fail, parse_args

    config = parse_args(DevicePackConfig, argv, "benchmarks/device_pack.py", __doc__.strip().splitlines()[0], _validate)
    dev = os.path.join(REPO, ".dev")
    try:
        if config.pack:
            _run_pack_sh(dev)
        add_extra_wheels(os.path.join(dev, "a", "whl"))
        record = repack(dev, tree_bytes(), int(config.margin_mb * 1e6))
    except subprocess.CalledProcessError as error:
        fail(f"{' '.join(map(str, error.cmd)) if isinstance(error.cmd, list) else error.cmd} exited with status {error.returncode}")
    except ValueError as error:
        fail(str(error))
    with open(RECORD, "w") as file:
        json.dump(record, file, indent=1)
        file.write("\n")
    kernels = "" if os.path.isdir(os.path.join(dev, KERNELS)) else " (no .dev/kernels: run benchmarks/warp_kernels.py, then this with pack=false)"
    print(f"first call (.dev/a and the tree) {record['first_call'] / 1e6:.2f} MB, second "
          f"(.dev/b, .dev/kernels and the tree) {record['second_call'] / 1e6:.2f} MB{kernels}, of {TRANSFER_LIMIT / 1e6:.2f} MB each; "
          f"the tree is {record['tree'] / 1e6:.2f} MB and may grow to {record['room_for_tree'] / 1e6:.2f} MB; "
          f"record {os.path.relpath(RECORD, REPO)}")


if __name__ == "__main__":
    main(sys.argv[1:])
