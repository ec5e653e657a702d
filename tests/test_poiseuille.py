"""A channel's flow between two walls (``warpsph validate poiseuille``): the walls' friction against no slip."""

import numpy as np
import pytest

from warpsph.validation.poiseuille import NU, W, fit_profile, no_slip_mean, poiseuille


def test_the_fit_finds_the_planes_of_a_known_parabola():
    """Speeds on u = f / (2 nu) (y + 0.01) (W + 0.01 - y): no-slip planes at -0.01 and W + 0.01, the curvature f / nu."""
    y = np.linspace(0.005, W - 0.005, 40)
    u = 1.0 / (2 * NU) * (y + 0.01) * (W + 0.01 - y)
    y0, y1, curvature = fit_profile(y, u)
    assert (y0, y1, curvature) == pytest.approx((-0.01, W + 0.01, 1.0), abs=1e-9)
    assert no_slip_mean() == pytest.approx(1.0 * W * W / (12 * NU))


def test_twice_the_viscosity_against_the_walls_holds_the_flow_at_them(device):
    """10 across (CPU, 10b4e5b): with boundary viscosity 2 nu the parabola's no-slip planes lie 0.063 spacings beyond
    the walls and the mean flow is 1.042 of Poiseuille's (the bulk's curvature 0.89 of f / nu); with nu they lie
    0.61 spacings beyond (1.39x the mean): a partial slip."""
    r = poiseuille(10, device)
    r.pop("sim")
    assert abs(r["slip_spacings"]) < 0.095
    assert abs(r["mean_over_no_slip"] - 1.0) < 0.063
    assert abs(r["curvature_ratio"] - 1.0) < 0.165
    slipping = poiseuille(10, device, overrides={"fluid.boundary_viscosity": NU})
    slipping.pop("sim")
    assert 0.4 < slipping["slip_spacings"] < 0.92
