"""Inflow emitters and outflow sinks: a fluid whose particle count changes during the run.

Every per-particle array is allocated for ``Simulation.capacity`` particles (the initial fill
plus what the emitters can add over the scene's duration); the first ``num_fluid`` rows hold the
particles. An emitter appends lattice layers at the end of the rows (zeroing every registered
per-particle array there, so the solvers' warm start starts from nothing, and marking the models'
history there as absent, so VR and Rankine skip a new particle's first correction)
with new, never reused ids; a sink compacts the rows (a stable sort on "inside a sink"), so the
neighbour structures, the models' state and the USD ``ids`` stay consistent. Both run on the host
side of the step, before the neighbour search, so the captured solver graph is only rebuilt when
the count changes.
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass

import numpy as np
import warp as wp

from warpsph import sampling
from warpsph.errors import SceneError
from warpsph.kernels.inflow import drive_inflow_particles, mark_particles_in_sinks


logger = logging.getLogger(__name__)

DRIVE_LENGTH = 2.0  # spacings downstream of an emitter's face in which particles keep its velocity


def layer_points(emitter, spacing):
    """One layer of an emitter's lattice at its upstream face (before it travels)."""
    k = emitter.axis
    lo, hi = np.array(emitter.min, np.float64), np.array(emitter.max, np.float64)
    face = hi[k] - 0.5 * spacing if emitter.velocity[k] < 0 else lo[k] + 0.5 * spacing
    lo[k], hi[k] = face - 0.5 * spacing, face + 0.5 * spacing  # a slab one spacing thick: one layer
    return sampling.fill_block(lo, hi, spacing)


@dataclass
class InflowContext:
    """What the emitters and sinks see of the simulation, and nothing else: the state (the fluid's arrays, its
    count, which only they change, between steps, and ``zero_rows``), the device, the launch call, and two calls
    back: ``reorder(order)`` permutes every per-particle array that a step carries (a sink's compaction: the
    solver's and the models' state too) and ``emitted(first, count)`` tells the models which rows are new."""

    state: object  # warpsph.state.State
    device: object  # the simulation's Warp device
    launch: object  # (kernel, dim, inputs): on the simulation's device, counted
    reorder: object  # (order): array[:] = array[order] for every carried per-particle array
    emitted: object  # (first, count): rows first .. first + count - 1 hold particles just added


class Inflow:
    """The scene's emitters and sinks (an open domain is a sink everywhere outside its box), how
    much they have emitted and how many particles they have removed."""

    def __init__(self, scene, initial_count):
        self.scene = scene
        d = scene.particle_diameter
        self.layers = [layer_points(e, d) for e in scene.emitters]
        for n, points in enumerate(self.layers):
            if not len(points):
                raise SceneError(scene.source, f"emitters[{n}]", "the box's cross-section holds no particle: make it "
                                                                 f"at least one spacing ({d:.3g} m) wide on both axes across the flow")
        duration = scene.output.frames / scene.output.fps
        self.room = 0
        for e, points in zip(scene.emitters, self.layers):
            end = duration if e.end is None else min(e.end, duration)
            count = max(0, math.floor((end - e.start) * abs(e.velocity[e.axis]) / d) + 2)
            self.room += count * len(points)
        self.emitted_layers = [0] * len(scene.emitters)
        self.next_id = initial_count
        self._sinks = None
        self._warned = False
        self.removed_in_sinks = 0  # particles removed so far, inside sinks
        self.removed_outside = 0  # and outside an open domain

    # -- inflow -------------------------------------------------------------------------------------------
    def emit(self, ctx, time):
        """Adds every layer due by ``time``: layer m leaves at start + m d / |v| and has travelled
        |v| (time - its departure) since, so the layers stay one spacing apart whatever dt is."""
        d = self.scene.particle_diameter
        for n, (e, points) in enumerate(zip(self.scene.emitters, self.layers)):
            if time < e.start:
                continue
            speed = abs(e.velocity[e.axis])
            until = time if e.end is None else min(time, e.end)
            due = math.floor((until - e.start) * speed / d + 1e-9) + 1
            for m in range(self.emitted_layers[n], due):
                travelled = speed * (time - (e.start + m * d / speed))
                shift = np.zeros(3)
                shift[e.axis] = math.copysign(travelled, e.velocity[e.axis])
                if not self._append(ctx, points + shift.astype(np.float32), np.asarray(e.velocity, np.float32)):
                    return
                self.emitted_layers[n] = m + 1

    def _append(self, ctx, x, velocity):
        state = ctx.state
        n, k = state.num_fluid, len(x)
        if n + k > state.capacity:
            if not self._warned:
                logger.warning(f"emitters: the fluid is at its capacity of {state.capacity:,} particles (sized for "
                               f"output.frames / output.fps); emission pauses until sinks free room")
                self._warned = True
            return False
        if self.next_id + k > np.iinfo(np.int32).max:
            raise SceneError(self.scene.source, "emitters",
                             f"particle ids would pass {np.iinfo(np.int32).max} (int32): fewer or larger particles")
        state.zero_rows(n, k)
        state.fluid.x[n: n + k].assign(x)
        state.fluid.v[n: n + k].assign(np.tile(velocity, (k, 1)))
        state.fluid.ids[n: n + k].assign(np.arange(self.next_id, self.next_id + k, dtype=np.int32))
        ctx.emitted(n, k)  # the models: no history, skip their first correction
        self.next_id += k
        state.num_fluid = n + k
        return True

    # -- outflow -------------------------------------------------------------------------------------------
    def drain(self, ctx):
        """Removes the particles inside the sinks, and outside an open domain (one host read of
        their counts per step)."""
        domain = self.scene.domain
        if not (self.scene.sinks or domain.is_open) or ctx.state.num_fluid == 0:
            return
        if self._sinks is None:
            sinks = self.scene.sinks
            # along periodic axes particles wrap around: nothing leaves there
            lo = [-1e30 if "xyz"[k] in domain.periodic else v for k, v in enumerate(domain.min)]
            hi = [1e30 if "xyz"[k] in domain.periodic else v for k, v in enumerate(domain.max)]
            box = lambda key: np.asarray([getattr(s, key) for s in sinks], np.float32).reshape(-1, 3)
            self._sinks = (wp.array(box("min"), dtype=wp.vec3, device=ctx.device),
                           wp.array(box("max"), dtype=wp.vec3, device=ctx.device),
                           wp.zeros(2, dtype=wp.int32, device=ctx.device), wp.vec3(*lo), wp.vec3(*hi))
        lo, hi, removed, domain_lo, domain_hi = self._sinks
        n = ctx.state.num_fluid
        keys = wp.empty(2 * n, dtype=wp.int32, device=ctx.device)  # radix sort needs 2n
        order = wp.empty(2 * n, dtype=wp.int32, device=ctx.device)
        removed.zero_()
        ctx.launch(mark_particles_in_sinks, n,
                   [ctx.state.fluid.x, lo, hi, int(domain.is_open), domain_lo, domain_hi, keys, order, removed])
        in_sinks, outside = (int(c) for c in removed.numpy())
        count = in_sinks + outside
        if count:
            wp.utils.radix_sort_pairs(keys, order, n)
            ctx.reorder(order)
            ctx.state.num_fluid = n - count
            self.removed_in_sinks += in_sinks
            self.removed_outside += outside

    def drive(self, ctx, time):
        """Particles in an active emitter's box, extended to DRIVE_LENGTH spacings downstream of its
        face, take the emitter's velocity."""
        d = self.scene.particle_diameter
        for e in self.scene.emitters:
            if time < e.start or (e.end is not None and time > e.end):
                continue
            lo, hi = np.array(e.min, np.float64), np.array(e.max, np.float64)
            k = e.axis
            if e.velocity[k] > 0:
                hi[k] = max(hi[k], lo[k] + DRIVE_LENGTH * d)
            else:
                lo[k] = min(lo[k], hi[k] - DRIVE_LENGTH * d)
            ctx.launch(drive_inflow_particles, ctx.state.num_fluid,
                       [ctx.state.fluid.x, wp.vec3(*lo), wp.vec3(*hi), wp.vec3(*e.velocity), ctx.state.fluid.v])

    def update(self, ctx, time):
        """Drains the sinks, then emits and drives the layers due at ``time`` (``ctx``: an :class:`InflowContext`)."""
        self.drain(ctx)
        self.emit(ctx, time)
        self.drive(ctx, time)

    # -- state ---------------------------------------------------------------------------------------------
    def state(self):
        return {"inflow.next_id": self.next_id, "inflow.emitted_layers": np.asarray(self.emitted_layers, np.int64),
                "inflow.removed_in_sinks": self.removed_in_sinks, "inflow.removed_outside": self.removed_outside}

    def restore(self, flags):
        self.next_id = int(flags["inflow.next_id"])
        self.emitted_layers = [int(v) for v in np.atleast_1d(flags["inflow.emitted_layers"])]
        self.removed_in_sinks = int(flags.get("inflow.removed_in_sinks", 0))  # checkpoints before the counts: 0
        self.removed_outside = int(flags.get("inflow.removed_outside", 0))
