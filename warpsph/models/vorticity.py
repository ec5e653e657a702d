"""The vorticity field shared by the turbulence models: computed once per step."""

import warp as wp

from warpsph.kernels.vorticity import compute_vorticity


class VorticityField:
    """curl v~ after the divergence solve (eq 6), and grad v~ (eq 8) when a model needs it.

    Allocated only when a scene enables a model that reads it; every model of the step
    reads the same field, so it is never computed twice for one state."""

    def __init__(self, sim, with_gradient: bool):
        n = sim.num_fluid
        self.vorticity = sim.zeros("vorticity", n, dtype=wp.vec3)
        self.gradient = sim.zeros("vorticity", n, dtype=wp.mat33) if with_gradient else None
        self._no_gradient = wp.empty(0, dtype=wp.mat33, device=sim.device)

    def update(self, sim):
        f = sim.fluid
        with_gradient = self.gradient is not None
        sim.launch(compute_vorticity, sim.num_fluid,
                   [f.x, f.v, f.density, sim.neighbours.lists, sim.particle_mass, sim.support_radius, int(with_gradient),
                    self.vorticity, self.gradient if with_gradient else self._no_gradient])
