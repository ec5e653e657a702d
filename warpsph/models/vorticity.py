"""The vorticity field shared by the turbulence models: computed once per step."""

import warp as wp

from warpsph.kernels.vorticity import compute_vorticity


class VorticityField:
    """curl v~ after the divergence solve (eq 6).

    Allocated only when a scene enables a model that reads it; every model of the step
    reads the same field, so it is never computed twice for one state."""

    def __init__(self, sim):
        self.vorticity = sim.per_particle("vorticity", wp.vec3)

    def update(self, sim):
        curl_of(sim, sim.fluid.v, self.vorticity)
        sim.exchange(self.vorticity)


def curl_of(sim, v, out):
    """out = the SPH curl (eq 6) of the per-particle field ``v`` over the current neighbour lists and
    densities (for diagnostics, tools and tests as well as the shared field)."""
    f = sim.fluid
    sim.launch(compute_vorticity, sim.num_fluid,
               [f.x, v, f.density, sim.neighbours.lists, sim.particle_mass, sim.support_radius, out])
    return out
