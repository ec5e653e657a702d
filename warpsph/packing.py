"""Particle packing before t = 0 (scene key ``initial_packing``): see :class:`warpsph.scene.InitialPacking`."""

from __future__ import annotations

import dataclasses

import numpy as np


def packed_positions(scene, device, simulation):
    """The fluid blocks' particles after the scene's packing: the lattice jittered (wrapped along periodic
    axes, kept inside the domain along the others), then relaxed at rest by the scene's own solver in a
    ``simulation`` (the :class:`~warpsph.simulation.Simulation` class, which calls this: passed, not imported)."""
    packing = scene.initial_packing
    at_rest = dataclasses.replace(scene, initial_packing=None, models=(), gravity=(0.0, 0.0, 0.0), emitters=(), sinks=())
    sim = simulation(at_rest, device=device, bodies_move=False)  # the bodies stay at their initial pose
    spacing = scene.particle_diameter
    x = sim.host(sim.fluid.x).astype(np.float64)
    x += np.random.default_rng(packing.seed).uniform(-packing.jitter * spacing, packing.jitter * spacing, x.shape)
    lo, hi = np.asarray(scene.domain.min, np.float64), np.asarray(scene.domain.max, np.float64)
    periodic = np.asarray(scene.domain.period) > 0
    x = np.where(periodic, lo + np.mod(x - lo, hi - lo), np.clip(x, lo, hi))
    sim.active(sim.fluid.x).assign(x.astype(np.float32))
    for _ in range(packing.steps):
        sim.fluid.v.zero_()
        sim.step()
    return sim.host(sim.fluid.x)
