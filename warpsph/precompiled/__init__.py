"""Precompiled CUDA kernels shipped with warpsph (#43): a first run on a GPU loads its kernel modules instead of
compiling them.

``warpsph/precompiled/`` (package data) holds, for each of warpsph's kernel modules, the files that Warp writes into
its kernel cache when it compiles the module for a GPU and loads it: the metadata and, for each architecture built
(:data:`ARCHS`), the CUBIN and the PTX, each compressed with xz (not the generated CUDA source, which loading does
not read: it carries the build tree's paths in comments). ``manifest.json`` names the Warp
version and the CUDA toolkit (Warp's NVRTC) they were built with and, for each module, Warp's full module hash (a
SHA-256 of its kernels' source, the functions and structs they use, the constants they read and the compile options:
what Warp itself names a compiled module by) and each file's SHA-256.

Before a :class:`~warpsph.simulation.Simulation` on a CUDA device loads its modules, :func:`seed` copies into Warp's
kernel cache (``wp.config.kernel_cache_dir``: ``WARP_CACHE_PATH`` when set, else a per-user folder) the files Warp
will look up for that device (its own names: ``wp_<module>_<hash>/...sm90.cubin`` on an H100 whose driver is older
than Warp's toolkit, ``...sm90.ptx`` where it is not), where the cache lacks them, and only

- for the Warp version and toolkit of the manifest (another Warp: nothing is copied),
- for a module whose hash now is the full hash they were built from (a kernel, a function it calls or an option
  changed: nothing is copied and Warp compiles the module as before), and
- for the files whose content has the manifest's SHA-256.

Warp then finds them as it finds any module it compiled earlier. Nothing is shipped for the CPU (Warp does not
document loading CPU objects built on another machine): a run on the CPU compiles as before.

``WARPSPH_PRECOMPILED=0`` turns the copying off. ``tools/build_precompiled.py`` rebuilds the set (on any machine:
Warp's NVRTC needs no GPU); ``tests/test_precompiled.py`` fails when it is stale for the current source.
"""

from __future__ import annotations

import functools
import hashlib
import importlib
import json
import logging
import lzma
import os
import threading
from pathlib import Path

ENV = "WARPSPH_PRECOMPILED"
FOLDER = Path(__file__).resolve().parent  # the package: this file, manifest.json and a folder per module
MANIFEST = "manifest.json"
FORMAT = 1
# The architectures tools/build_precompiled.py builds by default: T4 (75), A100/A30 (80), RTX 30xx/A10/A40 (86),
# L4/L40/RTX 40xx (89), H100/H200/GH200 (90), B200/GB200 (100), RTX 50xx/RTX PRO 6000 (120). 75 also serves any
# newer GPU whose program sets wp.config.ptx_target_arch = 75 (where Warp compiles PTX: driver >= its toolkit).
ARCHS = (75, 80, 86, 89, 90, 100, 120)

log = logging.getLogger(__name__)


def enabled() -> bool:
    """Whether :func:`seed` copies anything (the environment variable ``WARPSPH_PRECOMPILED=0`` turns it off)."""
    return os.environ.get(ENV, "1").strip().lower() not in ("0", "false", "no", "off")


def manifest(folder=FOLDER) -> dict | None:
    """The manifest of the precompiled set in ``folder`` (default: the one shipped), or None where there is none
    (read once a folder; not to be changed)."""
    return _manifest(Path(folder).resolve())


@functools.lru_cache(maxsize=4)
def _manifest(folder) -> dict | None:
    try:
        with open(folder / MANIFEST) as f:
            data = json.load(f)
    except (OSError, ValueError):
        return None
    return data if data.get("format") == FORMAT else None


def toolkit() -> str:
    """The CUDA toolkit of this Warp's NVRTC, "13.4" ("" where it has none)."""
    import warp as wp

    wp.init()
    version = wp._src.context.runtime.toolkit_version
    return "" if version is None else f"{version[0]}.{version[1]}"


def for_this_warp(man) -> bool:
    """Whether the set of manifest ``man`` was built with this Warp and its CUDA toolkit."""
    import warp as wp

    return bool(man) and man.get("warp") == wp.config.version and man.get("cuda_toolkit") == toolkit()


def warp_module(name):
    """The Warp module of Python module ``name`` (imported; a Warp module is returned as it is)."""
    import warp as wp

    if not isinstance(name, str):
        return name
    importlib.import_module(name)
    return wp.get_module(name)


def module_hash(module) -> str:
    """Warp's full hash of ``module`` for the variant a CUDA launch loads (the module's block size), hex."""
    return module.get_module_hash(module.options["block_dim"]).hex()


def lookup_names(module, device=None, arch=None, use_ptx=None) -> tuple[str, str]:
    """The file names Warp looks up in the module's cache folder when it loads ``module`` on ``device`` (a CUDA
    device), or for CUDA architecture ``arch`` as PTX or CUBIN (``use_ptx``): (binary, metadata)."""
    block_dim = module.options["block_dim"]
    if device is not None:
        binary = module._get_compile_output_name(device, block_dim=block_dim)
    else:
        binary = module._get_compile_output_name(None, output_arch=arch, use_ptx=use_ptx, block_dim=block_dim)
    return binary, module._get_meta_name(block_dim=block_dim)


def _write(data, path):
    """Writes ``data`` to ``path`` through a temporary file beside it (another process may seed or compile the same
    module at the same time: each file appears whole or not at all)."""
    path.parent.mkdir(parents=True, exist_ok=True)
    temporary = path.with_name(f".{path.name}.{os.getpid()}.{threading.get_ident()}.tmp")
    try:
        with open(temporary, "wb") as f:
            f.write(data)
        os.replace(temporary, path)
    finally:
        if temporary.exists():
            temporary.unlink()


def seed(names, device=None, *, arch=None, use_ptx=None, root=None, folder=FOLDER) -> list[Path]:
    """Copies into Warp's kernel cache (``root``, default ``wp.config.kernel_cache_dir``) the precompiled files of
    the Warp modules ``names`` (Python module names, or Warp modules) that Warp will look up when it loads them on
    ``device`` (a CUDA device; a CPU device copies nothing), or for architecture ``arch`` as PTX or CUBIN
    (``use_ptx``), where the cache lacks them, the set is this Warp's and the module's hash is the one they were
    built from. Returns the paths written (none when ``WARPSPH_PRECOMPILED`` is 0 or Warp's ``cache_kernels`` is
    off). A module left out compiles as before."""
    import warp as wp

    if not enabled():
        return []
    if device is not None:
        device = wp.get_device(device)
        if not device.is_cuda:
            return []
    elif arch is None or use_ptx is None:
        raise ValueError("seed needs a CUDA device, or an architecture and the form (use_ptx)")
    man = manifest(folder)
    if not wp.config.cache_kernels or not for_this_warp(man):
        return []
    root = Path(root if root is not None else wp.config.kernel_cache_dir)
    written = []
    for module in dict.fromkeys(map(warp_module, names)):
        name = module.name
        entry = man["modules"].get(name)
        if entry is None:
            continue
        if module_hash(module) != entry["hash"]:
            log.debug("precompiled %s: built from another source (hash %s, now %s): it compiles", name,
                      entry["hash"][:12], module_hash(module)[:12])
            continue
        try:
            binary, meta = lookup_names(module, device, arch, use_ptx)
        except Exception as e:  # e.g. a GPU this Warp does not compile for: Warp says so when it loads the module
            log.debug("precompiled %s: no file name for %s (%s)", name, device or f"sm_{arch}", e)
            continue
        if binary not in entry["files"] or meta not in entry["files"]:  # an architecture not built
            continue
        target = root / module.get_module_identifier(block_dim=module.options["block_dim"])
        missing = [f for f in (meta, binary) if not (target / f).exists()]
        contents = {}
        for f in missing:
            try:
                data = lzma.decompress((Path(folder) / entry["dir"] / f"{f}.xz").read_bytes())
            except (OSError, lzma.LZMAError):
                data = None
            if data is None or hashlib.sha256(data).hexdigest() != entry["files"][f]:
                log.warning("precompiled %s: %s is missing or not the file built (its SHA-256 differs); the module "
                            "compiles", name, f)
                contents = {}
                break
            contents[f] = data
        try:
            for f in contents:  # the metadata first: Warp loads the binary only beside it
                _write(contents[f], target / f)
                written.append(target / f)
        except OSError as e:  # a read-only cache: Warp compiles (and says so where it cannot write either)
            log.debug("precompiled %s: not copied into %s (%s)", name, target, e)
    if written:
        log.debug("precompiled: %d files copied into %s", len(written), root)
    return written
