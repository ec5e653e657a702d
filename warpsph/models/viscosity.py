"""Viscosity, the fluid's own non-pressure force: the artificial viscosity of the VR paper (eq 4) on the free surface
and its band, and the corrected operator of kernels/viscosity.py elsewhere."""

import warp as wp

from warpsph.kernels.integration import advance_substep, count_down, start_substeps
from warpsph.kernels.particles import SymmetricMatrix
from warpsph.kernels.viscosity import (
    add_corrected_viscosity_acceleration,
    add_viscosity_acceleration,
    compute_strain_rate,
)

from .base import Model, register


@register("viscosity")
class Viscosity(Model):
    """a_i += nu laplacian(v)_i; enabled whenever the scene's fluid viscosity is > 0.

    Away from the free surface and its band (``ctx.surface_flags``) the Laplacian is the corrected one
    (:data:`add_corrected_viscosity_acceleration`), which takes a strain-rate pass and six floats a particle;
    eq 4 on the surface and its band, with IISPH (no surface flags) and in a periodic box. Lamb-Oseen on the H200 at
    64 / 128 / 256 across: 0.97 / 0.69 / 0.39 % with it, 1.90 / 1.52 / 1.12 % with eq 4 (peak vorticity 2-4 %
    high; docs/notes/solver.md). In the periodic box the corrected operator did not fall from 128 to 256 across
    (Taylor-Green 0.33 / 0.34 %, eq 4 0.33 / 0.26 %).

    Example:

    ```python
    import warpsph

    scene = warpsph.scene_from_dict({
        "particle_radius": 0.02, "domain": {"min": [0, 0, 0], "max": [0.4, 0.4, 0.2]},
        "fluid_blocks": [{"start": [0, 0, 0], "end": [0.2, 0.2, 0.2]}],
        "fluid": {"viscosity": 0.01}})
    warpsph.Simulation(scene).run(frames=2)  # viscosity 0: no viscosity kernels
    ```
    """

    computes_vorticity = True  # fills the shared vorticity field (ctx.vorticity) in the same pass when it exists
    corrected_bytes_per_particle = 24  # the strain rate, where the operator is the corrected one

    @staticmethod
    def takes_corrected_operator(scene, detects_free_surface):
        """Whether ``scene`` runs the corrected operator away from the free surface: with a pressure solver that
        detects the surface (``detects_free_surface``: DFSPH; IISPH does not), a viscosity, and walls (the periodic box keeps eq 4: there the
        corrected operator did not fall from 128 to 256 across, Taylor-Green 0.33 / 0.34 % against eq 4's 0.33 /
        0.26 %)."""
        return (detects_free_surface and scene.fluid.viscosity > 0.0
                and len(scene.domain.periodic) < 3)

    def __init__(self, ctx, params=None):
        super().__init__(ctx, params)
        self._empty_vec3 = wp.empty(0, dtype=wp.vec3, device=ctx.device)
        self.corrected = self.takes_corrected_operator(ctx.scene, ctx.detects_free_surface)
        self._empty_flags = wp.empty(0, dtype=wp.int32, device=ctx.device)
        self.strain_rate = (ctx.per_particle("viscosity", SymmetricMatrix) if self.corrected
                            else wp.empty(0, dtype=SymmetricMatrix, device=ctx.device))
        self.stress_correction = (ctx.per_particle("viscosity", SymmetricMatrix) if self.corrected
                                  else wp.empty(0, dtype=SymmetricMatrix, device=ctx.device))
        # sub-stepped (solver.viscosity_substeps > 1): each sub-step's acceleration, integrated into v at once
        self.substep_acceleration = (ctx.per_particle("viscosity", wp.vec3) if ctx.viscous_substeps is not None
                                     else None)

    def step(self, ctx):
        if ctx.viscous_substeps is None:
            self._add_acceleration(ctx, ctx.dt, ctx.fluid.acceleration)
            return
        # n sub-steps of dt / n, each integrated into v~ (the step is up to n explicit limits long): a device loop
        count, substep_dt, left = ctx.viscous_substeps
        ctx.launch(start_substeps, 1, [count, left])

        def substep():
            self.substep_acceleration.zero_()
            self._add_acceleration(ctx, substep_dt, self.substep_acceleration)
            ctx.launch(advance_substep, ctx.num_fluid, [self.substep_acceleration, substep_dt, ctx.fluid.v])
            ctx.exchange(ctx.fluid.v)
            ctx.launch(count_down, 1, [left])

        wp.capture_while(left, substep)

    def _add_acceleration(self, ctx, dt, acceleration):
        """acceleration += nu laplacian(v) (and the shared vorticity of v in the same pass, when it exists); ``dt``
        is the step (or sub-step) of the bodies' friction impulse."""
        f, vorticity = ctx.fluid, ctx.vorticity
        with_vorticity = vorticity is not None
        if self.corrected:
            ctx.launch(compute_strain_rate, ctx.num_fluid,
                       [f.x, f.v, f.density, ctx.neighbour_lists, ctx.particle_mass, ctx.scene.fluid.density,
                        ctx.support_radius, ctx.surface_flags, self.strain_rate, self.stress_correction])
            ctx.exchange(self.strain_rate, self.stress_correction)
        kernel = add_corrected_viscosity_acceleration if self.corrected else add_viscosity_acceleration
        ctx.launch(kernel, ctx.num_fluid,
                   [f.x, f.v, f.density, ctx.neighbour_lists, ctx.particle_mass, ctx.scene.fluid.viscosity,
                    ctx.support_radius, ctx.boundary_samples, ctx.scene.fluid.boundary_viscosity, dt,
                    int(with_vorticity), ctx.surface_flags if self.corrected else self._empty_flags, self.strain_rate,
                    self.stress_correction, ctx.scene.fluid.density, acceleration,
                    vorticity if with_vorticity else self._empty_vec3])
        if with_vorticity:
            ctx.exchange(vorticity)
