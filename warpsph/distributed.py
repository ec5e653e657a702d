"""One simulation over several processes, one subdomain (slab) each, through MPI (issue #40).

The slabs, ghost rows, migration and reductions are :mod:`warpsph.decomposition`'s; only the communicator differs:
:class:`MPIComm` stands where :class:`~warpsph.decomposition.Threads` stands for the subdomains of one process.
Each MPI rank steps one subdomain on its own device (``cuda:<local rank>`` on a GPU host, else ``cpu``), and what
the subdomains say to each other goes through mpi4py:

- ``counts``: the rows each subdomain sends each other one (leavers, ghosts): ``Alltoall`` of int64;
- ``transfer`` / ``exchange``: rows gathered on the owner's device into a staging array (the same
  ``gather_rows`` kernel as in one process), copied to the host, ``Isend``/``Irecv`` to their subdomain, copied
  into its rows behind its own (migration) or into its ghost rows (exchanges);
- ``allreduce``: every rank's small arrays gathered (``allgather``) and combined in rank order, as the threads
  combine them on the host (:func:`~warpsph.decomposition.combine`): every rank takes the same dt and the same
  iterations.

The seam for device-to-device transport (NCCL, e.g. nccl4py; not written): :meth:`MPIComm._swap` posts one send and
one receive per (peer, array) of rows already gathered into a contiguous device staging array (``_pack``) and
copies what arrives into place (``_unpack``); an NCCL communicator would send the staging arrays themselves
(``ncclSend``/``ncclRecv`` in one group) instead of their host copies, and ``allreduce`` would become
``ncclAllReduce`` (sum and max are ops of its own) or an ``allgather`` and the same ordered combine on the device.
The counts stay small host messages.

Each rank adds the seconds it spends inside ``counts``, ``transfer``, ``exchange`` and ``allreduce`` (waiting for the
others included) to ``MPIComm.seconds`` and their calls to ``MPIComm.calls``.

Launch (one process per GPU; several hosts are a host file away)::

    mpiexec -n 2 python -m warpsph.distributed scenes/dam_break.json --scale 64 --frames 50 --out out/dam.usdc

Rank 0 gathers each frame and writes the USD point cache (and ``--positions``: the last frame as .npz); the other
ranks write nothing. Benchmark (strong scaling against ``warpsph bench steps --devices``: the same scene at ~N fluid
particles, the same timing)::

    mpiexec -n 2 python -m warpsph.distributed scenes/dam_break.json --particles 32e6 --model none \\
        --warmup 60 --steps 30 --bench-json out/mpi_2.json

Rank 0 prints, and writes to ``--bench-json``, what ``bench steps`` writes for ``--devices`` (ms per step; the stages
of subdomain 0, rank 0's) with each rank's device and seconds inside the communicator over the timed steps
(``tools/gpu/mpi_scaling.sh`` runs 1, 2 and 4 ranks on a GPU host). Needs the ``distributed`` extra:
``pip install 'warpsph[distributed]'`` (mpi4py and the ``mpich`` wheel, whose libmpi mpi4py's wheel loads; any MPI
that mpi4py finds works).
"""

from __future__ import annotations

import argparse
import functools
import json
import sys
import time
import traceback
from pathlib import Path

import numpy as np
import warp as wp

from warpsph import log
from warpsph.cli import Progress
from warpsph.device import init_warp
from warpsph.decomposition import CAPACITY_FACTOR, DecomposedSimulation, reduced, reusable
from warpsph.errors import SceneError
from warpsph.io.frames import HostFrame
from warpsph.io.usd import UsdPointCache, body_meshes, run_metadata, write_host_frame
from warpsph.scene import load_scene
from warpsph.kernels.decomposition import gather_rows
from warpsph.validation.bench import MODELS, make_scene, timed_steps
from warpsph.validation.cases import commit_info

EXTRA = "pip install 'warpsph[distributed]' (mpi4py and an MPI runtime such as the mpich wheel)"


class MissingMPI(ImportError):
    """mpi4py, or the MPI library it loads, is not installed: the message names the extra to install.

    Example:

    ```python
    from warpsph.distributed import MissingMPI, mpi

    try:
        MPI = mpi()
    except MissingMPI as missing:
        print(missing)  # ... pip install 'warpsph[distributed]' ...
    ```
    """


def mpi():
    """mpi4py's ``MPI`` module; :class:`MissingMPI` naming the ``distributed`` extra when it cannot load."""
    try:
        from mpi4py import MPI
    except ImportError as exc:
        raise MissingMPI(f"a run over MPI processes needs mpi4py: {EXTRA}") from exc
    except RuntimeError as exc:  # mpi4py without a libmpi it can load
        raise MissingMPI(f"mpi4py found no MPI library ({exc}): {EXTRA}") from exc
    return MPI


def _timed(method):
    """The communicator's call, its seconds and calls added to ``self.seconds`` / ``self.calls`` under its name."""
    @functools.wraps(method)
    def timed(self, *args, **kwargs):
        start = time.perf_counter()
        try:
            return method(self, *args, **kwargs)
        finally:
            name = method.__name__
            self.seconds[name] = self.seconds.get(name, 0.0) + time.perf_counter() - start
            self.calls[name] = self.calls.get(name, 0) + 1
    return timed


class MPIComm:
    """The communicator of :class:`~warpsph.decomposition.DecomposedSimulation` when each subdomain is a process of
    ``comm`` (default ``MPI.COMM_WORLD``): subdomain k is rank k. The interface is
    :class:`~warpsph.decomposition.Threads`'s; rows and reductions go through host-staged numpy buffers.

    Example:

    ```python
    # needs: mpi4py
    import warpsph
    from warpsph.distributed import MPIComm

    comm = MPIComm()  # under mpiexec -n N: N ranks; run alone: one rank, one subdomain
    scene = warpsph.load_scene("scenes/dam_break.json", scale=0.05)
    sim = warpsph.DecomposedSimulation(scene, ["cpu"], comm=comm)
    sim.run(frames=1)
    ```
    """

    def __init__(self, comm=None):
        self.MPI = mpi()
        self.comm = self.MPI.COMM_WORLD if comm is None else comm
        self.rank, self.size = self.comm.Get_rank(), self.comm.Get_size()
        node = self.comm.Split_type(self.MPI.COMM_TYPE_SHARED, key=self.rank)
        self.local_rank = node.Get_rank()  # this rank's place among the ranks of its host: its GPU
        node.Free()
        self._buffers = {}  # staging arrays reused from meeting to meeting: by (direction, peer, position, device)
        self._unpacked = None  # on a GPU: the event after the last meeting's copies out of the host staging
        self.seconds, self.calls = {}, {}  # inside counts, transfer, exchange, allreduce: by name (:func:`_timed`)

    # -- the group's ---------------------------------------------------------------------------------
    def local(self, count):
        """The subdomains this process steps: its rank's."""
        if count != self.size:
            raise ValueError(f"{count} subdomains over {self.size} MPI processes: one each")
        return [self.rank]

    def everyone(self, values):
        """Every subdomain's value in subdomain (rank) order, from this rank's list of its own: on every rank."""
        return [v for part in self.comm.allgather(list(values)) for v in part]

    def to_first(self, values):
        """As :meth:`everyone` on rank 0; None on the others (a frame for the writer)."""
        parts = self.comm.gather(list(values), root=0)
        return None if parts is None else [v for part in parts for v in part]

    def from_first(self, make):
        """``make()`` computed on rank 0 and sent to every rank (the initial particles: sampled and packed once)."""
        return self.comm.bcast(make() if self.rank == 0 else None, root=0)

    def parallel(self, sims, work):
        """``work(sim)`` on this rank's subdomain, on its device."""
        with wp.ScopedDevice(sims[0].device):
            return [work(sim) for sim in sims]

    def abort(self, code=1):
        """Stops every rank (one rank's error would leave the others waiting at their next meeting)."""
        self.comm.Abort(code)

    # -- the subdomain's -----------------------------------------------------------------------------
    @_timed
    def counts(self, sub, mine):
        """What each rank's outbox holds for this one (``mine[j]``: this one's for rank j)."""
        received = np.zeros(self.size, np.int64)
        self.comm.Alltoall(np.ascontiguousarray(mine, dtype=np.int64), received)
        received[self.rank] = 0
        return received

    @_timed
    def transfer(self, sub, dst, placements):
        self._swap(sub, dst, placements)

    @_timed
    def exchange(self, sub, arrays, placements):
        self._swap(sub, arrays, placements)

    @_timed
    def allreduce(self, sub, pairs, read=True):
        """Every rank's values gathered, combined in rank order on every rank (the same sums as the threads')."""
        values = [array.numpy().copy() for array, _ in pairs]  # waits for the device
        return reduced(pairs, self.comm.allgather(values))

    # -- rows: the transport (an NCCL communicator replaces these three) -----------------------------------
    def _pack(self, sub, src, index, count, key):
        """Rows ``src[index[:count]]`` as a contiguous host array (gathered on src's device, then copied off it)."""
        device = src.device
        rows = reusable(self._buffers, ("rows", *key, device.alias), count, src.dtype, device)
        wp.launch(gather_rows, count, [src, index, 0, rows], device=device)
        if device.is_cpu:
            return rows
        host = reusable(self._buffers, ("out", *key, device.alias), count, src.dtype, "cpu", pinned=True)
        wp.copy(host, rows, count=count)
        return host

    def _swap(self, sub, dst, placements):
        """Every peer's rows for this subdomain (its outbox) into ``dst`` at ``placements[j]`` = (first, count), and
        this subdomain's outbox rows to every peer: one message per (peer, array), tagged by the array's position."""
        MPI, box, gpu = self.MPI, sub.outbox, not sub.device.is_cpu
        if self._unpacked is not None:  # the last meeting's copies out of the host staging are done before its reuse
            wp.synchronize_event(self._unpacked)
            self._unpacked = None
        sends, receives = [], []
        for j in range(self.size):
            if j == self.rank:
                continue
            count = int(box.counts[j])
            if count:
                index = box.rows_for(j)
                for n, a in enumerate(box.arrays):
                    sends.append((self._pack(sub, a, index, count, (j, n)), count, j, n))
            first, count = placements[j]
            if count:
                for n, a in enumerate(dst):
                    host = reusable(self._buffers, ("in", j, n, "cpu"), count, a.dtype, "cpu", pinned=gpu)
                    receives.append((host, a, first, count, j, n))
        if sends and gpu:
            wp.synchronize_device(sub.device)  # the host copies are done
        requests = [self.comm.Irecv([host.numpy()[:count], MPI.BYTE], source=j, tag=n)
                    for host, _, _, count, j, n in receives]
        requests += [self.comm.Isend([host.numpy()[:count], MPI.BYTE], dest=j, tag=n) for host, count, j, n in sends]
        MPI.Request.Waitall(requests)
        self._unpack(sub, receives)

    def _unpack(self, sub, receives):
        """The received rows into place: on a GPU, copies from pinned memory on the device's stream, which the host
        does not wait for (the next meeting waits for their event before it reuses the staging)."""
        for host, a, first, count, _, _ in receives:
            wp.copy(a, host, dest_offset=first, count=count)
        if receives and not sub.device.is_cpu:
            self._unpacked = sub.device.stream.record_event()


def rank_device(comm, device=None):
    """This rank's device: ``cuda:<local rank>`` (modulo the GPUs of its host) for "cuda" or, where CUDA is
    available, None; else "cpu"; a full name ("cuda:1") as given."""
    if device in (None, "auto"):
        device = "cuda" if wp.is_cuda_available() else "cpu"
    if device == "cuda":
        return f"cuda:{comm.local_rank % wp.get_cuda_device_count()}"
    return device


class DistributedSimulation(DecomposedSimulation):
    """A scene over the processes of an MPI communicator, one subdomain (slab) each, this process's on ``device``
    (default :func:`rank_device`: its host's GPU of its local rank, else the CPU). Every method of
    :class:`~warpsph.decomposition.DecomposedSimulation`; the particle accessors (``positions()``, ...) are
    collective: every rank calls them, and every rank gets every particle.

    Under ``mpiexec -n 2 python script.py`` two subdomains, one a process; alone, one.

    Example:

    ```python
    # needs: mpi4py
    import warpsph
    from warpsph.distributed import DistributedSimulation

    scene = warpsph.load_scene("scenes/dam_break.json", scale=0.05)
    sim = DistributedSimulation(scene, device="cpu")
    sim.run(frames=1)
    x = sim.positions()  # every rank's particles, in id order
    ```
    """

    def __init__(self, scene, device=None, comm=None, axis=None, capacity_factor=CAPACITY_FACTOR,
                 rebalance_interval=100, state=None):
        comm = comm if isinstance(comm, MPIComm) else MPIComm(comm)
        super().__init__(scene, [rank_device(comm, device)], axis=axis, capacity_factor=capacity_factor,
                         rebalance_interval=rebalance_interval, state=state, comm=comm)

    rank = property(lambda self: self.comm.rank)
    size = property(lambda self: self.comm.size)

    def frame_arrays(self):
        """This frame's x, v and ids of every particle in id order (numpy) on rank 0; None on the others (every rank
        calls it: a gather to rank 0).

        Example:

        ```python
        # needs: mpi4py
        import numpy as np
        import warpsph
        from warpsph.distributed import DistributedSimulation

        sim = DistributedSimulation(warpsph.load_scene("scenes/dam_break.json", scale=0.05), device="cpu")
        sim.step()
        arrays = sim.frame_arrays()
        if sim.rank == 0:
            np.savez("frame.npz", **arrays)  # ids, x, v of every rank's particles
        ```
        """
        parts = self.comm.to_first([(s.ids(), s.positions(), s.velocities()) for s in self.sims])
        if parts is None:
            return None
        ids = np.concatenate([p[0] for p in parts])
        order = np.argsort(ids, kind="stable")
        return {"ids": ids[order], "x": np.concatenate([p[1] for p in parts])[order],
                "v": np.concatenate([p[2] for p in parts])[order]}


class _Writer:
    """Rank 0's output a frame: the progress and the USD point cache (as ``warpsph run`` writes it: the fluid's
    points, velocities and ids a frame, the boundary once); the frame is gathered only for the cache."""

    def __init__(self, sim, out, frames=None):
        self.sim, self.out, self.cache = sim, out, None
        self.progress = Progress(frames) if frames is not None and sim.rank == 0 else None
        if out is not None and sim.rank == 0:
            scene = sim.scene
            static = sim.num_boundary if sim.moving_bodies is None else sim.moving_bodies.first_sample
            self.cache = UsdPointCache(out, scene.output.fps, scene.output.up_axis,
                                       boundary_points=sim.boundary.x.numpy()[:static],
                                       boundary_radius=scene.particle_radius, bodies=body_meshes(sim),
                                       metadata=run_metadata(scene), domain=scene.domain)

    def __call__(self, sim, frame):
        if self.progress is not None:
            self.progress(sim, frame)
        if self.out is None:
            return
        arrays = sim.frame_arrays()  # collective: every rank writes or none
        if self.cache is not None:
            poses = sim.moving_bodies.poses() if sim.moving_bodies is not None else None
            item = HostFrame(frame, sim.time, sim.step_count, len(arrays["ids"]), arrays, poses)
            write_host_frame(self.cache, item, sim.scene.particle_radius, ["points", "velocities", "ids"])

    def close(self):
        if self.progress is not None:
            self.progress.close()
        if self.cache is not None:
            self.cache.finish(self.out)


def _arguments(argv):
    p = argparse.ArgumentParser(prog="mpiexec -n N python -m warpsph.distributed",
                                description="One simulation over the MPI processes, a slab of the domain each.")
    p.add_argument("scene", help="scene JSON")
    size = p.add_mutually_exclusive_group()
    size.add_argument("--scale", type=float, default=1.0, help="particle count scale, as warpsph run's")
    size.add_argument("--particles", type=float, default=None, help="instead of --scale: the scale that gives ~N fluid "
                                                                    "particles (as warpsph bench steps)")
    p.add_argument("--model", choices=MODELS, default=None, help="with --particles: the models, as warpsph bench "
                                                                 "steps' (none: plain DFSPH; default the scene's)")
    p.add_argument("--frames", type=int, default=None, help="output frames (default: the scene's)")
    p.add_argument("--steps", type=int, default=None, help="instead of --frames: this many steps, then the last frame")
    p.add_argument("--device", default=None, help="cpu, cuda (each rank its host's GPU of its local rank; "
                                                  "the default where CUDA is available) or a full name")
    p.add_argument("--out", default=None, help="the USD point cache rank 0 writes (.usdc); none by default")
    p.add_argument("--positions", default=None, help="the last frame's ids, x and v in id order (.npz, rank 0)")
    p.add_argument("--axis", type=int, choices=(0, 1, 2), default=None, help="the axis cut into slabs "
                                                                           "(default: the domain's longest)")
    p.add_argument("--rebalance-interval", type=int, default=100, help="steps between rebalances (0: never)")
    p.add_argument("--capacity-factor", type=float, default=CAPACITY_FACTOR)
    p.add_argument("--warmup", type=int, default=None, help="benchmark: this many steps, then --steps (default 30) "
                                                             "timed as warpsph bench steps times them")
    p.add_argument("--bench-json", default=None, help="benchmark (--warmup default 0): the result rank 0 writes")
    p.add_argument("-q", "--quiet", action="store_true", help="no progress a frame (rank 0 shows it, as warpsph run)")
    args = p.parse_args(argv)
    args.bench = args.warmup is not None or args.bench_json is not None
    if args.bench:
        args.warmup, args.steps = args.warmup or 0, 30 if args.steps is None else args.steps
    return args


def bench(args, sim, setup_s):
    """``--warmup`` steps, then :func:`~warpsph.validation.bench.timed_steps` (the stage-timed steps, then the timed
    ones), each end of the timed steps met by every rank (its device synchronised, then an MPI barrier). The result
    on rank 0 (ms per step, and each rank's seconds and calls inside the communicator over the timed steps), None
    on the others."""
    comm, marks = sim.comm, []

    def meet():
        wp.synchronize_device(sim.device)
        comm.comm.Barrier()
        marks.append((dict(comm.seconds), dict(comm.calls)))

    for _ in range(args.warmup):
        sim.step()
    stages, ms, iterations = timed_steps(sim, sim.sims[0], args.steps, synchronize=meet)
    (s0, c0), (s1, c1) = marks[-2:]
    device = sim.device.name if sim.device.is_cuda else "cpu"
    mine = {"device": device, "device_alias": sim.device.alias, "host": comm.MPI.Get_processor_name(),
            "ms_per_step": ms, "owned": sim.sims[0].num_fluid, "ghosts": sim.subdomains[0].ghosts,
            "rows": sim.subdomains[0].capacity,
            "comm_seconds": {k: v - s0.get(k, 0.0) for k, v in s1.items()},
            "comm_calls": {k: v - c0.get(k, 0) for k, v in c1.items()}}
    ranks = comm.to_first([mine])
    if ranks is None:
        return None
    scene = sim.scene

    def each(key):  # every rank's value of ``key``, in rank order
        return [r[key] for r in ranks]

    return {
        "benchmark": "scene, MPI",
        "scene": scene.name,
        "model": "+".join(type(m).plugin_name for m in scene.models) or "none",
        "ranks": sim.size,
        "devices": each("device"),
        "device_aliases": each("device_alias"),
        "hosts": each("host"),
        "warp": wp.__version__,
        **commit_info(),
        "fluid_particles": sim.num_fluid,
        "axis": sim.axis,
        "particles_per_subdomain": each("owned"),
        "ghosts_per_subdomain": each("ghosts"),
        "rows_per_subdomain": each("rows"),
        "particle_radius": scene.particle_radius,
        "rebalance_interval": sim.rebalance_interval,
        "setup_s": setup_s,
        "warmup_steps": args.warmup,
        "timed_steps": args.steps,
        "simulated_time_s": sim.time,
        "steps_total": sim.step_count,
        "ms_per_step": ms,
        "ms_per_step_per_rank": each("ms_per_step"),
        "ms_per_step_by_stage_synchronised_subdomain0": stages,
        **iterations,
        "comm_seconds_per_rank": each("comm_seconds"),  # over the timed steps, waiting included
        "comm_calls_per_rank": each("comm_calls"),
    }


def run(argv=None):
    """The launch (``python -m warpsph.distributed``): returns the exit code on rank 0 and the others."""
    args = _arguments(argv)
    if args.steps is not None and args.out is not None:
        raise SceneError("", "--out", "--steps runs steps, not frames: give --frames for a cache (--positions keeps "
                                      "the last step's particles)")
    if args.model is not None and args.particles is None:
        raise SceneError("", "--model", "goes with --particles (the benchmark's scene)")
    for option, value, low in (("--particles", args.particles, 1), ("--warmup", args.warmup, 0),
                               ("--steps", args.steps, 1)):
        if value is not None and not low <= value < float("inf"):
            raise SceneError("", option, f"expected a number >= {low}, got {value}")
    comm = MPIComm()
    log.configure(log.verbosity(quiet=args.quiet) if comm.rank == 0 else log.QUIET)
    init_warp()  # as the command line starts Warp: no CUDA-driver warning on a host without one
    device = rank_device(comm, args.device)
    wp.set_device(device)  # nothing of this rank's lands on another GPU by default
    if args.particles is not None:
        scene = make_scene(args, args.particles)  # bench steps' scene at ~N fluid particles
    else:
        scene = load_scene(args.scene, scale=args.scale)
    start = time.perf_counter()
    sim = DistributedSimulation(scene, device=device, comm=comm, axis=args.axis, capacity_factor=args.capacity_factor,
                                rebalance_interval=args.rebalance_interval)
    setup = time.perf_counter() - start
    if args.bench:
        result = bench(args, sim, setup)
        if result is not None:
            print(json.dumps(result, indent=2), flush=True)
            if args.bench_json:
                Path(args.bench_json).parent.mkdir(parents=True, exist_ok=True)
                Path(args.bench_json).write_text(json.dumps(result, indent=2) + "\n")
        return 0
    frames = scene.output.frames if args.frames is None else args.frames
    writer = _Writer(sim, args.out, None if args.steps is not None else frames)
    start = time.perf_counter()
    if args.steps is not None:
        for _ in range(args.steps):
            sim.step()
            problem = sim.check_health()
            if problem is not None:
                raise problem
    else:
        sim.run(frames=frames, on_frame=writer)
    wall = time.perf_counter() - start
    writer.close()
    counts = sim.owned_counts()
    arrived = sum(comm.everyone([s.arrived for s in sim.subdomains]))  # particles that crossed a cut
    arrays = sim.frame_arrays() if args.positions else None  # collective: the last step's particles
    if sim.rank == 0:
        steps = sim.step_count
        if args.positions:
            np.savez(args.positions, ids=arrays["ids"], x=arrays["x"], v=arrays["v"], time=sim.time, steps=steps,
                     frame=sim.frame, owned=np.array(counts), arrived=arrived)
        print(f"{scene.name}: {sim.num_fluid} fluid particles over {sim.size} processes ({counts} along "
              f"{'xyz'[sim.axis]}), {sim.device.alias}; set-up {setup:.2f} s, {steps} steps in {wall:.2f} s "
              f"({1e3 * wall / max(steps, 1):.1f} ms a step), {arrived} crossed a cut" + (f" -> {args.out}" if args.out else ""), flush=True)
    return 0


def main(argv=None):
    """``python -m warpsph.distributed``: :func:`run`; an error on any rank stops every rank (MPI abort)."""
    try:
        MPI = mpi()
    except MissingMPI as missing:
        print(f"warpsph.distributed: {missing}", file=sys.stderr)
        return 2
    try:
        return run(argv)
    except SystemExit:
        raise
    except BaseException as exc:  # the other ranks would wait at their next meeting: stop them all
        rank = MPI.COMM_WORLD.Get_rank()
        if isinstance(exc, SceneError):
            print(f"warpsph.distributed (rank {rank}): {exc}", file=sys.stderr, flush=True)
        else:
            print(f"warpsph.distributed (rank {rank}): {type(exc).__name__}: {exc}", file=sys.stderr, flush=True)
            traceback.print_exc()
        sys.stderr.flush()
        if MPI.COMM_WORLD.Get_size() > 1:
            MPI.COMM_WORLD.Abort(2 if isinstance(exc, SceneError) else 1)
        return 2 if isinstance(exc, SceneError) else 1


if __name__ == "__main__":
    sys.exit(main())
