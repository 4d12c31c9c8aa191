"""The GPU campaign's first two device calls each fit one transfer (benchmarks/device_pack.py),
and the figures results commit stay small (benchmarks/compact_pngs.py)."""

from __future__ import annotations

import base64
import importlib.metadata
import io
import json
import os
import subprocess
import tarfile
import zipfile

import pytest

import device_pack

MB = 10**6


def _mujoco_wheel(size: int) -> dict[str, bytes]:
    """A mujoco wheel's files, MuJoCo Studio among them, with its RECORD; the same bytes for the same size."""
    library = bytes(range(256)) * (size // 256)
    return {"mujoco/libmujoco.so": library, "mujoco/experimental/studio/studio.so": b"studio" * 3000,
            "mujoco-3.17.0.dist-info/RECORD": b"mujoco/libmujoco.so,sha256=x,1\n"
                                               b"mujoco/experimental/studio/studio.so,sha256=y,2\n"
                                               b"mujoco-3.17.0.dist-info/RECORD,,\n"}


def _fake_pack_sh(dev, warp_so: bytes, tests: bytes, wheels: int, first_part: int) -> None:
    """A .dev as ../shared/device/pack.sh leaves it: wheels and warp-lang's first part in a/, the rest in b/."""
    os.makedirs(dev / "a" / "whl")
    os.makedirs(dev / "b")
    with zipfile.ZipFile(dev / "a" / "whl" / "mujoco-3.17.0-cp312-cp312-manylinux_2_28_x86_64.whl", "w") as wheel:
        for name, data in _mujoco_wheel(wheels).items():
            wheel.writestr(name, data)
    (dev / "a" / "whl" / "PyOpenGL-3.1.10-py3-none-any.whl").write_bytes(os.urandom(wheels // 3))  # only MuJoCo's renderer imports it
    (dev / "a" / "stage.sh").write_text("staged\n")
    (dev / "b" / "finish.sh").write_text("finished\n")
    buffer = io.BytesIO()
    with tarfile.open(fileobj=buffer, mode="w") as tar:
        for name, data in (("./warp/bin/warp.so", warp_so), ("./warp/tests/test_all.py", tests), ("./warp/__init__.py", b"")):
            info = tarfile.TarInfo(name)
            info.size = len(data)
            tar.addfile(info, io.BytesIO(data))
    archive = subprocess.run(["xz", "-0"], input=buffer.getvalue(), capture_output=True, check=True).stdout
    (dev / "a" / "warp.part0").write_bytes(archive[:first_part])
    (dev / "b" / "warp.part1").write_bytes(archive[first_part:])


def _joined(dev) -> dict[str, bytes]:
    """warp-lang as finish.sh unpacks it: the two parts joined, decompressed, untarred."""
    data = subprocess.run(f"cat {dev}/a/warp.part0 {dev}/b/warp.part1 | xz -d", shell=True, capture_output=True, check=True).stdout
    with tarfile.open(fileobj=io.BytesIO(data)) as tar:
        return {member.name: tar.extractfile(member).read() for member in tar.getmembers() if member.isfile()}


def test_the_wheels_pack_sh_lacks_are_added_once(tmp_path, monkeypatch):
    """mujoco-warp (MJX runs it for its deterministic mode), as pyproject.toml's 'cuda' extra pins it
    (mujoco-mjx's release), is downloaded into .dev/a/whl unless there."""
    assert device_pack.EXTRA_WHEELS == (f"mujoco-warp=={importlib.metadata.version('mujoco-mjx')}",)
    downloads = []
    monkeypatch.setattr(device_pack.subprocess, "run", lambda command, check: downloads.append(command[-1]))
    device_pack.add_extra_wheels(str(tmp_path))
    assert downloads == ["mujoco-warp==3.17.0"]
    (tmp_path / "mujoco_warp-3.17.0-py3-none-any.whl").write_bytes(b"")
    device_pack.add_extra_wheels(str(tmp_path))
    assert downloads == ["mujoco-warp==3.17.0"]


def test_packs_are_slimmed_and_split_so_that_each_call_fits_with_the_tree(tmp_path, monkeypatch, capsys):
    """Small sizes for 64 MiB: a 1 MB limit, a 0.3 MB tree, 0.3 MB of wheels, 0.1 MB of kernels,
    warp-lang 0.8 MB (incompressible) and its test suite 0.3 MB, whose first part pack.sh left
    small, as it does."""
    monkeypatch.setattr(device_pack, "TRANSFER_LIMIT", 1 * MB)
    dev = tmp_path / ".dev"
    warp_so, tests = os.urandom(800_000), os.urandom(300_000)
    _fake_pack_sh(dev, warp_so, tests, wheels=300_000, first_part=100_000)
    os.makedirs(dev / "kernels")
    (dev / "kernels" / "warp-kernels.tar.xz").write_bytes(os.urandom(100_000))
    margin, tree = 10_000, 300_000
    second_call = lambda: (tree + device_pack.folder_bytes(dev / "b", tmp_path)
                           + device_pack.folder_bytes(dev / "kernels", tmp_path) + device_pack.ARCHIVE_END)
    assert second_call() > 1 * MB  # as pack.sh split it, the second call would be over

    record = device_pack.repack(str(dev), tree, margin)
    # The wheels stage.sh installs: all but those no campaign step imports, and of mujoco's
    # files all but MuJoCo Studio's (and its RECORD line), each as it was.
    assert os.listdir(dev / "a" / "whl") == ["mujoco-3.17.0-cp312-cp312-manylinux_2_28_x86_64.whl"]
    with zipfile.ZipFile(dev / "a" / "whl" / "mujoco-3.17.0-cp312-cp312-manylinux_2_28_x86_64.whl") as wheel:
        kept = {name: wheel.read(name) for name in wheel.namelist()}
    assert kept == {"mujoco/libmujoco.so": _mujoco_wheel(300_000)["mujoco/libmujoco.so"],
                    "mujoco-3.17.0.dist-info/RECORD": b"mujoco/libmujoco.so,sha256=x,1\nmujoco-3.17.0.dist-info/RECORD,,\n"}
    # warp-lang as finish.sh unpacks it: all of it but the test suite, never imported at run time.
    assert _joined(dev) == {"./warp/bin/warp.so": warp_so, "./warp/__init__.py": b""}
    # The first call (.dev/a) is filled to within a block of the limit less the margin; the rest
    # goes second, with the kernels: the call that starts the worker carries them, since a
    # call's carried folders do not stay for the next. Each counts as a tar archive would take.
    assert 1 * MB - margin - 512 < record["first_call"] <= 1 * MB - margin
    assert record["second_call"] == second_call() <= 1 * MB - margin
    for call, carried in (("first_call", ".dev/a"), ("second_call", ".dev/b .dev/kernels")):
        archived = subprocess.run(f"tar -C {tmp_path} -cf - {carried} | wc -c", shell=True, capture_output=True,
                                  check=True).stdout
        assert record[call] - device_pack.ARCHIVE_END < tree + int(archived) <= record[call]
    # A second run over what the first wrote changes nothing but the record's date.
    again = device_pack.repack(str(dev), tree, margin)
    assert {**again, "date": None} == {**record, "date": None}

    # A tree with which the two calls cannot hold it all: refused in one line, nothing rewritten.
    before = _joined(dev)
    with pytest.raises(ValueError, match=r"^the working tree \(0\.41 MB\) leaves too little room for the device packs: "
                                         r"both calls fit with a tree of at most 0\.3\d MB") as refused:
        device_pack.repack(str(dev), 410_000, margin)
    assert "\n" not in str(refused.value)
    assert _joined(dev) == before
    # A .dev that pack.sh never filled, and a margin past the packs' room: one line each, before any work.
    with pytest.raises(ValueError, match=f"^{tmp_path / 'empty' / 'a' / 'warp.part0'} is missing: run this with pack=true "):
        device_pack.repack(str(tmp_path / "empty"), tree, margin)
    for margin_mb in ("-1", "10"):
        with pytest.raises(SystemExit) as refused_margin:
            device_pack.main(["pack=false", f"margin_mb={margin_mb}"])
        assert refused_margin.value.code == 2
        assert capsys.readouterr().err.strip().splitlines()[-1] == f"error: margin_mb must be in [0, 10), got {float(margin_mb)}"


def test_the_committed_tree_leaves_room_for_the_recorded_packs():
    """The tree that travels with every device call, against what device_pack.py last packed
    (its record): results committed too large would stop the GPU campaign's second call."""
    with open(device_pack.RECORD) as file:
        record = json.load(file)
    payload = device_pack.Payload(**{field: record[field] for field in ("first_call_fixed", "second_call_fixed", "warp")})
    room = device_pack.room_for_tree(payload, record["margin"])
    tree = device_pack.tree_bytes()
    assert tree <= room, (f"the tree ({tree / MB:.2f} MB) is over the {room / MB:.2f} MB the device packs leave "
                          "(benchmarks/results/device_pack.json): commit results smaller")


def test_compacted_figures_look_the_same_at_a_fraction_of_the_bytes(tmp_path):
    """compact_pngs.py: a matplotlib figure (lines over shaded bands beside a viridis heatmap, as
    ours are) rewritten as a palette PNG, its pixels as they were to the eye; one already
    compacted is left as it is; a path that is neither a PNG nor a folder is refused."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import numpy as np
    from PIL import Image

    import compact_pngs

    figure, (lines, heatmap) = plt.subplots(1, 2, figsize=(8, 3))
    steps = np.linspace(0, 1, 200)
    for phase, colour in ((0.0, "tab:blue"), (1.0, "tab:red")):
        lines.plot(steps, np.sin(6 * steps + phase), color=colour)
        lines.fill_between(steps, np.sin(6 * steps + phase) - 0.3, np.sin(6 * steps + phase) + 0.3, color=colour, alpha=0.2)
    figure.colorbar(heatmap.imshow(np.random.default_rng(0).random((11, 40)), aspect="auto"), ax=heatmap)
    path = tmp_path / "figures" / "curves.png"
    path.parent.mkdir()
    figure.savefig(path, dpi=150)
    plt.close(figure)
    with Image.open(path) as image:
        original = np.asarray(image.convert("RGB"), dtype=np.int16)
    full_colour = path.read_bytes()

    before, after = compact_pngs.compact(str(path))
    assert after == os.path.getsize(path) < 0.6 * before
    with Image.open(path) as image:
        assert image.mode == "P"
        compacted = np.asarray(image.convert("RGB"), dtype=np.int16)
    difference = np.abs(compacted - original)
    assert difference.mean() < 0.5 and np.percentile(difference, 99) <= 8, (difference.mean(), np.percentile(difference, 99))
    assert compact_pngs.compact(str(path)) == (after, after)
    # A notebook's PNG outputs likewise (base64 in its JSON), the rest of it as it was.
    cells = [{"cell_type": "markdown", "metadata": {}, "source": ["# Ünïcode stays"]},
             {"cell_type": "code", "execution_count": 1, "metadata": {}, "source": ["plot()"], "outputs": [
                 {"output_type": "display_data", "metadata": {},
                  "data": {"image/png": base64.b64encode(full_colour).decode("ascii"), "text/plain": ["<Figure>"]}}]}]
    notebook = tmp_path / "figures" / "walkthrough.ipynb"
    notebook.write_text(json.dumps({"cells": cells, "metadata": {}, "nbformat": 4, "nbformat_minor": 5},
                                   sort_keys=True, indent=1, ensure_ascii=False) + "\n", encoding="utf-8")
    notebook_before, notebook_after = compact_pngs.compact(str(notebook))
    assert notebook_after == os.path.getsize(notebook) < notebook_before - 0.5 * (before - after)
    compacted_cells = json.loads(notebook.read_text(encoding="utf-8"))["cells"]
    (output,) = compacted_cells[1]["outputs"]
    assert base64.b64decode(output["data"].pop("image/png")) == path.read_bytes()  # the file's own compaction
    assert compacted_cells[0] == cells[0] and output["data"] == {"text/plain": ["<Figure>"]}
    assert compact_pngs.compact(str(notebook)) == (notebook_after, notebook_after)
    assert compact_pngs.png_files([str(tmp_path)]) == [str(path), str(notebook)]
    with pytest.raises(ValueError, match=r"^.*notes\.txt: not a PNG file, a notebook nor a folder$"):
        compact_pngs.png_files([str(tmp_path / "notes.txt")])
