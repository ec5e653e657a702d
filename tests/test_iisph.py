"""IISPH (solver.method "iisph"): its Jacobi step against SPlisHSPlasH's formulation, the hydrostatic tank, a
dam break with every model, convergence, allocations, checkpoints and the validate command."""

import json

import numpy as np
import pytest

from conftest import make_sim, tank_scene
from warpsph.solvers.dfsph import DFSPHSolver
from warpsph.solvers.iisph import IISPHSolver

IISPH = {"method": "iisph"}


def dam_scene(models=(), **solver):
    return tank_scene(radius=0.01, domain=(0.6, 0.4, 0.12), block=(0.2, 0.3, 0.12), models=list(models),
                      solver={**IISPH, **solver})


def _gradient(d, H):
    """Cubic spline gradient, numpy (kernels/sph_kernel.py)."""
    r = np.linalg.norm(d, axis=1)
    q = r / H
    lam = 48.0 / np.pi / H**3
    safe = np.where(r > 1e-9 * H, r, 1.0)
    scale = np.where(q <= 0.5, lam * q * (3 * q - 2), -lam * (1 - q) ** 2) / (H * safe)
    scale = np.where((r < 1e-9 * H) | (q > 1.0), 0.0, scale)
    return d * scale[:, None]


def test_one_jacobi_step_matches_splishsplash_formulation():
    """Coefficients and one relaxed Jacobi step against a numpy transcription of SPlisHSPlasH's two-pass
    TimeStepIISPH (d_ij p_j, then the row sum with d_jj p_j and d_jk p_k), less its boundary d_bi term in a_ii."""
    from warpsph.kernels.iisph import (MIN_DIAGONAL, compute_iisph_coefficients, compute_pressure_displacement,
                                       update_iisph_pressure)

    sim = make_sim(tank_scene(radius=0.025, domain=(0.3, 0.4, 0.3), block=(0.3, 0.25, 0.3), solver=IISPH))
    n, s = sim.num_fluid, sim.pressure_solver
    rng = np.random.default_rng(3)
    sim.fluid.v.assign((rng.normal(size=(n, 3)) * 0.2).astype(np.float32))
    previous = (rng.random(n) * 2000.0 / sim.rest_density).astype(np.float32)  # last step's p / rho0
    s.pressure.assign(previous)
    sim.dt.assign(np.array([0.002], np.float32))
    f, nb, bnd, V, H, rho0 = sim.fluid, sim.neighbours.lists, sim.boundary.samples, sim.fluid_volume, sim.support_radius, sim.rest_density
    sim.launch(compute_iisph_coefficients, n, [f.x, f.v, nb, bnd, f.density, V, rho0, H, sim.dt, 0.5, s.d_ii, s.a_ii,
                                               s.source, s.pressure, s.stiffness])
    sim.launch(compute_pressure_displacement, n, [f.x, nb, V, H, s.d_ii, s.pressure, s.stiffness, s.displacement])
    sim.launch(update_iisph_pressure, n, [f.x, nb, f.density, V, rho0, H, MIN_DIAGONAL / H**2, sim.dt, 0.5, s.d_ii,
                                          s.a_ii, s.source, s.displacement, s.pressure, s.stiffness, s.error])

    x, v = f.x.numpy().astype(np.float64), f.v.numpy().astype(np.float64)
    rho = f.density.numpy().astype(np.float64) / rho0
    xb, Vb = sim.boundary.x.numpy().astype(np.float64), sim.boundary.volume.numpy().astype(np.float64)
    fo, fl = nb.fluid_offsets.numpy(), nb.fluid.numpy()
    bo, bl = nb.boundary_offsets.numpy(), nb.boundary.numpy()
    fi = np.repeat(np.arange(n), np.diff(fo[: n + 1]))
    fj = fl[: fo[n]]
    bi = np.repeat(np.arange(n), np.diff(bo[: n + 1]))
    bj = bl[: bo[n]]
    gf = _gradient(x[fi] - x[fj], H)
    gb = _gradient(x[bi] - xb[bj], H)
    h = 0.002

    def per_i(values, index):
        out = np.zeros((n,) + values.shape[1:])
        np.add.at(out, index, values)
        return out

    dii = -(per_i(V * gf, fi) + per_i(Vb[bj, None] * gb, bi)) / rho[:, None] ** 2
    rho_adv = rho + h * (per_i(V * np.einsum("ij,ij->i", v[fi] - v[fj], gf), fi)
                         + per_i(Vb[bj] * np.einsum("ij,ij->i", v[bi], gb), bi))
    dji = (V / rho[fi] ** 2)[:, None] * gf
    aii = per_i(V * np.einsum("ij,ij->i", dii[fi] - dji, gf), fi) + per_i(Vb[bj] * np.einsum("ij,ij->i", dii[bi], gb), bi)
    last = 0.5 * previous.astype(np.float64)
    dij_pj = per_i(-(V / rho[fj] ** 2 * last[fj])[:, None] * gf, fi)
    row = per_i(V * np.einsum("ij,ij->i", dij_pj[fi] - dii[fj] * last[fj, None] - (dij_pj[fj] - dji * last[fi, None]), gf), fi) \
        + per_i(Vb[bj] * np.einsum("ij,ij->i", dij_pj[bi], gb), bi)
    b = 1.0 - rho_adv
    expected = np.maximum(0.5 * last + 0.5 * (b - h * h * row) / (aii * h * h), 0.0)

    np.testing.assert_allclose(s.a_ii.numpy()[:n], aii, rtol=1e-4)
    np.testing.assert_allclose(s.source.numpy()[:n], b, atol=1e-5)
    p = s.pressure.numpy()[:n]
    assert (expected > 0).sum() > n // 4 and (expected == 0).sum() > 0  # both branches of the clamp
    np.testing.assert_allclose(p, expected, rtol=1e-4, atol=1e-4 * expected.max())


@pytest.mark.slow
def test_hydrostatic_tank_with_iisph():
    """The validation tank (10 across, 1.5 s): mean density error <= 0.1 %, p at mid-depth within 5 % of rho g h."""
    from warpsph.validation.hydrostatic import hydrostatic

    r = hydrostatic(radius=0.02, device="cpu", overrides={"solver.method": "iisph"})
    assert abs(r["density_error_mean"]) <= 0.001
    assert abs(r["mid_depth_pressure_ratio"] - 1.0) < 0.05
    assert r["max_speed"] < 0.1


@pytest.mark.slow
@pytest.mark.parametrize("models", [[], [{"type": "vorticity_refinement"}], [{"type": "rankine"}],
                                    [{"type": "micropolar"}]], ids=["none", "vr", "rankine", "micropolar"])
def test_dam_break_with_each_model(models):
    sim = make_sim(dam_scene(models))
    sim.run(until_time=0.15)  # checks health after every step: raises InstabilityError
    rho = sim.densities() / sim.rest_density
    assert rho.max() < 1.05
    stats = sim.statistics()
    assert stats["divergence_iterations"] == 0.0 and 1.0 <= stats["density_iterations"] < sim.scene.solver.max_iterations
    assert np.linalg.norm(sim.velocities(), axis=1).max() < 3.0  # free fall from 0.3 m: 2.4 m/s


def test_iterations_reach_the_tolerance():
    sim = make_sim(dam_scene(density_max_error=0.005, min_iterations=0))
    for _ in range(30):
        sim.step()
        assert sim.check_health() is None
        _, error = sim.pressure_solver.last_errors()
        assert error <= 0.005 * 0.01
    totals = sim.pressure_solver.iteration_totals()
    assert totals[:2] == (0, 0) and totals[3] == 30 and totals[2] >= 30  # one iteration at least, every solve
    assert sim.pressure_solver.max_iteration_streak.numpy().max() == 0
    capped = make_sim(dam_scene(density_max_error=1e-6, max_iterations=3))
    for _ in range(3):
        capped.step()
    assert capped.pressure_solver.iteration_totals()[2] == 9  # the cap holds
    assert capped.pressure_solver.max_iteration_streak.numpy()[1] == 3  # and the health check sees it


def test_allocates_no_dfsph_arrays():
    iisph, dfsph = make_sim(dam_scene()), make_sim(dam_scene(method="dfsph"))
    assert isinstance(iisph.pressure_solver, IISPHSolver) and isinstance(dfsph.pressure_solver, DFSPHSolver)
    assert iisph.fluid.factor.shape[0] == 0 and dfsph.fluid.factor.shape[0] == dfsph.capacity
    assert iisph.allocations["fluid"] == dfsph.allocations["fluid"] - 4 * dfsph.capacity
    assert not any(k.startswith("solver/pressure_sum") for k in iisph.state_arrays())
    assert "solver/pressure" in iisph.state_arrays() and "solver/pressure" not in dfsph.state_arrays()
    for name in ("pressure_sum", "surface", "concentration_gradient"):
        assert not hasattr(iisph.pressure_solver, name)
    assert iisph.allocations["pressure"] < dfsph.allocations["pressure"]


def test_checkpoint_resume_is_bit_identical(tmp_path):
    from warpsph import load_scene
    from warpsph.io.checkpoint import load_checkpoint, save_checkpoint
    from warpsph.simulation import Simulation

    path = tmp_path / "scene.json"
    data = tank_scene(radius=0.03, domain=(0.6, 0.4, 0.2), block=(0.2, 0.3, 0.2), output={"fps": 50, "frames": 4},
                      solver={**IISPH, "sort_interval": 4})
    path.write_text(json.dumps(data))
    straight = Simulation(load_scene(path), device="cpu").run(frames=4)
    first = Simulation(load_scene(path), device="cpu").run(frames=2)
    save_checkpoint(first, tmp_path / "ckpt.h5")
    resumed = load_checkpoint(tmp_path / "ckpt.h5", device="cpu").run(frames=4)
    for name in ("x", "v"):
        assert np.array_equal(getattr(resumed.fluid, name).numpy(), getattr(straight.fluid, name).numpy()), name
    assert np.array_equal(resumed.pressure_solver.pressure.numpy(), straight.pressure_solver.pressure.numpy())
    # a checkpoint of an earlier version holds every solver's keys in its scene, DFSPH's too, and not IISPH's own
    # relaxation: it resumes all the same, and the scene file is still its scene
    import h5py

    with h5py.File(tmp_path / "ckpt.h5", "r+") as f:
        stored = json.loads(f.attrs["scene"])
        assert stored["solver"].pop("relaxation") == 0.5 and "shifting" not in stored["solver"]
        stored["solver"].update(divergence_solver=True, divergence_max_error=0.1, divergence_min_iterations=1,
                                divergence_max_iterations=100, shifting=2.0)
        f.attrs["scene"] = json.dumps(stored, sort_keys=True)
    again = load_checkpoint(tmp_path / "ckpt.h5", scene=load_scene(path), device="cpu").run(frames=4)
    assert np.array_equal(again.fluid.x.numpy(), straight.fluid.x.numpy())


def test_validate_takes_the_solver(tmp_path):
    from warpsph.cli import main

    out = tmp_path / "front.json"
    assert main(["validate", "dam-front", "--resolutions", "4", "--solver", "iisph", "--device", "cpu",
                 "--json", str(out)]) == 0
    report = json.loads(out.read_text())
    assert report["solver"] == {"method": "iisph"} and report["rows"][0]["error_pct"] is not None
