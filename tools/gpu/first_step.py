"""The time to a scene's first step (#43): `import warpsph`, Warp's start, the Simulation (its kernels compiled,
loaded or copied from warpsph's precompiled set) and one step, each timed; one JSON line on stdout.

    WARP_CACHE_PATH=$(mktemp -d) python tools/gpu/first_step.py scenes/dam_break.json --device cuda   # cold
    WARP_CACHE_PATH=$(mktemp -d) WARPSPH_PRECOMPILED=0 python tools/gpu/first_step.py ...           # cold, compiled

Run each cold case in a process of its own on an empty WARP_CACHE_PATH (the cache is what makes it cold).
"""

import time

t0 = time.perf_counter()
import argparse  # noqa: E402
import json  # noqa: E402
import os  # noqa: E402
from pathlib import Path  # noqa: E402

import warpsph  # noqa: E402

t_import = time.perf_counter()
import warp as wp  # noqa: E402

wp.init()
t_warp = time.perf_counter()
from warpsph import precompiled  # noqa: E402
from warpsph.simulation import Simulation  # noqa: E402

parser = argparse.ArgumentParser()
parser.add_argument("scene")
parser.add_argument("--device", default="cuda")
parser.add_argument("--scale", type=float, default=1.0)
args = parser.parse_args()
t_list = time.perf_counter()
cache = Path(wp.config.kernel_cache_dir)
before = {p for p in cache.rglob("*") if p.is_file()}
t1 = time.perf_counter()  # the listing (t_list to t1) is not counted
scene = warpsph.load_scene(args.scene, scale=args.scale)
t_scene = time.perf_counter()
sim = Simulation(scene, device=args.device)
t_sim = time.perf_counter()
sim.step()
wp.synchronize()
t_step = time.perf_counter()
after = {p for p in cache.rglob("*") if p.is_file()}
new = sorted(p.name for p in after - before)
device = wp.get_device(args.device)
print(json.dumps({
    "to_first_step_s": round(t_step - t0 - (t1 - t_list), 3), "import_warpsph_s": round(t_import - t0, 3),
    "warp_init_s": round(t_warp - t_import, 3), "imports_s": round(t_list - t_warp, 3), "scene_s": round(t_scene - t1, 3), "simulation_s": round(t_sim - t_scene, 3),
    "step_s": round(t_step - t_sim, 3), "particles": sim.num_fluid, "device": device.name, "arch": getattr(device, "arch", None),
    "warp": wp.config.version, "precompiled": precompiled.enabled(), "kernel_cache": str(cache),
    "new_files": {"modules_compiled (their .cu/.cpp)": sum(n.endswith((".cu", ".cpp")) for n in new),
                  "binaries": sum(n.endswith((".cubin", ".ptx", ".o")) for n in new), "total": len(new)},
    "commit": os.environ.get("WARPSPH_COMMIT", "")}))
