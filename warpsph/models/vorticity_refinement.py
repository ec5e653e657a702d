"""Vorticity refinement (VR paper, Algorithm 2) as a non-pressure model."""

import warp as wp

from warpsph.kernels.vorticity_refinement import (
    apply_vorticity_refinement,
    compute_stream_function_and_target,
    compute_vorticity_loss,
)

from . import Model, register


@register("vorticity_refinement")
class VorticityRefinementModel(Model):
    """Per step, after the divergence solve gave v~ and its vorticity zeta~ (shared field):
    d zeta = zeta^{n+1} - zeta~ (eq 12), psi (eq 15), v += alpha curl psi (eqs 16-17), and the
    next ideal zeta^{n+1} from the vorticity equation (eqs 9-11). Three launches."""

    needs_vorticity = True

    def __init__(self, sim, params):
        super().__init__(sim, params)
        n = sim.num_fluid
        self.target = sim.zeros(self.name, n, dtype=wp.vec3)  # zeta^{n+1}, carried to the next step
        self.loss = sim.zeros(self.name, n, dtype=wp.vec3)  # d zeta
        self.stream_function = sim.zeros(self.name, n, dtype=wp.vec3)  # psi
        self.viscosity = sim.scene.fluid.viscosity if params.viscosity is None else params.viscosity
        self.has_target = 0

    def step(self, sim):
        f, n, field = sim.fluid, sim.num_fluid, sim.vorticity_field
        alpha = self.params.alpha
        sim.launch(compute_vorticity_loss, n, [self.target, field.vorticity, self.has_target, self.loss])
        sim.launch(compute_stream_function_and_target, n,
                   [f.x, f.v, f.density, sim.neighbours.lists, field.vorticity, self.loss,
                    sim.particle_mass, alpha, self.viscosity, sim.support_radius, sim.dt,
                    self.stream_function, self.target])
        sim.launch(apply_vorticity_refinement, n,
                   [f.x, f.density, sim.neighbours.lists, self.stream_function, sim.particle_mass, alpha,
                    sim.support_radius, f.v])
        self.has_target = 1

    def reorder(self, sim, order):
        sim.permute(self.target, order)

    def state(self):
        return {"vr_target_vorticity": self.target}
