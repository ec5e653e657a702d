"""Micropolar turbulence (Bender et al. 2017/2018), the baseline both papers compare against."""

import warp as wp

from warpsph.kernels.micropolar import micropolar_step

from . import Model, register


@register("micropolar")
class MicropolarModel(Model):
    """Angular velocity omega per particle, coupled to v through nu_t. One launch and a copy."""

    needs_vorticity = True
    scratch_columns = 3

    def __init__(self, sim, params):
        super().__init__(sim, params)
        self.omega = sim.per_particle(self.name, wp.vec3)
        self.omega_next = sim.scratch(wp.vec3, 0)

    def step(self, sim):
        p, f = self.params, sim.fluid
        sim.launch(micropolar_step, sim.num_fluid,
                   [f.x, f.density, sim.neighbours.lists, sim.vorticity_field.vorticity, self.omega,
                    sim.particle_mass, p.transfer_coefficient, p.inverse_inertia, p.viscosity_omega,
                    sim.support_radius, sim.dt, f.acceleration, self.omega_next])
        wp.copy(self.omega, self.omega_next)

    def reorder(self, sim, order):
        sim.permute(self.omega, order)

    def fields(self):
        return {"angular_velocity": self.omega}

    def state(self):
        return {"micropolar_angular_velocity": self.omega}

    def rotational_energy(self, sim):
        """sum_i 1/2 m I |omega_i|^2 with micro-inertia I = 1 / Theta^-1 (host read)."""
        w = sim.host(self.omega)
        return 0.5 * sim.particle_mass / self.params.inverse_inertia * float((w.astype("f8") ** 2).sum())
