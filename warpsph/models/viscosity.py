"""Artificial viscosity (VR paper eq 4), the fluid's own non-pressure force."""

from warpsph.kernels.viscosity import add_viscosity_acceleration

from . import Model, register


@register("viscosity")
class Viscosity(Model):
    """a_i += nu laplacian(v)_i; enabled whenever the scene's fluid viscosity is > 0."""

    def step(self, sim):
        f = sim.fluid
        sim.launch(add_viscosity_acceleration, sim.num_fluid,
                   [f.x, f.v, f.density, sim.neighbours.lists, sim.particle_mass,
                    sim.scene.fluid.viscosity, sim.support_radius, f.acceleration])
