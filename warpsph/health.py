"""Health checks after every step: NaN/inf, particles that tunnelled out, runaway density, a solver stuck at
its iteration limit. The checks count on the device (``kernels/stability.py``); this reads the counts."""

from __future__ import annotations

import numpy as np
import warp as wp

from warpsph.kernels.stability import DENSITY_LIMIT, NOT_FINITE, OUTSIDE_DOMAIN, check_particles
from warpsph.scene_setup import WALL_OFFSET

# rho / rho0 above which the solver has lost control: a 2000-particle dam break peaks at 1.22 for one
# step as its front corner shoots out (then recovers); the 1M run that exploded reached 2.2
DENSITY_HARD_LIMIT = 1.5
ESCAPE_MARGIN = WALL_OFFSET + 1.0  # radii past the box: a radius beyond its wall layer = tunnelled through
MAX_ITERATION_STREAK = 50  # consecutive solves that stop at max_iterations
RETRIES = 4  # reduce-dt policy: halvings of dt tried for one frame
CHECK_NAMES = {int(NOT_FINITE): "NaN or inf in position, velocity or density",
               int(OUTSIDE_DOMAIN): "particle left the domain",
               int(DENSITY_LIMIT): f"density above {DENSITY_HARD_LIMIT:g} rho0"}


class InstabilityError(RuntimeError):
    """The simulation became unstable; the message names the step, time, check and particle.

    Example:

    ```python
    import warpsph

    sim = warpsph.Simulation(warpsph.load_scene("scenes/dam_break.json", scale=0.05))
    try:
        sim.run(frames=2)
    except warpsph.InstabilityError as error:  # error.step, .time, .check, .particle_id, .position
        print("unstable:", error)
    ```
    """

    def __init__(self, step, time, check, particle_id=None, position=None):
        self.step, self.time, self.check, self.particle_id, self.position = step, time, check, particle_id, position
        where = "" if particle_id is None else f", particle id {particle_id} at {np.round(position, 4).tolist()}"
        super().__init__(f"unstable at step {step} (t = {time:.4f} s): {check}{where}")




class HealthChecks:
    """The checks of every step (NaN/inf, particles past the walls, runaway density: counted on the device by
    ``kernels/stability.py``) and their reading. What it sees of the simulation, and nothing else: the state (the
    fluid's arrays and count, the counters, the clock), the constants (the domain, the radius, rho0), the launch call
    and the pressure solver's iteration streaks (``streak``: a device array of two, divergence and density)."""

    def __init__(self, state, constants, launch, streak):
        self.state, self.launch, self.streak = state, launch, streak
        self.counts = state.zeros("health", 4, dtype=wp.int32)
        self.first = state.zeros("health", 4, dtype=wp.int32)
        c = constants
        lo = np.asarray(c.domain_min) - ESCAPE_MARGIN * c.particle_radius
        hi = np.asarray(c.domain_max) + ESCAPE_MARGIN * c.particle_radius
        if not c.walls:  # an open domain: particles may leave (the next step removes them)
            lo, hi = np.full(3, -1e30), np.full(3, 1e30)
        self.lo, self.hi = wp.vec3(*lo), wp.vec3(*hi)
        self.density_limit = DENSITY_HARD_LIMIT * c.rest_density

    def check(self):
        """Counts this step's failures on the device (in the step, no host read)."""
        f = self.state.fluid
        self.counts.zero_()
        self.first.fill_(2**31 - 1)
        self.launch(check_particles, self.state.num_fluid, [f.x, f.v, f.density, self.lo, self.hi, self.density_limit,
                                                            self.counts, self.first])

    def first_failure(self):
        """The first failed health check of the last step as an :class:`InstabilityError`, or None."""
        state = self.state
        counts, first = self.counts.numpy(), self.first.numpy()
        time = float(state.time_device.numpy()[0])
        for check in (int(NOT_FINITE), int(OUTSIDE_DOMAIN), int(DENSITY_LIMIT)):
            if counts[check]:
                i = int(first[check])
                return InstabilityError(state.step_count, time, f"{CHECK_NAMES[check]} ({counts[check]} particles)",
                                        int(state.fluid.ids.numpy()[i]), state.fluid.x.numpy()[i])
        streak = self.streak.numpy()
        if streak.max() >= MAX_ITERATION_STREAK:
            which = "divergence" if streak[0] >= MAX_ITERATION_STREAK else "density"
            return InstabilityError(state.step_count, time,
                                    f"{which} solver hit max_iterations {int(streak.max())} steps in a row")
        return None
