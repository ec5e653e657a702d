"""Artificial viscosity (VR paper eq 4), the fluid's own non-pressure force."""

import warp as wp

from warpsph.kernels.viscosity import add_viscosity_acceleration

from . import Model, register


@register("viscosity")
class Viscosity(Model):
    """a_i += nu laplacian(v)_i; enabled whenever the scene's fluid viscosity is > 0."""

    computes_vorticity = True  # fills sim.vorticity_field in the same pass when it exists

    def __init__(self, sim, params=None):
        super().__init__(sim, params)
        self._empty_vec3 = wp.empty(0, dtype=wp.vec3, device=sim.device)

    def step(self, sim):
        f, field = sim.fluid, sim.vorticity_field
        vorticity = field.vorticity if field is not None else self._empty_vec3
        sim.launch(add_viscosity_acceleration, sim.num_fluid,
                   [f.x, f.v, f.density, sim.neighbours.lists, sim.particle_mass, sim.scene.fluid.viscosity,
                    sim.support_radius, sim.boundary.samples, sim.scene.fluid.boundary_viscosity, sim.dt,
                    int(field is not None), f.acceleration, vorticity])
