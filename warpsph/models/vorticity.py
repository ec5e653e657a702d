"""The vorticity field shared by the turbulence models: computed once per step."""

import warp as wp

from warpsph.kernels.vorticity import compute_vorticity, compute_vorticity_and_gradient


class VorticityField:
    """curl v~ after the divergence solve (eq 6), and grad v~ (eq 8) when a model needs it.

    Allocated only when a scene enables a model that reads it; every model of the step
    reads the same field, so it is never computed twice for one state."""

    def __init__(self, sim, with_gradient: bool):
        n = sim.num_fluid
        self.vorticity = sim.zeros("vorticity", n, dtype=wp.vec3)
        self.gradient = sim.zeros("vorticity", n, dtype=wp.mat33) if with_gradient else None

    def update(self, sim):
        f = sim.fluid
        common = [f.x, f.v, f.density, sim.neighbours.lists, sim.particle_mass, sim.support_radius, self.vorticity]
        if self.gradient is None:
            sim.launch(compute_vorticity, sim.num_fluid, common)
        else:
            sim.launch(compute_vorticity_and_gradient, sim.num_fluid, common + [self.gradient])
