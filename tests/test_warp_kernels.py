"""benchmarks/warp_kernels.py: the CUDA modules a GPU lease loads, built here on the CPU."""

import importlib.util
import os
import sys

import numpy as np
import warp as wp

BENCHMARKS = os.path.join(os.path.dirname(__file__), "..", "benchmarks")
sys.path.insert(0, BENCHMARKS)  # warp_kernels.py imports as the benchmarks do
_spec = importlib.util.spec_from_file_location("warp_kernels", os.path.join(BENCHMARKS, "warp_kernels.py"))
warp_kernels = sys.modules["warp_kernels"] = importlib.util.module_from_spec(_spec)  # its dataclass looks it up there
_spec.loader.exec_module(warp_kernels)


@wp.kernel(module="unique")
def _add_one_tiled(values: wp.array(dtype=float)):
    i, _lane = wp.tid()
    if _lane == 0:
        values[i] = values[i] + 1.0


@wp.kernel(module="unique")
def _double(values: wp.array(dtype=float)):
    i = wp.tid()
    values[i] = values[i] * 2.0


def test_modules_are_built_for_the_block_size_a_cuda_launch_uses(tmp_path):
    """The CPU runs every block with one thread, but a CUDA load looks a module up under the
    block size its launch asks for: a tiled launch's 64 (which Warp resolves twice), a plain
    launch's default 256. Each module is recorded with that size, still runs on the CPU, and
    is compiled to sm_90 CUBIN at the path a CUDA load reads: <cache>/<id>/<id>.sm90.cubin
    and its metadata, <id> naming that block size."""
    values = wp.zeros(4, dtype=float, device="cpu")
    with warp_kernels.ModuleLoads() as loads:
        wp.launch_tiled(_add_one_tiled, dim=[4], inputs=[values], block_dim=64, device="cpu")
        wp.launch(_double, dim=4, inputs=[values], device="cpu")
    np.testing.assert_array_equal(values.numpy(), np.full(4, 2.0))  # (0 + 1) * 2
    assert sorted((module.name, block_dim) for module, block_dim in loads.loads.values()) == sorted(
        [(_add_one_tiled.module.name, 64), (_double.module.name, warp_kernels.CUDA_DEFAULT_BLOCK_DIM)])
    # The block size is part of the name: the CPU's own (1) would be another module.
    assert _add_one_tiled.module.get_module_identifier(64) != _add_one_tiled.module.get_module_identifier(1)

    files = warp_kernels.compile_for_cuda(loads, 90, str(tmp_path))
    expected = []
    for module, block_dim in [(_add_one_tiled.module, 64), (_double.module, 256)]:
        identifier = module.get_module_identifier(block_dim)
        expected += [str(tmp_path / identifier / f"{identifier}.sm90.cubin"), str(tmp_path / identifier / f"{identifier}.meta")]
    assert sorted(files) == sorted(expected)
    assert all(os.path.getsize(path) > 0 for path in files)
