"""MuJoCo Warp's CUDA kernels for a GPU lease, built here on the CPU.

    python benchmarks/warp_kernels.py [envs=hopper,walker2d,ant] [arch=90] [out=.dev/kernels/warp-kernels.tar.xz]
    python benchmarks/warp_kernels.py envs=hopper deterministic=false leave_out=.dev/kernels/warp-kernels.tar.xz \
        out=.dev/kernels/warp-kernels-hopper-package.tar.xz
    python benchmarks/warp_kernels.py envs=ant deterministic=false mjx_own_warp=true \
        leave_out=.dev/kernels/warp-kernels.tar.xz,.dev/kernels/warp-kernels-hopper-package.tar.xz \
        out=.dev/kernels/warp-kernels-ant-own.tar.xz

A fresh device machine compiles Warp's modules the first time a program steps an env: on the
H100 (2026-11-24) a campaign run's first chunk took 36-58 s more than the next ones. Two kinds
are compiled there: each module a launch uses, at the block size the launch asks for (256
where it names none), and, before MJX's first CUDA graph capture (its default graph mode
captures each call), every module Python has registered, at its default block size: Warp's
``capture_begin`` preloads them all (``force_load``; ``config.enable_graph_capture_module_load_by_default``).
Warp compiles for a CUDA architecture without a GPU (its NVRTC), and the name a module is
cached under depends on its source, options and block size, never on the device. So this
steps each env on the CPU with MuJoCo Warp, notes each module a launch loads with the block
size a CUDA launch would give it (the CPU runs a block with one thread), adds every
registered module at its default block size, compiles each for ``sm_ARCH`` (CUBIN: the
device's driver, CUDA 13.0, is older than Warp's NVRTC, so Warp loads CUBIN there) and packs
the binaries and their metadata as ``warp_cache/<warp version>/...``, a Warp kernel cache,
into ``out``. H100 and H200 are both sm_90.

The second device call, which starts the campaign's worker, carries it (``carry=[".dev/b",
".dev/kernels"]``: a call's carried folders do not stay for the next call, so on the H200
lease of 2026-12-04, when the first call carried it, the worker found none); ``gpu_campaign.sh``
unpacks it into ``runs/campaign/warp_cache`` and points Warp there (``WARP_CACHE_PATH``). A
module missing from it is compiled on the device as before, and each call's pack says how
many modules came prebuilt and how many were compiled on the machine.

The modules depend on which MuJoCo Warp runs and in which mode (their names and options do),
so each setup a lease runs needs its own: the campaign's runs step the ``mujoco-warp``
package in its deterministic mode (the default here), the speed step's cost stage also
steps it in the GPU's own order (``deterministic=false``), and ``CAMPAIGN_DETERMINISTIC=0``
steps MJX's own copy (``deterministic=false mjx_own_warp=true``). One setup per process, as
for our envs: one archive each, all in ``.dev/kernels``, which the worker unpacks together;
``leave_out`` keeps out of one what the others hold (the modules no setup changes).

This reads Warp's module loading from inside (``warp._src.context``, Warp 1.19); another Warp
version stops it with a one-line error rather than building a cache the device would miss.
"""

from __future__ import annotations

import dataclasses
import os
import sys
import tarfile
import tempfile
import threading
import time
from typing import Iterable

import jax
import jax.numpy as jnp

from admissable_jax.cli import parse_args
from admissable_jax.envs import canonical_env_name, make_env, warp_package

CUDA_DEFAULT_BLOCK_DIM = 256  # what a CUDA launch that names no block size gets (Warp's default)
KNOWN_WARP = "1.19."


@dataclasses.dataclass
class WarpKernelsConfig:
    envs: str = dataclasses.field(default="hopper,walker2d,ant", metadata={"help": "comma-separated envs"})
    arch: int = dataclasses.field(default=90, metadata={"help": "CUDA architecture (sm_ARCH): 90 for H100/H200"})
    out: str = dataclasses.field(default=".dev/kernels/warp-kernels.tar.xz",
                                 metadata={"help": "the archive to write (carry its folder to the device)"})
    batch: int = dataclasses.field(default=4, metadata={"help": "worlds stepped on the CPU (modules do not depend on it)"})
    deterministic: bool = dataclasses.field(default=True, metadata={"help": "MuJoCo Warp's deterministic mode (deterministic_physics)"})
    mjx_own_warp: bool = dataclasses.field(default=False, metadata={"help": "MJX's own copy of MuJoCo Warp (needs deterministic=false)"})
    leave_out: str = dataclasses.field(default="", metadata={"help": "comma-separated archives whose files are not packed again"})


def _validate(config: WarpKernelsConfig) -> None:
    for name in config.envs.split(","):
        canonical_env_name(name.strip())
    if config.arch < 75:
        raise ValueError(f"arch must be a CUDA architecture Warp supports (>= 75), got {config.arch}")
    if config.batch < 1:
        raise ValueError("batch must be >= 1")
    if config.mjx_own_warp and config.deterministic:
        raise ValueError("mjx_own_warp=true steps MJX's own copy of MuJoCo Warp, which has no deterministic mode: "
                         "pass deterministic=false")
    for archive in filter(None, config.leave_out.split(",")):
        if not os.path.isfile(archive):
            raise ValueError(f"leave_out names no archive: {archive}")
    if not config.out.endswith(".tar.xz"):
        raise ValueError(f"out must name a .tar.xz archive, got {config.out!r}")


class ModuleLoads:
    """Records (module, CUDA block size) for every Warp module loaded while it is active.

    Warp resolves a launch's block size (``_resolve_launch_block_dim``) before loading the
    kernel's module for it, and on the CPU resolves it to 1; a tiled launch resolves it twice.
    The first size a launch asks for is kept until the module load it leads to, which
    records the size a CUDA device would have loaded the module with.
    """

    def __init__(self):
        from warp._src import context

        self._context = context
        self._requested = threading.local()
        self.loads: dict[tuple[int, int], tuple[object, int]] = {}

    def __enter__(self) -> ModuleLoads:
        context, requested, loads = self._context, self._requested, self.loads
        resolve, load = context._resolve_launch_block_dim, context.Module.load  # pylint: disable=protected-access
        self._originals = resolve, load

        def resolve_noting_request(device, block_dim):
            if getattr(requested, "block_dim", None) is None:
                requested.block_dim = block_dim
            return resolve(device, block_dim)

        def load_noting_module(module, device, block_dim=None, *args, **kwargs):
            asked, requested.block_dim = getattr(requested, "block_dim", None), None
            cuda_block_dim = int(asked) if asked is not None and int(asked) > 0 else CUDA_DEFAULT_BLOCK_DIM
            loads[(id(module), cuda_block_dim)] = (module, cuda_block_dim)
            return load(module, device, block_dim, *args, **kwargs)

        context._resolve_launch_block_dim = resolve_noting_request  # pylint: disable=protected-access
        context.Module.load = load_noting_module
        return self

    def __exit__(self, *_exception) -> None:
        self._context._resolve_launch_block_dim, self._context.Module.load = self._originals  # pylint: disable=protected-access


def step_env_on_cpu(name: str, batch: int, deterministic: bool = True) -> None:
    """Reset ``batch`` worlds of env ``name`` on MuJoCo Warp and step them twice: every module
    the campaign's programs launch (reset, step, contact forces) loads."""
    env = make_env(name, physics="warp", max_batch=batch, deterministic=deterministic)
    states = jax.jit(jax.vmap(env.reset))(jax.random.split(jax.random.key(0), batch))
    step = jax.jit(jax.vmap(env.step))
    actions = jnp.zeros((batch, env.action_size))
    for _ in range(2):
        states = step(states, actions)
    jax.block_until_ready(states)


def cuda_variants(loads: ModuleLoads, registered: Iterable[object]) -> list[tuple[object, int]]:
    """Every (module, block size) a CUDA device loads: the recorded launches', and each of the
    ``registered`` modules at its default block size, as a graph capture's preload loads the
    modules it finds unloaded."""
    variants = dict(loads.loads)
    for module in registered:
        default = int(module.options["block_dim"])
        variants.setdefault((id(module), default), (module, default))
    return list(variants.values())


def compile_for_cuda(variants: list[tuple[object, int]], arch: int, cache_dir: str) -> list[str]:
    """Each (module, block size) compiled to ``sm_arch`` CUBIN in Warp's cache layout under
    ``cache_dir``; returns the paths of the binaries and metadata files."""
    files = []
    for module, block_dim in variants:
        module.get_module_hash(block_dim)  # resolves this block size's options
        module_dir = os.path.join(cache_dir, module.get_module_identifier(block_dim))
        output_name = module._get_compile_output_name(None, arch, "", use_ptx=False, block_dim=block_dim)  # pylint: disable=protected-access
        module._compile(None, module_dir, output_name, arch, use_ptx=False,  # pylint: disable=protected-access
                        options=module.resolved_options[block_dim])
        files += [os.path.join(module_dir, output_name), os.path.join(module_dir, module._get_meta_name(block_dim))]  # pylint: disable=protected-access
    return files


def pack(files: list[str], root: str, out: str, leave_out: list[str]) -> list[str]:
    """Write ``files`` (under ``root``, named relative to it) into the archive ``out``, but those
    the ``leave_out`` archives hold under the same name; returns the names packed."""
    packed = set()
    for other in leave_out:
        with tarfile.open(other) as archive:
            packed.update(archive.getnames())
    names = sorted({os.path.relpath(path, root) for path in files} - packed)
    with tarfile.open(out, "w:xz") as archive:
        for name in names:
            archive.add(os.path.join(root, name), arcname=name)
    return names


def main(argv: list[str]) -> None:
    config = parse_args(WarpKernelsConfig, argv, "benchmarks/warp_kernels.py", __doc__.strip().splitlines()[0], _validate)
    if config.mjx_own_warp:  # before the first env imports MJX
        os.environ[warp_package.OWN_COPY_VARIABLE] = "1"
    import warp

    if not warp.__version__.startswith(KNOWN_WARP):
        sys.exit(f"warp_kernels.py reads Warp {KNOWN_WARP}x's module loading; this is Warp {warp.__version__}")
    from warp._src.context import user_modules

    start = time.perf_counter()
    with ModuleLoads() as loads:
        for name in config.envs.split(","):
            step_env_on_cpu(name.strip(), config.batch, config.deterministic)
    variants = cuda_variants(loads, list(user_modules.values()))
    print(f"{config.envs}: {len(loads.loads)} module variants launched, {len(variants)} with every registered "
          f"module's default ({time.perf_counter() - start:.0f} s); compiling for sm_{config.arch}", flush=True)
    with tempfile.TemporaryDirectory() as scratch:
        files = compile_for_cuda(variants, config.arch, os.path.join(scratch, "warp_cache", warp.__version__))
        os.makedirs(os.path.dirname(os.path.abspath(config.out)), exist_ok=True)
        names = pack(files, scratch, config.out, list(filter(None, config.leave_out.split(","))))
    print(f"{len(variants)} Warp module variants for sm_{config.arch} ({len(set(files)) - len(names)} of their "
          f"{len(set(files))} files already in {config.leave_out or 'no other archive'}) in {config.out}, "
          f"{os.path.getsize(config.out):,} bytes ({time.perf_counter() - start:.0f} s in all)")


if __name__ == "__main__":
    main(sys.argv[1:])
