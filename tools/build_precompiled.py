"""Rebuilds warpsph's precompiled CUDA kernels (warpsph/precompiled/, package data; warpsph/precompiled.py, #43).

    python tools/build_precompiled.py                     # every kernel module, the default architectures
    python tools/build_precompiled.py --archs 90 80       # only these
    python tools/build_precompiled.py --check             # say whether the shipped set is current; build nothing

Run it after changing a kernel (tests/test_precompiled.py fails until then) or upgrading Warp, on any machine: Warp's
NVRTC compiles for a GPU architecture without a GPU (~0.5-1.5 s a module, form and architecture on one core). Each
module is compiled into an empty kernel cache of its own (nothing already cached is reused, and the shipped set is
not read: WARPSPH_PRECOMPILED=0), for each architecture as CUBIN and as PTX; the metadata and the binaries are
written xz-compressed to warpsph/precompiled/<Warp's folder name>/ and listed in manifest.json with the module's
full hash and each file's SHA-256. The folders of modules no longer current are removed.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import lzma
import os
import shutil
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
os.environ["WARPSPH_PRECOMPILED"] = "0"  # compile everything: the shipped set is what is being rebuilt
CACHE = tempfile.mkdtemp(prefix="warpsph-precompiled-")
os.environ["WARP_CACHE_PATH"] = CACHE  # before Warp's import: an empty cache, so each module is compiled here
sys.path.insert(0, str(ROOT))

import warp as wp  # noqa: E402

from warpsph import precompiled, warmup  # noqa: E402

wp.config.quiet = True


def stale(names, man) -> list[str]:
    """The modules ``names`` that manifest ``man`` lacks or lists with another hash, and why the whole set is stale
    (another Warp or toolkit)."""
    if not man:
        return ["no manifest"]
    out = [] if precompiled.for_this_warp(man) else [
        f"built with Warp {man.get('warp')} / CUDA {man.get('cuda_toolkit')}, this is Warp {wp.config.version} / "
        f"CUDA {precompiled.toolkit()}"]
    for module in map(precompiled.warp_module, names):
        entry = man["modules"].get(module.name)
        if entry is None:
            out.append(f"{module.name}: not built")
        elif entry["hash"] != precompiled.module_hash(module):
            out.append(f"{module.name}: built from another source")
    return out


def build(names, archs, out, workers):
    start = time.perf_counter()
    warmup.compile_for_archs(names, archs, max_workers=workers)
    cache = Path(wp.config.kernel_cache_dir)
    modules, sizes = {}, {"meta": 0}
    staging = Path(tempfile.mkdtemp(prefix="warpsph-precompiled-out-"))
    for module in map(precompiled.warp_module, names):
        identifier = module.get_module_identifier(block_dim=module.options["block_dim"])
        files = {}
        wanted = [precompiled.lookup_names(module, arch=a, use_ptx=p) for a in archs for p in (False, True)]
        for f in dict.fromkeys(n for pair in wanted for n in pair):
            data = (cache / identifier / f).read_bytes()  # missing: the compile failed to write it, stop
            packed = lzma.compress(data, preset=9 | lzma.PRESET_EXTREME)
            (staging / identifier).mkdir(exist_ok=True)
            (staging / identifier / f"{f}.xz").write_bytes(packed)
            files[f] = hashlib.sha256(data).hexdigest()
            kind = f.rsplit(".", 2)[-2] + "." + f.rsplit(".", 1)[-1] if not f.endswith(".meta") else "meta"
            sizes[kind] = sizes.get(kind, 0) + len(packed)
        modules[module.name] = {"hash": precompiled.module_hash(module), "dir": identifier, "files": dict(sorted(files.items()))}
    man = {"format": precompiled.FORMAT, "warp": wp.config.version, "cuda_toolkit": precompiled.toolkit(),
           "archs": sorted(archs), "built_by": "tools/build_precompiled.py",
           "modules": dict(sorted(modules.items()))}
    for old in out.glob("wp_*"):
        shutil.rmtree(old)
    out.mkdir(parents=True, exist_ok=True)
    for folder in staging.iterdir():
        shutil.move(str(folder), out / folder.name)
    (out / precompiled.MANIFEST).write_text(json.dumps(man, indent=1) + "\n")
    shutil.rmtree(staging)
    total = sum(p.stat().st_size for p in out.rglob("*") if p.is_file())
    print(f"{len(names)} modules for sm_{', sm_'.join(map(str, sorted(archs)))} (CUBIN and PTX) in "
          f"{time.perf_counter() - start:.1f} s; {out.relative_to(ROOT)}: {total / 2**20:.2f} MiB")
    for kind, size in sorted(sizes.items()):
        print(f"  {kind:<12} {size / 2**10:8.0f} KiB")


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--archs", type=int, nargs="+", default=list(precompiled.ARCHS), metavar="SM")
    parser.add_argument("--modules", nargs="+", metavar="NAME", help="default: every kernel module (warmup.all_modules)")
    parser.add_argument("--workers", type=int, default=None, help="compile threads (default: one per idle core)")
    parser.add_argument("--out", type=Path, default=precompiled.FOLDER)
    parser.add_argument("--check", action="store_true", help="only say whether the shipped set is current")
    args = parser.parse_args(argv)
    names = args.modules or warmup.all_modules()
    try:
        if args.check:
            problems = stale(names, precompiled.manifest(args.out))
            print("\n".join(problems) or f"current: {len(names)} modules")
            return 1 if problems else 0
        build(names, list(dict.fromkeys(args.archs)), args.out.resolve(), args.workers)
        return 0
    finally:
        shutil.rmtree(CACHE, ignore_errors=True)


if __name__ == "__main__":
    sys.exit(main())
