"""Cubic spline kernel and neighbour search against analytic and brute-force references."""

import numpy as np
import warp as wp

from warpsph.kernels.sph_kernel import cubic_kernel, cubic_kernel_gradient
from conftest import make_sim, tank_scene


@wp.kernel
def _evaluate(offsets: wp.array(dtype=wp.vec3), H: float, w: wp.array(dtype=float), g: wp.array(dtype=wp.vec3)):
    i = wp.tid()
    w[i] = cubic_kernel(wp.length(offsets[i]), H)
    g[i] = cubic_kernel_gradient(offsets[i], H)


def _kernel_values(offsets, H, device):
    o = wp.array(offsets.astype(np.float32), dtype=wp.vec3, device=device)
    w = wp.zeros(len(offsets), dtype=float, device=device)
    g = wp.zeros(len(offsets), dtype=wp.vec3, device=device)
    wp.launch(_evaluate, dim=len(offsets), inputs=[o, H, w, g], device=device)
    return w.numpy(), g.numpy()


def test_lattice_sum_of_W_is_one_over_volume(device):
    d = 0.1  # spacing 2r, support 4r = 2d
    k = np.arange(-3, 4)
    offsets = np.stack(np.meshgrid(k, k, k), -1).reshape(-1, 3) * d
    w, _ = _kernel_values(offsets, 2 * d, device)
    assert abs(w.sum() * d**3 - 1.0) < 1e-3
    # and the kernel vanishes at and beyond the support radius
    far, _ = _kernel_values(np.array([[2 * d, 0, 0], [0, 2.5 * d, 0]]), 2 * d, device)
    assert np.all(far == 0.0)


def test_kernel_integrates_to_one(device):
    H = 1.0
    h = H / 20
    k = np.arange(-20, 21) * h
    offsets = np.stack(np.meshgrid(k, k, k), -1).reshape(-1, 3)
    w, _ = _kernel_values(offsets, H, device)
    assert abs(w.sum() * h**3 - 1.0) < 1e-3


def test_gradient_is_antisymmetric_and_matches_finite_differences(device):
    rng = np.random.default_rng(1)
    H = 0.4
    x = rng.uniform(-0.3, 0.3, (200, 3))
    _, g_plus = _kernel_values(x, H, device)
    _, g_minus = _kernel_values(-x, H, device)
    np.testing.assert_allclose(g_plus, -g_minus, atol=1e-6 * np.abs(g_plus).max())
    eps = 1e-3
    for axis in range(3):
        e = np.zeros(3)
        e[axis] = eps
        wp_, _ = _kernel_values(x + e, H, device)
        wm, _ = _kernel_values(x - e, H, device)
        fd = (wp_.astype(np.float64) - wm) / (2 * eps)
        np.testing.assert_allclose(g_plus[:, axis], fd, atol=2e-3 * np.abs(g_plus).max())


def _assert_lists_match_brute_force(sim, x):
    sim.fluid.x.assign(x.astype(np.float32))
    sim.neighbours.update(sim.fluid.x)
    H = sim.support_radius
    nb = sim.neighbours
    off, idx = nb.fluid_offsets.numpy(), nb.fluid_neighbours.numpy()
    boff, bidx = nb.boundary_offsets.numpy(), nb.boundary_neighbours.numpy()
    bx = sim.boundary.x.numpy()
    for i in range(0, sim.num_fluid, 7):
        d = np.linalg.norm(x - x[i], axis=1)
        expected = set(np.nonzero((d < H) & (np.arange(len(x)) != i))[0])
        assert set(idx[off[i]:off[i + 1]]) == expected
        db = np.linalg.norm(bx - x[i], axis=1)
        assert set(bidx[boff[i]:boff[i + 1]]) == set(np.nonzero(db < H)[0])


def test_neighbour_lists_match_brute_force(device):
    sim = make_sim(tank_scene(radius=0.03), device=device)
    rng = np.random.default_rng(0)
    _assert_lists_match_brute_force(sim, sim.fluid.x.numpy() + rng.normal(0, 0.01, (sim.num_fluid, 3)))


def test_neighbours_outside_domain_and_in_capped_coarse_cells(device, monkeypatch):
    """Points beyond the domain share its border cells (clamped), and a cell table held to its
    cap gets cells larger than the support radius: both still give every neighbour."""
    import warpsph.neighbours as wn

    sim = make_sim(tank_scene(radius=0.03), device=device)
    x = sim.fluid.x.numpy().astype(np.float64)
    x[::5] += np.array([0.0, 0.45, 0.0])  # a fifth of the particles above the lid, in clusters
    x[1::9] -= np.array([0.3, 0.0, 0.0])  # some beyond the x = 0 wall
    _assert_lists_match_brute_force(sim, x)
    monkeypatch.setattr(wn, "MIN_CELLS", 8)
    monkeypatch.setattr(wn, "CELLS_PER_POINT", 0)
    coarse = make_sim(tank_scene(radius=0.03), device=device)
    assert coarse.neighbours.cell_size > 1.5 * coarse.support_radius
    _assert_lists_match_brute_force(coarse, x)
