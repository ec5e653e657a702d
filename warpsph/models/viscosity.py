"""Artificial viscosity (VR paper eq 4), the fluid's own non-pressure force."""

import warp as wp

from warpsph.kernels.viscosity import add_viscosity_acceleration

from . import Model, register


@register("viscosity")
class Viscosity(Model):
    """a_i += nu laplacian(v)_i; enabled whenever the scene's fluid viscosity is > 0."""

    computes_vorticity = True  # fills the shared vorticity field (ctx.vorticity) in the same pass when it exists

    def __init__(self, ctx, params=None):
        super().__init__(ctx, params)
        self._empty_vec3 = wp.empty(0, dtype=wp.vec3, device=ctx.device)

    def step(self, ctx):
        f, vorticity = ctx.fluid, ctx.vorticity
        with_vorticity = vorticity is not None
        ctx.launch(add_viscosity_acceleration, ctx.num_fluid,
                   [f.x, f.v, f.density, ctx.neighbour_lists, ctx.particle_mass, ctx.scene.fluid.viscosity,
                    ctx.support_radius, ctx.boundary_samples, ctx.scene.fluid.boundary_viscosity, ctx.dt,
                    int(with_vorticity), f.acceleration, vorticity if with_vorticity else self._empty_vec3])
        if with_vorticity:
            ctx.exchange(vorticity)
