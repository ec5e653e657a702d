"""Micropolar turbulence (Bender et al. 2017/2018), the baseline both papers compare against."""

import warp as wp

from warpsph.kernels.micropolar import micropolar_step
from warpsph.keys import MAX_MODEL_VISCOSITY, key, schema

from .base import Model, register


@schema
class Micropolar:
    """Micropolar's scene parameters (Bender et al. 2017/2018; SPlisHSPlasH's defaults: nu_t 0.1,
    Theta^-1 0.5, zeta 0.1; the stress matrix ran nu_t up to 0.4).

    Example:

    ```python
    import warpsph

    scene = warpsph.scene_from_dict({
        "particle_radius": 0.02, "domain": {"min": [0, 0, 0], "max": [0.4, 0.4, 0.2]},
        "fluid_blocks": [{"start": [0, 0, 0], "end": [0.2, 0.2, 0.2]}],
        "models": [{"type": "micropolar", "transfer_coefficient": 0.1}]})
    warpsph.Simulation(scene).run(frames=2)
    ```
    """

    transfer_coefficient: float = key(0.05, doc="nu_t, the coupling of v and omega", ge=0.0, le=1.0)
    inverse_inertia: float = key(0.5, doc="Theta^-1, the inverse micro-inertia", gt=0.0, le=10.0)
    viscosity_omega: float = key(0.1, doc="zeta, the viscosity of omega", unit="m^2/s", ge=0.0, le=MAX_MODEL_VISCOSITY)


@register("micropolar")
class MicropolarModel(Model):
    """Angular velocity omega per particle, coupled to v through nu_t. One launch and a copy.

    Example:

    ```python
    import warpsph

    scene = warpsph.scene_from_dict({
        "particle_radius": 0.02, "domain": {"min": [0, 0, 0], "max": [0.4, 0.4, 0.2]},
        "fluid_blocks": [{"start": [0, 0, 0], "end": [0.2, 0.2, 0.2]}],
        "models": [{"type": "micropolar"}]})
    sim = warpsph.Simulation(scene)
    sim.run(frames=2)
    omega = sim.field_values("angular_velocity")  # (num_fluid, 3) [rad/s]
    omega_device, inertia = sim.turbulence_models[0].spin()
    ```
    """

    Parameters = Micropolar
    bytes_per_particle = 12  # one vec3 per particle
    output_fields = {"angular_velocity": 12}
    needs_vorticity = True
    scratch_columns = 3

    def __init__(self, ctx, params):
        super().__init__(ctx, params)
        self.omega = ctx.per_particle(self.name, wp.vec3)
        self.omega_next = ctx.scratch(wp.vec3, 0)

    def step(self, ctx):
        p, f = self.params, ctx.fluid
        ctx.launch(micropolar_step, ctx.num_fluid,
                   [f.x, f.density, ctx.neighbour_lists, ctx.vorticity, self.omega,
                    ctx.particle_mass, p.transfer_coefficient, p.inverse_inertia, p.viscosity_omega,
                    ctx.support_radius, ctx.dt, f.acceleration, self.omega_next])
        wp.copy(self.omega, self.omega_next)

    def reorder(self, ctx, order):
        ctx.permute(self.omega, order)

    def fields(self):
        return {"angular_velocity": self.omega}

    def state(self):
        return {"micropolar_angular_velocity": self.omega}

    def spin(self):
        """omega with micro-inertia I = 1 / Theta^-1 per unit mass."""
        return self.omega, 1.0 / self.params.inverse_inertia
