"""The data of a simulation, apart from its step: the constants of its discretisation, every per-particle array,
the particle count and the clock.

After newton's Model-State split: :class:`Constants` is the static part (what the scene fixes once: the particle
radius, the support radius, the mass, the rest density, the domain), never changed after it is built.
:class:`State` allocates and owns the arrays (counted per owner, for the memory report), knows which rows hold
particles, and names the arrays that a step carries to the next (``carried``): what a checkpoint saves and a
retried frame restores. The stepper (:class:`warpsph.simulation.Simulation`) and the plug-ins only read and write
them.
"""

from __future__ import annotations

from collections import defaultdict
from dataclasses import dataclass

import numpy as np
import warp as wp

from warpsph.scene import MAX_VISCOSITY_SUBSTEPS, walled_faces


def viscous_substeps(scene, viscous_dt: float) -> int:
    """The most sub-steps of the explicit viscosity in a step: ``solver.viscosity_substeps``, or where that is 0 as
    many as let the longest step (``time.fixed_dt``, else dt_max) stay within half the lattice's viscous limit
    ``viscous_dt`` [s] (the step's own limit falls below the lattice's where the flow compresses pairs:
    kernels/integration.py, VISCOUS_MARGIN), at most MAX_VISCOSITY_SUBSTEPS: the step then follows the CFL rule alone,
    as SPlisHSPlasH's does."""
    n = scene.solver.viscosity_substeps
    if n == 0:
        longest = scene.time.fixed_dt or scene.time_step_bounds[1]
        n = min(MAX_VISCOSITY_SUBSTEPS, max(1, int(np.ceil(2.0 * longest / viscous_dt * (1.0 - 1.0e-6)))))
    return n


@dataclass(frozen=True)
class Constants:
    """What the scene fixes once for a simulation: the discretisation, the fluid's constants and the domain. Built
    by :meth:`from_scene`, read by the stepper and every part (``Simulation.constants``); nothing changes it.

    Example:

    ```python
    import warpsph
    from warpsph.state import Constants

    scene = warpsph.load_scene("scenes/dam_break.json", scale=0.05)
    c = Constants.from_scene(scene)
    assert c.support_radius == 4 * c.particle_radius
    assert c.particle_mass == c.rest_density * c.fluid_volume
    ```
    """

    particle_radius: float  # r [m]
    particle_diameter: float  # the lattice spacing 2r [m]
    support_radius: float  # the kernel's support H = 4r [m] (``Scene.support_radius``: derived there only)
    fluid_volume: float  # a particle's volume (2r)^3 [m^3]: a lattice of spacing 2r sums to rho0 (see docs)
    rest_density: float  # rho0 [kg/m^3]
    particle_mass: float  # rho0 (2r)^3 [kg]
    domain_min: tuple  # the domain's corners [m]
    domain_max: tuple
    periodic: tuple  # the axes ("x", "y", "z") across which it wraps
    walls: bool  # False: an open domain
    inside_lo: wp.vec3  # the walled faces that hold every fluid particle (+-1e30 where it wraps or is open)
    inside_hi: wp.vec3
    viscous_dt: float  # the explicit viscosity's stable dt [s] (1e30 without viscosity)
    max_viscous_substeps: int  # the most viscosity sub-steps in a step (1: none)

    @classmethod
    def from_scene(cls, scene):
        r = scene.particle_radius
        support = scene.support_radius
        fluid_volume = scene.particle_diameter ** 3
        rest_density = scene.fluid.density
        # explicit viscosity is stable for dt <= 0.125 h^2 / nu with h = H / 2 (Morris et al. 1997): at
        # r = 2.9 mm and nu = 0.05 a 0.57 ms step flung dam-break particles out at 38 m/s
        nu = max(scene.fluid.viscosity, scene.fluid.boundary_viscosity)
        viscous_dt = 0.125 * (0.5 * support) ** 2 / nu if nu > 0 else 1.0e30
        d = scene.domain
        lo, hi = walled_faces(d)
        return cls(particle_radius=r, particle_diameter=scene.particle_diameter, support_radius=support,
                   fluid_volume=fluid_volume, rest_density=rest_density, particle_mass=rest_density * fluid_volume,
                   domain_min=tuple(d.min), domain_max=tuple(d.max), periodic=tuple(d.periodic), walls=d.walls,
                   inside_lo=wp.vec3(*np.maximum(lo, -1e30)), inside_hi=wp.vec3(*np.minimum(hi, 1e30)),
                   viscous_dt=viscous_dt,
                   # solver.viscosity_substeps > 1: the step may reach that many viscous limits; the viscosity
                   # sub-steps it
                   max_viscous_substeps=viscous_substeps(scene, viscous_dt) if nu > 0 else 1)


@dataclass
class FluidParticles:
    """Per-particle state of the fluid (sorted by cell every ``solver.sort_interval`` steps)."""

    x: wp.array  # position [m]
    v: wp.array  # velocity [m/s]
    ids: wp.array  # stable id (int32; int64 in USD), follows the particle through re-sorting
    density: wp.array  # [kg/m^3]
    factor: wp.array  # DFSPH factor (empty under IISPH)
    acceleration: wp.array  # non-pressure acceleration of this step [m/s^2]


class State:
    """Per-particle arrays of ``capacity`` rows (room for what emitters add), of which the first ``num_fluid``
    hold particles; the device clock (dt, previous dt, time, steps) and the host counters (steps, frame)."""

    def __init__(self, device, capacity: int, num_fluid: int):
        self.device = wp.get_device(device)
        self.capacity = capacity
        self.num_fluid = num_fluid
        self.allocations = defaultdict(int)  # owner -> bytes
        self.carried = {}  # name -> array that a step carries to the next (checkpoints, retries)
        self.optional = set()  # carried names an older checkpoint may lack
        self._per_particle = []
        self.fluid = None
        self.step_count = 0
        self.frame = 0  # last output frame reached

    # -- allocation --------------------------------------------------------------------------------
    def zeros(self, owner, shape, dtype=float):
        a = wp.zeros(shape, dtype=dtype, device=self.device)
        self.allocations[owner] += a.capacity
        return a

    def array(self, owner, data, dtype):
        a = wp.array(data, dtype=dtype, device=self.device)
        self.allocations[owner] += a.capacity
        return a

    def per_particle(self, owner, dtype=float, data=None):
        """A per-fluid-particle array of ``capacity`` rows with ``data`` in its first rows; its rows are
        zeroed where an emitter adds particles (:meth:`zero_rows`)."""
        a = self.zeros(owner, self.capacity, dtype=dtype)
        if data is not None and len(data):
            a[: len(data)].assign(np.ascontiguousarray(data))
        self._per_particle.append(a)
        return a

    def carry(self, name, array, optional=False):
        """Registers ``array`` as state a step carries to the next, under ``name`` (a checkpoint's key);
        ``optional``: a checkpoint written before it existed loads without it (the array keeps its start)."""
        if name in self.carried:
            raise ValueError(f"state {name!r} is registered twice")
        self.carried[name] = array
        if optional:
            self.optional.add(name)
        return array

    def allocate_fluid(self, x, v, factor=True, ids=None):
        """The fluid's arrays, with positions ``x``, velocities ``v`` and ``ids`` (default 0, 1, ...) in the
        first rows; ``factor`` False: an empty DFSPH factor (a solver without one)."""
        p = self.per_particle
        self.fluid = FluidParticles(
            x=p("fluid", wp.vec3, x), v=p("fluid", wp.vec3, v),
            ids=p("fluid", wp.int32, np.arange(len(x), dtype=np.int32) if ids is None else ids),
            density=p("fluid"), factor=p("fluid") if factor else self.zeros("fluid", 0),
            acceleration=p("fluid", wp.vec3))
        for name in ("x", "v", "ids"):
            self.carry(f"fluid/{name}", getattr(self.fluid, name))

    def allocate_clock(self, dt_max):
        """Device clock: dt (this step), dt_previous (starts at ``dt_max``), time (float64) and steps."""
        self.dt = self.carry("clock/dt", self.zeros("clock", 1))
        self.dt_previous = self.carry("clock/dt_previous", self.array("clock", np.array([dt_max], np.float32), float))
        self.time_device = self.carry("clock/time", self.zeros("clock", 1, dtype=wp.float64))
        self.steps_device = self.carry("clock/steps", self.zeros("clock", 1, dtype=wp.int64))

    def carried_rows(self):
        """The carried arrays that hold a row per particle (what moves with a particle to another subdomain)."""
        rows = {id(a) for a in self._per_particle}
        return [a for a in self.carried.values() if id(a) in rows]

    # -- rows ------------------------------------------------------------------------------------
    def zero_rows(self, first, count):
        """Zeroes rows ``first .. first + count - 1`` of every per-particle array (particles an emitter adds)."""
        for a in self._per_particle:
            a[first: first + count].zero_()

    def active(self, array):
        """The rows of a per-particle array that hold particles (a view; the array itself when full)."""
        return array if array.shape[0] == self.num_fluid else array[: self.num_fluid]

    def host(self, array):
        """The particles' rows of a per-particle array, copied to the host."""
        return self.active(array).numpy()

    # -- what a checkpoint keeps -----------------------------------------------------------------------
    def counters(self):
        return {"step": self.step_count, "frame": self.frame, "num_fluid": self.num_fluid}

    def restore_counters(self, flags):
        self.step_count, self.frame = int(flags["step"]), int(flags["frame"])
        self.num_fluid = int(flags.get("num_fluid", self.num_fluid))
