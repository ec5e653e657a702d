"""Rankine vortex feedback (Rankine paper, Algorithm 1) as a non-pressure model."""

from typing import Optional

import warp as wp

from warpsph.kernels.rankine import apply_rankine_feedback, compute_vorticity_change
from warpsph.keys import MAX_MODEL_VISCOSITY, key, schema

from .base import NO_HISTORY, Model, register


@schema
class RankineFeedback:
    """Rankine feedback's scene parameters (Rankine paper, Algorithm 1): r_c = beta sqrt(4 1.25643 nu dt).

    Example:

    ```python
    import warpsph

    scene = warpsph.scene_from_dict({
        "particle_radius": 0.02, "domain": {"min": [0, 0, 0], "max": [0.4, 0.4, 0.2]},
        "fluid_blocks": [{"start": [0, 0, 0], "end": [0.2, 0.2, 0.2]}],
        "models": [{"type": "rankine", "beta": 0.6}]})
    warpsph.Simulation(scene).run(frames=2)
    ```
    """

    beta: float = key(1.0, doc="intensity beta of eq 11 (Fig 7's sweep)", ge=0.0, le=1.0)
    viscosity: Optional[float] = key(None, doc="nu of eq 11; null: the fluid's", unit="m^2/s",
                                     ge=0.0, le=MAX_MODEL_VISCOSITY)


@register("rankine")
class RankineModel(Model):
    """Per step: omega^n = curl v (shared field, fluid only), d omega = omega^n - omega^{n-1},
    v += sum_j r_c^2/(2r) d omega_j x e_theta, before advection. Two launches.

    beta is the paper's intensity knob (eq 11: r_c = beta r_c^max, 0 <= beta <= 1, Fig 7's sweep). warpsph
    bounds the largest core, r_c^max = min(sqrt(4 1.25643 nu dt), 0.7 r) (``kernels.rankine.core_radius``:
    the paper keeps the core inside a particle, and above about 0.9 r the feedback ran away), and applies beta
    after that bound, so the feedback (eq 15, proportional to r_c^2) grows as beta^2 over the whole range.
    Bounding beta r_c^max instead made every beta above 0.7 r / r_c^max (about 0.44 at the viscous time-step
    limit) the same model.

    Example:

    ```python
    import warpsph

    scene = warpsph.scene_from_dict({
        "particle_radius": 0.02, "domain": {"min": [0, 0, 0], "max": [0.4, 0.4, 0.2]},
        "fluid_blocks": [{"start": [0, 0, 0], "end": [0.2, 0.2, 0.2]}],
        "models": [{"type": "rankine"}]})
    sim = warpsph.Simulation(scene)
    sim.run(frames=2)
    rankine = sim.turbulence_models[0]  # this class; sim.field_values("vorticity"): omega^n
    ```
    """

    Parameters = RankineFeedback
    bytes_per_particle = 12  # one vec3 per particle
    flag_names = ("has_previous",)
    needs_vorticity = True
    scratch_columns = 3

    def __init__(self, ctx, params):
        super().__init__(ctx, params)
        self.previous = ctx.per_particle(self.name, wp.vec3)  # omega^{n-1}
        self.change = ctx.scratch(wp.vec3, 0)  # d omega (within the step)
        self.viscosity = ctx.scene.fluid.viscosity if params.viscosity is None else params.viscosity
        self.has_previous = 0

    def step(self, ctx):
        n = ctx.num_fluid
        ctx.launch(compute_vorticity_change, n,
                   [ctx.vorticity, self.has_previous, self.previous, self.change])
        ctx.exchange(self.change)
        ctx.launch(apply_rankine_feedback, n,
                   [ctx.fluid.x, ctx.neighbour_lists, self.change, self.params.beta, self.viscosity,
                    ctx.particle_radius, ctx.dt,
                    ctx.fluid.v])
        self.has_previous = 1

    def emitted(self, ctx, first, count):
        """An emitted particle has no omega^{n-1}: with the zero it was given, its whole vorticity would be
        fed back as change on its first step (3-15x the jet's d omega in tests/test_inflow.py's jet)."""
        self.previous[first: first + count].fill_(NO_HISTORY)

    def reorder(self, ctx, order):
        ctx.permute(self.previous, order)

    def state(self):
        return {"rankine_previous_vorticity": self.previous}
