"""Vorticity refinement (VR paper, Algorithm 2) as a non-pressure model."""

from typing import Optional

import warp as wp

from warpsph.kernels.vorticity_refinement import (
    apply_vorticity_refinement,
    compute_stream_function,
    compute_target_vorticity,
    compute_vorticity_loss,
)
from warpsph.keys import MAX_MODEL_VISCOSITY, key, schema

from .base import NO_HISTORY, Model, register


@schema
class VorticityRefinement:
    """Vorticity refinement's scene parameters (VR paper, Algorithm 2): v <- v~ + alpha dv (eq 17).

    Example:

    ```python
    import warpsph

    scene = warpsph.scene_from_dict({
        "particle_radius": 0.02, "domain": {"min": [0, 0, 0], "max": [0.4, 0.4, 0.2]},
        "fluid_blocks": [{"start": [0, 0, 0], "end": [0.2, 0.2, 0.2]}],
        "models": [{"type": "vorticity_refinement", "alpha": 0.5}]})
    warpsph.Simulation(scene).run(frames=2)
    ```
    """

    alpha: float = key(1.0, doc="refinement strength alpha of eq 17 (the VR paper uses 0 to 1.3; every alpha in "
                                "[0, 2] ran stable in the stress matrix)", ge=0.0, le=2.0)
    viscosity: Optional[float] = key(None, doc="nu_v of eq 10; null: the fluid's", unit="m^2/s",
                                     ge=0.0, le=MAX_MODEL_VISCOSITY)


@register("vorticity_refinement")
class VorticityRefinementModel(Model):
    """Per step, after the divergence solve gave v~ and its vorticity zeta~ (shared field):
    V d zeta = V (zeta^{n+1} - zeta~) (eq 12) over the target, psi (eq 15), v += alpha curl psi (eqs 16-17); then
    zeta^n = curl v of the refined velocity and from it the next ideal zeta^{n+1} (eqs 9-11).
    Three neighbour passes; one scratch vector per particle (psi) besides the carried target.

    Example:

    ```python
    import warpsph

    scene = warpsph.scene_from_dict({
        "particle_radius": 0.02, "domain": {"min": [0, 0, 0], "max": [0.4, 0.4, 0.2]},
        "fluid_blocks": [{"start": [0, 0, 0], "end": [0.2, 0.2, 0.2]}],
        "models": [{"type": "vorticity_refinement"}]})
    sim = warpsph.Simulation(scene)
    sim.run(frames=2)
    vr = sim.turbulence_models[0]  # this class; sim.field_values("vorticity"): its zeta per particle
    ```
    """

    Parameters = VorticityRefinement
    bytes_per_particle = 12  # one vec3 per particle
    flag_names = ("has_target",)
    needs_vorticity = True
    scratch_columns = 3

    def __init__(self, ctx, params):
        super().__init__(ctx, params)
        self.target = ctx.per_particle(self.name, wp.vec3)  # zeta^{n+1}, carried to the next step
        self.stream_function = ctx.scratch(wp.vec3, 0)  # psi (within the step)
        self.viscosity = ctx.scene.fluid.viscosity if params.viscosity is None else params.viscosity
        self.has_target = 0

    def step(self, ctx):
        f, n, vorticity = ctx.fluid, ctx.num_fluid, ctx.vorticity
        nb, mass, H = ctx.neighbour_lists, ctx.particle_mass, ctx.support_radius
        ctx.launch(compute_vorticity_loss, n, [vorticity, f.density, mass, self.has_target, self.target])
        ctx.exchange(self.target)
        ctx.launch(compute_stream_function, n, [f.x, nb, self.target, H, self.stream_function])
        ctx.exchange(self.stream_function)
        ctx.launch(apply_vorticity_refinement, n,
                   [f.x, f.density, nb, self.stream_function, mass, self.params.alpha, H, f.v])
        ctx.exchange(f.v)
        ctx.launch(compute_target_vorticity, n,
                   [f.x, f.v, f.density, nb, vorticity, mass, self.viscosity, H, ctx.dt, self.target])
        self.has_target = 1

    def emitted(self, ctx, first, count):
        """An emitted particle has no target zeta^{n+1}: with the zero it was given, its first step would
        remove all of its vorticity (d zeta = 0 - curl v~)."""
        self.target[first: first + count].fill_(NO_HISTORY)

    def reorder(self, ctx, order):
        ctx.permute(self.target, order)

    def state(self):
        return {"vr_target_vorticity": self.target}
