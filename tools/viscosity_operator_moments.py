"""The viscosity Laplacian of the VR paper's eq 4 (Koschier's form, kernels/viscosity.py) applied in numpy to
analytic divergence-free fields at the particles of the Taylor-Green box (periodic, L = 1, 6 spacings deep;
the cubic lattice and the validation's 40-step packing), projected on the exact Laplacian (1 = exact).
Developer diagnostic for issue #16's plateaus (docs/notes/solver.md).

    python tools/viscosity_operator_moments.py --resolutions 16 32 --out tools/results/viscosity_operator_moments_cpu.json
"""
import argparse
import json
import sys

import numpy as np
import warp as wp

wp.config.log_level = wp.LOG_WARNING
from warpsph.validation import taylor_green as tg  # noqa: E402

pi = np.pi


def grad_w(xij, r, H):
    """The cubic spline's gradient (kernels/sph_kernel.py) for offsets x_ij of length r, support H."""
    q = r / H
    l = 48.0 / pi / H**3
    g = np.where(q <= 0.5, l * q * (3 * q - 2), -l * (1 - q) ** 2)
    g = np.where((r > 1e-9 * H) & (r <= H), g, 0.0)
    return (g / np.maximum(r, 1e-12) / H)[:, None] * xij

FIELDS = {
    "Taylor-Green": (lambda x: np.stack([-np.cos(2*pi*x[:,0])*np.sin(2*pi*x[:,1]), np.sin(2*pi*x[:,0])*np.cos(2*pi*x[:,1]), 0*x[:,0]], 1), -8*pi**2),
    "shear along an axis, v_x(y)": (lambda x: np.stack([np.sin(2*pi*x[:,1]), 0*x[:,0], 0*x[:,0]], 1), -4*pi**2),
    "shear at 45 deg": (lambda x: np.stack([np.sin(2*pi*(x[:,0]+x[:,1])), -np.sin(2*pi*(x[:,0]+x[:,1])), 0*x[:,0]], 1), -8*pi**2),
}

def operator(x, v, V, H, period):
    """Eq 4 at every particle: 2(d+2) sum_j V (v_ij . x_ij) / (r^2 + 0.01 H^2) grad W_ij, minimum image."""
    out = np.zeros_like(v)
    for s in range(0, len(x), 256):
        xij = x[s:s+256, None, :] - x[None, :, :]
        xij -= period * np.round(xij / period)
        r = np.linalg.norm(xij, axis=2)
        m = (r > 0) & (r < H)
        ii, jj = np.nonzero(m)
        xs = xij[ii, jj]; rs = r[ii, jj]
        vij = v[s + ii] - v[jj]
        term = (10.0 * V * (vij * xs).sum(1) / (rs**2 + 0.01 * H**2))[:, None] * grad_w(xs, rs, H)
        np.add.at(out, s + ii, term)
    return out

def factors(res):
    dx = 1.0 / res
    H = 2 * dx
    period = np.array([1.0, 1.0, 6 * dx])
    lattice = (np.stack(np.meshgrid(np.arange(res), np.arange(res), np.arange(6), indexing="ij"), -1).reshape(-1, 3) + 0.5) * dx
    sim, _ = tg.build([], res, tg.NU, tg.T_END, "cpu", 4, pack_steps=tg.PACK_STEPS)
    packed = sim.host(sim.fluid.x).astype(np.float64)
    rows = []
    for name, x in (("lattice", lattice), ("packed", packed)):
        for field, (f, lap) in FIELDS.items():
            v = f(x)
            L = operator(x, v, dx**3, H, period)
            exact = lap * v
            rows.append({"resolution": res, "arrangement": name, "field": field,
                         "factor": round(float((L * exact).sum() / (exact * exact).sum()), 4)})
            print(rows[-1], flush=True)
    return rows


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--resolutions", type=int, nargs="+", default=[16, 32])
    ap.add_argument("--out")
    args = ap.parse_args(argv)
    rows = [r for res in args.resolutions for r in factors(res)]
    if args.out:
        with open(args.out, "w") as f:
            json.dump({"what": "eq 4's Laplacian / the exact one, projected (1 = exact); cubic spline, support 2 spacings",
                       "device": "cpu (numpy)", "warp": wp.__version__, "rows": rows}, f, indent=1)


if __name__ == "__main__":
    sys.exit(main())
