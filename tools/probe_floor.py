"""The floor of one neighbour pass: a cubic-spline density pass over N particles.

    python tools/probe_floor.py --device cuda --sizes 1e6 8e6 --out tools/results/probe_floor_h100.json

For each size, a jittered lattice of spacing 2r (support 4r, ~33 neighbours) is timed:
- ``grid_sorted_ms`` / ``grid_random_ms``: the density pass querying ``wp.HashGrid`` on the fly, with the
  particles in cell order and in random order (the reference figures: 1.03 / 3.74 ms at 1M on an H100);
- ``list_ms``: the same pass reading a CSR neighbour list (what warpsph's solver passes do);
- ``grid_build_ms`` and ``list_build_ms`` (count + scan + fill).
A DFSPH step costs k neighbour passes; its floor is k x the pass floor.
"""

import argparse
import json
import time
from pathlib import Path

import numpy as np
import warp as wp

wp.set_module_options({"enable_backward": False})

from warpsph.kernels import neighbours as nk  # noqa: E402
from warpsph.kernels.sph_kernel import cubic_kernel  # noqa: E402


@wp.kernel
def density_grid(grid: wp.uint64, x: wp.array(dtype=wp.vec3), H: float, volume: float, rho: wp.array(dtype=float)):
    i = wp.tid()
    xi = x[i]
    s = float(0.0)
    query = wp.hash_grid_query(grid, xi, H)
    j = int(0)
    while wp.hash_grid_query_next(query, j):
        s += cubic_kernel(wp.length(xi - x[j]), H)
    rho[i] = volume * s


@wp.kernel
def density_list(x: wp.array(dtype=wp.vec3), offsets: wp.array(dtype=wp.int32), index: wp.array(dtype=wp.int32),
                 H: float, volume: float, rho: wp.array(dtype=float)):
    i = wp.tid()
    xi = x[i]
    s = cubic_kernel(0.0, H)
    for k in range(offsets[i], offsets[i + 1]):
        s += cubic_kernel(wp.length(xi - x[index[k]]), H)
    rho[i] = volume * s


def timed(fn, device, repeats=20):
    fn()
    wp.synchronize_device(device)
    samples = []
    for _ in range(repeats):
        start = time.perf_counter()
        fn()
        wp.synchronize_device(device)
        samples.append(1e3 * (time.perf_counter() - start))
    return float(np.median(samples))


def probe(n, device, seed=0):
    r = 0.005
    d, H = 2 * r, 4 * r
    side = int(round(n ** (1 / 3)))
    g = np.arange(side) * d
    pts = np.stack(np.meshgrid(g, g, g, indexing="ij"), -1).reshape(-1, 3)
    pts += np.random.default_rng(seed).uniform(-0.1 * d, 0.1 * d, pts.shape)
    n = len(pts)
    grid = wp.HashGrid(128, 128, 128, device=device)
    result = {"particles": n}
    rho = wp.zeros(n, dtype=float, device=device)
    for order in ("sorted", "random"):
        p = pts if order == "sorted" else pts[np.random.default_rng(seed + 1).permutation(n)]
        x = wp.array(p.astype(np.float32), dtype=wp.vec3, device=device)
        grid.build(x, H)
        result[f"grid_{order}_ms"] = timed(lambda: wp.launch(density_grid, n, [grid.id, x, H, d**3, rho], device=device), device)
        if order == "sorted":
            result["grid_build_ms"] = timed(lambda: grid.build(x, H), device)
            counts = wp.zeros(n + 1, dtype=wp.int32, device=device)
            offsets = wp.zeros(n + 1, dtype=wp.int32, device=device)
            box = [wp.vec3(0.0), wp.vec3(0.0)]  # not periodic
            no_list = wp.empty(0, dtype=wp.int32, device=device)

            def build_list():
                wp.launch(nk.find_neighbours, n, [grid.id, x, x, H, 0, *box, 0, counts, no_list], device=device)
                wp.utils.array_scan(counts, offsets, inclusive=False)
                return offsets

            build_list()
            total = int(offsets.numpy()[n])
            index = wp.zeros(total, dtype=wp.int32, device=device)

            def fill():
                build_list()
                wp.launch(nk.find_neighbours, n, [grid.id, x, x, H, 0, *box, 1, offsets, index], device=device)

            result["list_build_ms"] = timed(fill, device)
            result["mean_neighbours"] = total / n
            result["list_ms"] = timed(lambda: wp.launch(density_list, n, [x, offsets, index, H, d**3, rho], device=device), device)
    return result


def main():
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--device", default="cuda")
    parser.add_argument("--sizes", type=float, nargs="+", default=[1e6])
    parser.add_argument("--out")
    args = parser.parse_args()
    wp.config.log_level = wp.LOG_WARNING
    wp.init()
    device = wp.get_device(args.device)
    from warpsph.validation.cases import commit_info

    report = {"device": device.name if device.is_cuda else "cpu", "warp": wp.__version__, **commit_info(),
              "probes": [probe(int(n), device) for n in args.sizes]}
    text = json.dumps(report, indent=2)
    print(text)
    if args.out:
        Path(args.out).write_text(text + "\n")


if __name__ == "__main__":
    main()
