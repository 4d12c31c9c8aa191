"""benchmarks/warp_kernels.py: the CUDA modules a GPU lease loads, built here on the CPU; and
benchmarks/warp_atomics.py's reading of the atomics in the C++ Warp generates."""

import os
import tarfile
import types

import numpy as np
import pytest
import warp as wp
import warp_atomics  # benchmarks/ is on the tests' path (conftest.py)
import warp_kernels
import warp_launches
from warp._src import context as warp_context


@wp.kernel(module="unique")
def _add_one_tiled(values: wp.array(dtype=float)):
    i, _lane = wp.tid()
    if _lane == 0:
        values[i] = values[i] + 1.0


@wp.kernel(module="unique")
def _double(values: wp.array(dtype=float)):
    i = wp.tid()
    values[i] = values[i] * 2.0


@wp.kernel(module="unique")
def _never_launched(values: wp.array(dtype=float)):
    values[wp.tid()] = 0.0


@wp.func
def _add_to(sums: wp.array(dtype=float), i: int, value: float):
    sums[i] += value


@wp.kernel(module="unique")
def _atomics_of_each_kind(counts: wp.array(dtype=int), slots: wp.array(dtype=int), sums: wp.array(dtype=float)):
    i = wp.tid()
    slots[i] = wp.atomic_add(counts, 0, 1)
    wp.atomic_add(counts, 1, 1)
    _add_to(sums, i % 2, 1.0)


def test_warp_atomics_reads_each_kind_from_the_generated_code():
    """A slot counter (the return value used), an integer sum (unused), a float += in a
    function the kernel calls: each found, of its kind, with the Python line it came from."""
    arrays = [wp.zeros(2, dtype=int, device="cpu"), wp.zeros(4, dtype=int, device="cpu"), wp.zeros(2, dtype=float, device="cpu")]
    kernels, launches, empty = warp_launches.launched_kernels(
        wp, lambda: wp.launch(_atomics_of_each_kind, dim=4, inputs=arrays, device="cpu"))
    key = _atomics_of_each_kind.key
    assert (list(kernels), launches[key], empty) == ([key], 1, set())
    found = warp_atomics.atomics_of(key, warp_atomics.generated_source(wp, kernels[key]))
    assert sorted((atomic["kind"], atomic["line"].split(" <L")[0]) for atomic in found) == [
        ("float", "sums[i] += value"), ("integer", "wp.atomic_add(counts, 1, 1)"),
        ("slot counter", "slots[i] = wp.atomic_add(counts, 0, 1)")]
    assert sorted(arrays[1].numpy()) == [0, 1, 2, 3] and list(arrays[2].numpy()) == [2.0, 2.0]


@wp.kernel(module="unique", module_options={"deterministic": wp.DeterministicMode.RUN_TO_RUN})
def _sum_and_slots_run_to_run(values: wp.array(dtype=float), total: wp.array(dtype=float),
                              counts: wp.array(dtype=int), slots: wp.array(dtype=int), others: wp.array(dtype=int)):
    i = wp.tid()
    wp.atomic_add(total, 0, values[i])
    slots[i] = wp.atomic_add(counts, 0, 1)
    others[i] = wp.atomic_add(counts, 1, 1)


def test_warp_atomics_counts_what_a_forward_launch_adds_on_a_gpu():
    """A RUN_TO_RUN kernel with a float sum and a slot counter called twice: on a GPU each
    forward launch sort-reduces the sum's target and scans the counter, which holds two
    records per thread. The sum's adjoint (the gradient it would add into ``values``) is a
    target of the backward launch only, and is not counted."""
    arrays = [wp.full(4, 0.5, dtype=float, device="cpu"), wp.zeros(1, dtype=float, device="cpu"),
              wp.zeros(2, dtype=int, device="cpu"), wp.zeros(4, dtype=int, device="cpu"), wp.zeros(4, dtype=int, device="cpu")]

    def twice():
        for _ in range(2):
            wp.launch(_sum_and_slots_run_to_run, dim=4, inputs=arrays, device="cpu")

    kernels, launches, _ = warp_launches.launched_kernels(wp, twice)
    key = _sum_and_slots_run_to_run.key
    meta = kernels[key].adj.det_meta
    assert any(target.adjoint and not target.use_forward for target in meta.scatter_targets)  # the adjoint, listed
    added = warp_atomics.gpu_deterministic_path(kernels, launches, {key})
    assert dict(added) == {"launches": 2, "sort_reduces": 2, "counter_scans": 2}
    assert arrays[1].numpy()[0] == 4.0
    assert sorted(arrays[3].numpy()) == sorted(arrays[4].numpy()) == [4, 5, 6, 7]  # the second launch's slots
    assert dict(warp_atomics.gpu_deterministic_path(kernels, launches, set())) == {
        "launches": 0, "sort_reduces": 0, "counter_scans": 0}
    # Two call sites of the slot counter: two records per thread, which a third call would outgrow.
    assert warp_atomics.slot_counter_records(kernels, {key}) == {key: {"counts": 2}}


class _H200:
    """What Warp's CUDA load reads of a device to name the binary it looks up: an sm_90 GPU
    whose driver is CUDA 13.0, as on the lent H200s (the device library's KINDS.md)."""
    is_cpu, is_cuda, arch, alias, is_cubin_supported = False, True, 90, "cuda:0", True
    get_cuda_output_format = warp_context.Device.get_cuda_output_format
    get_cuda_compile_arch = warp_context.Device.get_cuda_compile_arch
    _get_cuda_arch_suffix = warp_context.Device._get_cuda_arch_suffix  # pylint: disable=protected-access

    def __init__(self):
        wp.init()
        self.runtime = types.SimpleNamespace(driver_version=(13, 0), toolkit_version=warp_context.runtime.toolkit_version)


def test_modules_are_built_for_the_block_sizes_a_cuda_device_loads(tmp_path):
    """The CPU runs every block with one thread, but a CUDA load looks a module up under the
    block size its launch asks for: a tiled launch's 64 (which Warp resolves twice), a plain
    launch's default 256. Before a graph capture Warp also loads every registered module it
    finds unloaded, at its default (256): the never-launched kernel, and the tiled one again.
    Each launch still runs on the CPU, and each variant is compiled to sm_90 CUBIN at the path
    a CUDA load on the H200 reads (Warp's own naming for that device):
    <cache>/<id>/<id>.sm90.cubin and its metadata, <id> naming the block size."""
    values = wp.zeros(4, dtype=float, device="cpu")
    with warp_kernels.ModuleLoads() as loads:
        wp.launch_tiled(_add_one_tiled, dim=[4], inputs=[values], block_dim=64, device="cpu")
        wp.launch(_double, dim=4, inputs=[values], device="cpu")
    np.testing.assert_array_equal(values.numpy(), np.full(4, 2.0))  # (0 + 1) * 2
    default = warp_kernels.CUDA_DEFAULT_BLOCK_DIM
    assert sorted((module.name, block_dim) for module, block_dim in loads.loads.values()) == sorted(
        [(_add_one_tiled.module.name, 64), (_double.module.name, default)])
    # The block size is part of the name: the CPU's own (1) would be another module.
    assert _add_one_tiled.module.get_module_identifier(64) != _add_one_tiled.module.get_module_identifier(1)

    registered = [_add_one_tiled.module, _double.module, _never_launched.module]
    variants = warp_kernels.cuda_variants(loads, registered)
    expected_variants = [(_add_one_tiled.module, 64), (_add_one_tiled.module, default), (_double.module, default),
                         (_never_launched.module, default)]
    assert sorted((module.name, block_dim) for module, block_dim in variants) == sorted(
        (module.name, block_dim) for module, block_dim in expected_variants)

    files = warp_kernels.compile_for_cuda(variants, 90, str(tmp_path))
    expected = []
    for module, block_dim in expected_variants:
        identifier = module.get_module_identifier(block_dim)
        on_the_device = module._get_compile_output_name(_H200(), block_dim=block_dim)  # pylint: disable=protected-access
        assert on_the_device == f"{identifier}.sm90.cubin"
        expected += [str(tmp_path / identifier / on_the_device), str(tmp_path / identifier / f"{identifier}.meta")]
    assert sorted(files) == sorted(expected)
    assert all(os.path.getsize(path) > 0 for path in files)


def test_an_archive_leaves_out_what_another_holds(tmp_path, capsys):
    """warp_kernels.py's archive per MuJoCo Warp setup packs only the files that the archives
    named in leave_out do not hold (the modules no setup changes), under the same names."""
    root = tmp_path / "scratch"
    files = []
    for name in ("warp_cache/1.19.0/wp_shared_1/m.cubin", "warp_cache/1.19.0/wp_own_2/m.cubin"):
        (root / name).parent.mkdir(parents=True)
        (root / name).write_bytes(name.encode())
        files.append(str(root / name))
    first = str(tmp_path / "first.tar.xz")
    assert warp_kernels.pack(files[:1], str(root), first, []) == ["warp_cache/1.19.0/wp_shared_1/m.cubin"]
    second = str(tmp_path / "second.tar.xz")
    assert warp_kernels.pack(files, str(root), second, [first]) == ["warp_cache/1.19.0/wp_own_2/m.cubin"]
    with tarfile.open(second) as archive:
        assert archive.extractfile("warp_cache/1.19.0/wp_own_2/m.cubin").read() == b"warp_cache/1.19.0/wp_own_2/m.cubin"
    # What would fail only after minutes of building (or on the GPU): refused in one line first.
    for args, message in (([f"out={tmp_path / 'kernels.tgz'}"], f"out must name a .tar.xz archive, got '{tmp_path / 'kernels.tgz'}'"),
                          ([f"leave_out={first},{tmp_path / 'none.tar.xz'}"], f"leave_out names no archive: {tmp_path / 'none.tar.xz'}"),
                          (["mjx_own_warp=true"], "mjx_own_warp=true steps MJX's own copy of MuJoCo Warp, which has no "
                                                  "deterministic mode: pass deterministic=false")):
        with pytest.raises(SystemExit) as refused:
            warp_kernels.main(args)
        assert refused.value.code == 2 and capsys.readouterr().err.strip().splitlines()[-1] == f"error: {message}"

