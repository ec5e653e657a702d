"""One simulation over several subdomains: slabs along one axis, on one device or one GPU each (issue #22).

Each subdomain is a :class:`~warpsph.simulation.Simulation` of its own particles (rows ``0 .. num_fluid - 1``)
followed by **ghost rows**: copies of the other subdomains' particles within one support radius of its slab,
which its neighbour lists find but its kernels never update. The subdomains step in lockstep, one thread
each (the threads of one device take turns between meetings); they meet at three kinds of points, all in :class:`Subdomain`:

- ``refresh`` at the start of a step: particles that crossed a cut move to their new subdomain (every array
  the step carries: positions, velocities, ids, warm starts, the models' state), then each subdomain
  takes its ghost rows (the same arrays);
- ``exchange(arrays)`` after a pass that wrote a field which a later pass reads at the neighbours (densities,
  the free-surface test's divergence of position, the solvers' stiffness each iteration and the velocities
  after each apply, the shared vorticity, the models' fields): the ghost rows get their owners' values;
- ``allreduce`` where the step reduces over all particles (the CFL speed, the solvers' error sums and
  maxima, the free-surface flag): every subdomain gets the same totals, so all take the same dt and the
  same number of iterations.

So a subdomain computes, for its own particles, what one simulation of the whole scene computes, up to the
order of floating-point sums. Cuts start at the quantiles of the fluid along the axis and move back to them
every ``rebalance_interval`` steps (load balance).

What the subdomains say to each other goes through a communicator (the slab logic above is the same for both):

- :class:`Threads` (the default): every subdomain in this process, one thread each. Communication is Warp's:
  gather kernels that read the other subdomain's memory (one CPU, or GPUs with peer access; else a gather on the
  owner's device and a peer ``wp.copy``). The threads meet at a :class:`threading.Barrier`; on GPUs with peer
  access, CUDA events order the exchanges and the reductions the solver does not read on the host, so those
  meetings wait on no device.
- :class:`warpsph.distributed.MPIComm`: one subdomain in each process of an MPI communicator (``mpiexec``; issue
  #40), rows and reductions through host-staged buffers (mpi4py).

The refresh's counts, the free-surface flag and each solver iteration's loop condition are still read on the host,
and the step is not a captured graph.
Not supported yet (a clear error): emitters, sinks and open domains, dynamic bodies, IISPH,
``on_instability = "reduce-dt"``.
"""

from __future__ import annotations

import sys
import threading
from concurrent.futures import ThreadPoolExecutor

import numpy as np
import warp as wp

from warpsph.errors import SceneError
from warpsph.health import InstabilityError
from warpsph.kernels.decomposition import (
    combine_values,
    gather_rows,
    list_ghosts,
    list_holes,
    list_leavers,
    list_movers,
    move_rows,
)
from warpsph import scene_setup
from warpsph.scene_setup import remove_fluid_inside_bodies, sample_scene
from warpsph.simulation import Simulation
from warpsph.packing import packed_positions
from warpsph.solvers import solver_class

# room per subdomain over its initial share, for particles that arrive and for ghost rows
CAPACITY_FACTOR = 1.6
# a particle within this many support radii of a slab is a ghost there (1 + a margin for float rounding)
GHOST_WIDTH = 1.001
# entries a device list (leavers, ghosts) holds per subdomain at least; a list that overflows is made again, longer
MIN_LIST_ROOM = 1024


def _problem_fields(problem):
    """An :class:`InstabilityError`'s fields (what crosses between processes: the exception does not pickle), or None."""
    if problem is None:
        return None
    return (problem.step, problem.time, problem.check, problem.particle_id, problem.position)


def device_names(text):
    """``--devices``: "cuda:0,cuda:1" as a list, or a count N as cuda:0 .. cuda:N-1."""
    text = str(text).strip()
    if text.isdigit():
        return [f"cuda:{n}" for n in range(int(text))]
    return [d.strip() for d in text.split(",") if d.strip()]


class DecompositionError(RuntimeError):
    """A subdomain outgrew its rows (raise ``capacity_factor`` or rebalance more often).

    Example:

    ```python
    import warpsph
    from warpsph.decomposition import DecompositionError

    scene = warpsph.load_scene("scenes/dam_break.json", scale=0.05)
    try:
        warpsph.DecomposedSimulation(scene, ["cpu"], subdomains=2, rebalance_interval=20).run(frames=2)
    except DecompositionError:  # retry with more room per subdomain
        warpsph.DecomposedSimulation(scene, ["cpu"], subdomains=2, capacity_factor=2.5).run(frames=2)
    ```
    """


def combine(values, ops):
    """Subdomain 0's, 1's, ... values of one all-reduction (numpy arrays, in subdomain order) combined element by
    element: ``ops[k]`` "s" (sum, in subdomain order), "m" (max) or "-" (subdomain 0's)."""
    out = values[0].copy()
    for k, op in enumerate(ops):
        column = [v[k] for v in values]
        if op == "s":
            out[k] = sum(column[1:], column[0])
        elif op == "m":
            out[k] = max(column)
    return out


def reduced(pairs, posted):
    """Each (array, ops) of ``pairs`` set to every subdomain's values combined (:func:`combine`; ``posted[s][n]``:
    subdomain s's values of pair n, in subdomain order); returns the combined numpy arrays."""
    combined = []
    for n, (array, ops) in enumerate(pairs):
        out = combine([values[n] for values in posted], ops)
        array.assign(out)
        combined.append(out)
    return combined


def reusable(cache, key, count, dtype, device, spare=16, pinned=False):
    """``cache[key]``: an array of at least ``count`` entries of ``dtype`` on ``device``, reused from meeting to
    meeting; allocated (a quarter more, plus ``spare``) when missing or short."""
    a = cache.get(key)
    if a is None or a.shape[0] < count or a.dtype != dtype:
        a = cache[key] = wp.empty(int(count * 1.25) + spare, dtype=dtype, device=device, pinned=pinned)
    return a


class Outbox:
    """Rows a subdomain offers the others at one meeting: for subdomain j, rows
    ``index[j * room:][:counts[j]]`` of each array in ``arrays`` (the receiver puts them where its placements say)."""

    __slots__ = ("index", "room", "counts", "arrays")

    def __init__(self, index, room, counts, arrays):
        self.index, self.room, self.counts, self.arrays = index, room, counts, arrays

    def rows_for(self, j, count=None):
        """The device index list of the rows for subdomain ``j`` (its first ``count``; default all)."""
        count = int(self.counts[j]) if count is None else int(count)
        return self.index[j * self.room: j * self.room + count]


class Subdomain:
    """What one subdomain's Simulation sees of the others (its ``halo``): which rows leave, which rows the others
    need as ghosts and where theirs go (the slab logic); the meetings themselves are its ``comm``'s
    (:class:`Threads`: subdomains of one process; :class:`warpsph.distributed.MPIComm`: one process each)."""

    def __init__(self, group, index, device, capacity, comm):
        self.group, self.index, self.device, self.capacity, self.comm = group, index, device, capacity, comm
        self.ghosts = 0  # ghost rows after the subdomain's own particles
        self.arrived = 0  # particles that crossed into this subdomain so far
        self.cuts = wp.array(group.cuts, dtype=float, device=device)
        k = group.count
        self.leave_count = np.zeros(k, np.int64)
        # rows of this subdomain that subdomain j holds as ghosts: send_lists[j * send_room:][:send_count[j]]
        self.send_lists, self.send_room, self.send_count = None, 0, np.zeros(k, np.int64)
        # rows that leave for subdomain j: leavers[j * room:][:leave_count[j]]
        self.leavers, self.room = None, 0
        self.ghost_first = np.zeros(k, np.int64)  # where subdomain j's ghosts start in this one's rows
        self.ghost_count = np.zeros(k, np.int64)
        self.outbox = None  # the rows this subdomain offers the others at the meeting under way (an Outbox)
        # the communicator's own, per subdomain
        self.posted = ()  # what a reduction put up for the others
        self.posted_event = None  # CUDA: recorded after the posted arrays were written
        self.done_event = None  # CUDA: recorded after this subdomain's gathers from the others
        self._staging = {}  # rows gathered on another device before a copy across: by (device, dtype)
        self._snapshots = {}  # a reduction's values set aside for the others to read: by (position, dtype, shape)
        self._reduction_ops = {}  # the ops string of a reduction as a device array
        self._lists = {}  # device index lists reused from step to step, by name (leavers, ghosts, holes, movers, counts)

    global_count = property(lambda self: self.group.global_count)
    grid_points = property(lambda self: self.group.global_count)  # cells as fine as one simulation's

    def ghost_placements(self):
        """(first row, count) of subdomain j's ghost rows in this one's, for every j (0 rows for itself)."""
        return [(int(f), int(c)) for f, c in zip(self.ghost_first, self.ghost_count)]

    # -- the three meeting points ------------------------------------------------------------------------
    def refresh(self, sim):
        """Start of a step: migration across the cuts, then the ghost rows."""
        self._migrate(sim)
        self._collect_ghosts(sim)

    def exchange(self, arrays):
        """The ghost rows of each of ``arrays`` (fields of this subdomain's rows) get their owners' values."""
        arrays = [a for a in arrays if a.shape[0]]
        self.outbox = Outbox(self.send_lists, self.send_room, self.send_count, arrays)
        self.comm.exchange(self, arrays, self.ghost_placements())

    def allreduce(self, pairs, read=True):
        """(array, ops) pairs combined over the subdomains in one meeting, in the same order of sums in all.
        ``read``: returns the combined values (numpy, through the host); else None (the communicator may combine
        them on the devices)."""
        return self.comm.allreduce(self, pairs, read)

    # -- refresh ----------------------------------------------------------------------------------------
    def _list(self, name, size):
        """A reusable device index list of at least ``size`` entries (grown by a quarter when short)."""
        return reusable(self._lists, name, size, wp.int32, self.device, spare=1024)

    def _migrate(self, sim):
        """Particles whose slab changed go to its subdomain: listed by destination on the device (``leavers``,
        ``room`` entries per destination), pulled by the others behind their rows; then this subdomain's stayers
        in the last ``leave`` rows fill the leavers' rows before them, and the arrivals follow."""
        group, k, n = self.group, self.index, sim.num_fluid
        counts = self._list("counts", group.count)
        room = max(MIN_LIST_ROOM, n // 16)
        while True:
            leavers = self._list("leavers", group.count * room)
            counts.zero_()
            sim.launch(list_leavers, n, [sim.fluid.x, group.axis, self.cuts, k, room, counts, leavers])
            leaving = counts.numpy()[: group.count].astype(np.int64)
            if leaving.max(initial=0) <= room:
                break
            room = int(leaving.max())
        leave = int(leaving.sum())
        self.leave_count, self.leavers, self.room = leaving, leavers, room
        rows = sim.state.carried_rows()
        self.outbox = Outbox(leavers, room, leaving, rows)
        arriving = self.comm.counts(self, leaving)  # arriving[j]: the rows subdomain j sends this one
        total_in = int(sum(arriving))
        if n + total_in > self.capacity:
            raise DecompositionError(f"subdomain {k} needs {n + total_in:,} rows of its {self.capacity:,} "
                                     "(raise capacity_factor or rebalance more often)")
        placements, first = [], n  # arrivals behind the old rows: the leavers' rows are still being read
        for j in range(group.count):
            count = 0 if j == k else int(arriving[j])
            placements.append((first, count))
            first += count
        self.comm.transfer(self, rows, placements)
        stay = n - leave
        if leave:  # the stayers among the last `leave` rows move into the leavers' rows before them
            holes, movers = self._list("holes", leave), self._list("movers", leave)
            found = self._list("found", 2)
            found.zero_()
            sim.launch(list_holes, group.count * room, [leavers, room, counts, stay, found, holes])
            sim.launch(list_movers, leave, [sim.fluid.x, group.axis, self.cuts, k, stay, found, movers])
            for a in rows:
                sim.launch(move_rows, leave, [holes, movers, found, a])
        moved = min(total_in, leave)  # the last arrivals fill the rows the leavers left at the end
        if moved:
            for a in rows:
                wp.copy(a, a, dest_offset=stay, src_offset=n + total_in - moved, count=moved)
        sim.state.num_fluid = stay + total_in
        self.arrived += total_in

    def _collect_ghosts(self, sim):
        """Lists, for every other subdomain, this one's particles within a support radius of its slab (on the
        device, ``room`` entries each); then takes its own ghost rows from the others' lists."""
        group, n = self.group, sim.num_fluid
        width = GHOST_WIDTH * sim.support_radius
        counts = self._list("ghost_counts", group.count)
        room = max(MIN_LIST_ROOM, n // 8)
        while True:
            index = self._list("ghost_index", group.count * room)
            counts.zero_()
            for peer in range(group.count):
                if peer != self.index:
                    lower, upper = group.slab_bounds(peer)
                    sim.launch(list_ghosts, n, [sim.fluid.x, group.axis, lower, upper, group.period, width, peer,
                                                room, counts, index])
            found = counts.numpy()[: group.count].astype(np.int64)
            if found.max(initial=0) <= room:
                break
            room = int(found.max())
        self.send_count, self.send_lists, self.send_room = found, index, room
        rows = sim.state.carried_rows()
        self.outbox = Outbox(index, room, found, rows)
        received = self.comm.counts(self, found)  # received[j]: subdomain j's rows that are ghosts here
        first = n
        for j in range(group.count):
            if j != self.index:
                self.ghost_first[j], self.ghost_count[j] = first, int(received[j])
                first += int(received[j])
        if first > self.capacity:
            raise DecompositionError(f"subdomain {self.index} needs {first:,} rows with its ghosts, of its "
                                     f"{self.capacity:,} (raise capacity_factor)")
        self.ghosts = first - n
        self.comm.transfer(self, rows, self.ghost_placements())


class Threads:
    """The communicator of the subdomains of one process (:class:`DecomposedSimulation`), one thread each (the
    threads of one device take turns between meetings). They meet at a :class:`threading.Barrier` and read each
    other's rows directly: gather kernels that read the other subdomain's memory (one CPU, or GPUs with peer access;
    else a gather on the owner's device and a peer ``wp.copy``). On GPUs with peer access, CUDA events order the
    exchanges and the reductions the solver does not read on the host, so those meetings wait on no device.

    The interface a communicator offers the subdomains (:class:`warpsph.distributed.MPIComm` is the other one):
    ``counts(sub, mine)`` (an all-to-all of row counts: what each subdomain holds for ``sub``), ``transfer(sub, dst,
    placements)`` (the rows of every subdomain's ``outbox`` for ``sub`` into ``dst`` at ``placements[j]`` = (first,
    count)), ``exchange(sub, arrays, placements)`` (the same for the ghost rows of fields), ``allreduce(sub, pairs,
    read)``; and for the group, ``local(count)`` (the subdomains this process steps), ``parallel(sims, work)``, ``everyone(values)``
    (every subdomain's values, in order, from this process's list of its own) and ``from_first(make)`` (the first
    process's ``make()``)."""

    def __init__(self, group, devices, count):
        self.group = group
        self.barrier = threading.Barrier(count)
        # one thread at a time on a device: Warp's scans and sorts share their temporary storage per device
        self.locks = {wp.get_device(d).alias: threading.Lock() for d in devices}

    @staticmethod
    def local(count):
        """The subdomains this process steps: all."""
        return list(range(count))

    @staticmethod
    def everyone(values):
        """Every subdomain's value, in subdomain order, from this process's list (one per subdomain it steps)."""
        return list(values)

    @staticmethod
    def from_first(make):
        """``make()`` as the first process computes it (here: computed)."""
        return make()

    # -- meeting the others --------------------------------------------------------------------------
    def _meet(self, sub):
        """Waits until this device's work is done and every subdomain has reached the same point."""
        wp.synchronize_device(sub.device)
        self._barrier(sub)

    def _barrier(self, sub):
        """The barrier, without the device's lock while waiting (subdomains of one device take turns)."""
        lock = self.locks[sub.device.alias]
        lock.release()
        try:
            self.barrier.wait()
        finally:
            lock.acquire()

    def _peers(self, sub):
        return [s for s in self.group.subdomains if s is not sub]

    def _pull(self, sub, dst, placements):
        """Rows of every other subdomain's outbox for ``sub`` into ``dst`` at ``placements``."""
        for peer in self._peers(sub):
            first, count = placements[peer.index]
            if count:
                box = peer.outbox
                index = box.rows_for(sub.index, count)
                for d, s in zip(dst, box.arrays):
                    self._gather(sub, s, index, first, d, count)

    def _gather(self, sub, src, index, first, dst, count):
        """dst[first + i] = src[index[i]], i < count: on dst's device (reading src's memory where peer access
        allows), else gathered on src's device and copied across."""
        if self.group.reads_directly(dst.device, src.device):
            wp.launch(gather_rows, count, [src, index, first, dst], device=dst.device)
        else:
            staging = reusable(sub._staging, (src.device.alias, src.dtype), count, src.dtype, src.device)
            wp.launch(gather_rows, count, [src, index, 0, staging], device=src.device)
            stream = src.device.stream if src.device.is_cuda else None  # after the gather
            wp.copy(dst, staging, dest_offset=first, count=count, stream=stream)

    # -- what the subdomains call --------------------------------------------------------------------
    def parallel(self, sims, work):
        """Runs ``work(sim)`` for every subdomain, one thread each; the first error stops them all."""
        def run(sim):
            try:
                with self.locks[sim.device.alias], wp.ScopedDevice(sim.device):
                    return work(sim)
            except BaseException:
                self.barrier.abort()  # the others stop at their next meeting point
                raise

        with ThreadPoolExecutor(len(sims)) as pool:
            futures = [pool.submit(run, s) for s in sims]
        errors = [f.exception() for f in futures if f.exception() is not None]
        if errors:
            self.barrier.reset()
            real = [e for e in errors if not isinstance(e, threading.BrokenBarrierError)]
            raise (real or errors)[0]
        return [f.result() for f in futures]

    def counts(self, sub, mine):
        """Meets the others (their outboxes posted); what each subdomain's outbox holds for ``sub``."""
        self._meet(sub)
        return np.array([0 if p is sub else int(p.outbox.counts[sub.index]) for p in self.group.subdomains], np.int64)

    def transfer(self, sub, dst, placements):
        """The others' outbox rows for ``sub`` into ``dst``; then meets them (their outboxes read by all)."""
        self._pull(sub, dst, placements)
        self._meet(sub)

    def exchange(self, sub, arrays, placements):
        if not self.group.asynchronous:
            self._meet(sub)
            self._pull(sub, arrays, placements)
            self._meet(sub)
            return
        # CUDA with peer access: ordered by events, the host waits for no device. Each stream waits for the
        # others' writes of the fields, gathers, and the others' streams wait for its gathers before they
        # write their own rows again.
        stream = sub.device.stream
        sub.posted_event = stream.record_event()
        self._barrier(sub)
        for peer in self._peers(sub):
            stream.wait_event(peer.posted_event)
        self._pull(sub, arrays, placements)
        sub.done_event = stream.record_event()
        self._barrier(sub)
        for peer in self._peers(sub):
            stream.wait_event(peer.done_event)

    def allreduce(self, sub, pairs, read=True):
        """``read``: combined through the host and returned; else, where every subdomain can read the others'
        memory, combined on the devices (:meth:`_allreduce_on_devices`) and None returned."""
        if not read and self.group.direct:
            return self._allreduce_on_devices(sub, pairs)
        sub.posted = [array.numpy().copy() for array, _ in pairs]  # waits for the device (CPU: numpy() is a view)
        self._barrier(sub)
        combined = reduced(pairs, [s.posted for s in self.group.subdomains])
        self._barrier(sub)  # the posted values are read by all before the next reduction
        return combined

    def _allreduce_on_devices(self, sub, pairs):
        """Each subdomain copies its values aside; after the meeting each one combines subdomain 0's, 1's, ...
        copies into its arrays on its own device (the others' memory read directly), so the host waits for no
        device; on GPUs, events order the copies and the reads."""
        stream = sub.device.stream if sub.device.is_cuda else None
        sub.posted = []
        for n, (array, ops) in enumerate(pairs):
            key = (n, array.dtype, array.shape)
            snapshot = sub._snapshots.get(key)
            if snapshot is None:
                snapshot = sub._snapshots[key] = wp.empty_like(array)
            if ops not in sub._reduction_ops:
                sub._reduction_ops[ops] = wp.array(["-sm".index(o) for o in ops], dtype=wp.int32, device=sub.device)
            wp.copy(snapshot, array)
            sub.posted.append(snapshot)
        if stream is not None:
            sub.posted_event = stream.record_event()
        self._barrier(sub)
        if stream is not None:
            for peer in self._peers(sub):
                stream.wait_event(peer.posted_event)
        first = self.group.subdomains[0]
        for n, (array, ops) in enumerate(pairs):
            wp.copy(array, first.posted[n])
            for other in self.group.subdomains[1:]:
                wp.launch(combine_values, array.shape[0], [other.posted[n], sub._reduction_ops[ops], array],
                          device=sub.device)
        if stream is not None:
            sub.done_event = stream.record_event()
        self._barrier(sub)  # the copies are read by all before the next reduction overwrites them
        if stream is not None:
            for peer in self._peers(sub):
                stream.wait_event(peer.done_event)
        return None


class DecomposedSimulation:
    """A scene split into ``subdomains`` slabs along ``axis`` (default: the domain's longest), subdomain k on
    ``devices[k % len(devices)]``. Steps, frames and the accessors of :class:`Simulation`; the particle
    accessors gather every subdomain's particles, ordered by id.

    Example:

    ```python
    import warpsph

    scene = warpsph.load_scene("scenes/dam_break.json", scale=0.05)
    sim = warpsph.DecomposedSimulation(scene, ["cpu"], subdomains=2)  # ["cuda:0", "cuda:1"]: one slab per GPU
    sim.run(frames=10)
    x = sim.positions()  # every subdomain's particles, ordered by id
    ```
    """

    def __init__(self, scene, devices, subdomains=None, axis=None, capacity_factor=CAPACITY_FACTOR,
                 rebalance_interval=100, state=None, comm=None):
        """``state``: (arrays, flags) of one simulation of the scene (``Simulation.state_arrays()`` as numpy,
        ``state_flags()``; a checkpoint's) to start from instead of the scene's initial particles. ``comm``: how
        the subdomains meet; None: :class:`Threads`, every subdomain in this process; an
        :class:`~warpsph.distributed.MPIComm`: one subdomain in each process of its MPI communicator, this one's on
        ``devices[0]`` (:class:`~warpsph.distributed.DistributedSimulation`)."""
        devices = [wp.get_device(d) for d in devices]
        self.count = comm.size if comm is not None else subdomains or len(devices)
        self.comm = comm if comm is not None else Threads(self, devices, self.count)
        self.scene = scene
        self.rebalance_interval = rebalance_interval
        self._refuse_unsupported(scene)
        extent = np.subtract(scene.domain.max, scene.domain.min)
        self.axis = int(np.argmax(extent)) if axis is None else int(axis)
        self.period = float(scene.domain.period[self.axis])
        self.lower, self.upper = float(scene.domain.min[self.axis]), float(scene.domain.max[self.axis])
        if state is not None:
            arrays, flags = state
            count = int(flags["num_fluid"])
            x, v, ids = (arrays[f"fluid/{k}"][:count] for k in ("x", "v", "ids"))
        else:  # sampled (and packed) once: on the first process, sent to the others
            x, v = self.comm.from_first(lambda: self._initial_fluid(scene, devices[0]))
            ids = np.arange(len(x), dtype=np.int32)
        self.global_count = len(x)
        self.cuts = self._balanced_cuts(x[:, self.axis])
        slab = np.searchsorted(self.cuts, x[:, self.axis], side="right")
        capacity = self._capacity(x[:, self.axis], slab, scene.support_radius, capacity_factor)
        self.subdomains, self.sims = [], []  # this process's
        for k in self.comm.local(self.count):
            device = devices[k % len(devices)]
            halo = Subdomain(self, k, device, capacity, self.comm)
            mine = slab == k
            sim = Simulation(scene, device=device, particles=(x[mine], v[mine], ids[mine]), halo=halo)
            halo.sim = sim
            self.subdomains.append(halo)
            self.sims.append(sim)
        self.device = self.sims[0].device
        self.peer_access = self._enable_peer_access(devices)
        # exchanges ordered by CUDA events alone: every device a GPU, each reading the others' memory
        self.asynchronous = all(d.is_cuda for d in devices) and all(self.peer_access.values())
        # every subdomain reads the others' memory (one CPU, or GPUs with peer access): reductions on the devices
        self.direct = self.asynchronous or all(d.is_cpu for d in devices)
        if state is not None:
            self._restore(state, slab)
        for name in [m for m in sys.modules if m.startswith("warpsph.kernels.")]:  # not from several threads at once
            for alias in sorted({s.device.alias for s in self.sims}):
                wp.load_module(name, device=alias)
        self._parallel(lambda s: (s.halo.refresh(s), s.update_densities()))

    @staticmethod
    def _enable_peer_access(devices):
        """Direct copies between the GPUs where they allow it (else the driver stages them through the host):
        {"cuda:0->cuda:1": True, ...}."""
        cuda = sorted({d.alias: d for d in devices if d.is_cuda}.values(), key=lambda d: d.alias)
        enabled = {}
        for a in cuda:
            for b in cuda:
                if a is not b:
                    ok = wp.is_peer_access_supported(a, b) and wp.is_mempool_access_supported(a, b)
                    if ok:
                        wp.set_peer_access_enabled(a, b, True)
                        wp.set_mempool_access_enabled(a, b, True)
                    enabled[f"{a.alias}->{b.alias}"] = bool(ok)
        return enabled

    def reads_directly(self, reader, owner):
        """Whether a kernel on device ``reader`` reads arrays on ``owner`` (the same device, or peer access);
        else rows are gathered on ``owner`` and copied across."""
        return reader == owner or bool(self.peer_access.get(f"{reader.alias}->{owner.alias}"))

    @staticmethod
    def _initial_fluid(scene, device):
        """The scene's fluid particles as one simulation samples them: blocks and meshes, less what lies
        inside closed bodies, packed when the scene asks."""
        x, v, _, _, bodies = sample_scene(scene, limit_fluid=False)  # the subdomains' rows are limited instead
        x, v = remove_fluid_inside_bodies(scene, bodies, x, v, device, lambda k, d, a: wp.launch(k, d, a, device=device))
        if scene.initial_packing is not None:
            x = np.array(x)
            packed = packed_positions(scene, device, Simulation)
            x[: len(packed)] = packed
        return x, v

    def _restore(self, state, slab):
        """Each subdomain's rows of every carried array, and the rest (clock, solver totals, flags) as saved."""
        arrays, flags = state
        count = int(flags["num_fluid"])
        for sim in self.sims:
            rows = {id(a) for a in sim.state.carried_rows()}
            mine = np.flatnonzero(slab == sim.halo.index)
            for name, a in sim.state_arrays().items():
                data = arrays[name]
                if id(a) in rows:
                    if len(mine):
                        a[: len(mine)].assign(np.ascontiguousarray(data[:count][mine]))
                else:
                    a.assign(data)
            sim.restore_flags({**flags, "num_fluid": len(mine)})

    @staticmethod
    def _refuse_unsupported(scene):
        unsupported = [("emitters", scene.emitters), ("sinks", scene.sinks), ("domain.open", scene.domain.is_open),
                       ("solver.method", not solver_class(scene.solver.method).decomposable),
                       ("obstacles.dynamics", any(o.dynamics is not None for o in scene.obstacles))]
        for key, present in unsupported:
            if present:
                raise SceneError(scene.source, key, "is not supported on several subdomains yet (issue #22): "
                                                    "run this scene on one device")

    # -- cuts ----------------------------------------------------------------------------------------------
    def _balanced_cuts(self, coordinate):
        """Interior cuts at the quantiles of the fluid along the axis: equal particle counts."""
        return np.quantile(coordinate, np.arange(1, self.count) / self.count).astype(np.float32)

    def _capacity(self, coordinate, slab, support_radius, factor):
        """Rows per subdomain: ``factor`` x the largest initial share with its ghosts, at most every particle
        (a subdomain never holds more than all of them: each of the others sends a particle once)."""
        need = 0
        for k in range(self.count):
            lower, upper = self.slab_bounds(k)
            gap = np.maximum(np.maximum(lower - coordinate, coordinate - upper), 0.0)
            if self.period > 0.0:
                for shift in (self.period, -self.period):
                    c = coordinate + shift
                    gap = np.minimum(gap, np.maximum(np.maximum(lower - c, c - upper), 0.0))
            need = max(need, int(np.sum(gap < GHOST_WIDTH * support_radius)))
        if need > scene_setup.MAX_PARTICLES:  # int32 neighbour lists: the limit of one simulation, per subdomain here
            raise SceneError(self.scene.source, "particle_radius",
                             f"{len(coordinate):,} particles put {need:,} in a subdomain with its ghosts, over the "
                             f"{scene_setup.MAX_PARTICLES:,} limit of one: use more subdomains, a larger radius or a "
                             "smaller --scale")
        return min(len(coordinate), int(factor * need) + 64)

    def slab_bounds(self, k):
        """[lower, upper) of slab k along the axis (unbounded outward where the axis is not periodic).

        Example:

        ```python
        import warpsph

        scene = warpsph.load_scene("scenes/dam_break.json", scale=0.05)
        sim = warpsph.DecomposedSimulation(scene, ["cpu"], subdomains=2)
        print([sim.slab_bounds(k) for k in range(2)])  # the cut at the fluid's median along sim.axis
        ```
        """
        lower, upper = (self.lower, self.upper) if self.period > 0.0 else (-1e30, 1e30)
        return (lower if k == 0 else float(self.cuts[k - 1]),
                upper if k == self.count - 1 else float(self.cuts[k]))

    def rebalance(self):
        """Moves the cuts back to the fluid's quantiles (the next step migrates the particles).

        Example:

        ```python
        import warpsph

        scene = warpsph.load_scene("scenes/dam_break.json", scale=0.05)
        sim = warpsph.DecomposedSimulation(scene, ["cpu"], subdomains=2)
        sim.run(frames=3)
        sim.rebalance()  # also every rebalance_interval steps (default 100)
        ```
        """
        coordinate = np.concatenate(self.comm.everyone([s.host(s.fluid.x)[:, self.axis] for s in self.sims]))
        self.cuts = self._balanced_cuts(coordinate)
        for s in self.subdomains:
            s.cuts.assign(self.cuts)

    # -- lockstep -------------------------------------------------------------------------------------------
    def _parallel(self, work):
        """Runs ``work(sim)`` for every subdomain of this process (the communicator's way: a thread each, or at once
        where it has one); the first error stops them all."""
        return self.comm.parallel(self.sims, work)

    def step(self):
        if self.rebalance_interval and self.step_count and self.step_count % self.rebalance_interval == 0:
            self.rebalance()
        self._parallel(lambda s: s.step())

    # -- what Simulation offers (the writers, diagnostics and checkpoints read these) -----------------------------------------------------------------------------
    num_fluid = property(lambda self: self.global_count)
    capacity = property(lambda self: self.global_count)
    inflow = None
    num_boundary = property(lambda self: self.sims[0].num_boundary)
    boundary = property(lambda self: self.sims[0].boundary)
    bodies = property(lambda self: self.sims[0].bodies)
    moving_bodies = property(lambda self: self.sims[0].moving_bodies)
    turbulence_models = property(lambda self: self.sims[0].turbulence_models)
    pressure_solver = property(lambda self: self.sims[0].pressure_solver)  # iteration totals: the same in all
    dt = property(lambda self: self.sims[0].dt)
    rest_density = property(lambda self: self.sims[0].rest_density)

    @property
    def on_instability(self):
        return "stop"

    @on_instability.setter
    def on_instability(self, value):
        if value != "stop":
            raise SceneError("", "--on-instability", f"{value} is not supported on several subdomains yet: use stop")

    def parts(self):
        """The subdomains' simulations (writers and diagnostics read each one's own rows)."""
        return list(self.sims)

    def fields(self):
        """The published fields of subdomain 0 (the same names in all; each part's arrays: ``parts()``)."""
        return self.sims[0].fields()

    def field_values(self, name):
        return self._gathered(lambda s: s.field_values(name))

    def state_arrays(self):
        """The carried arrays as one simulation of the scene holds them (a checkpoint that loads on one device
        or several): the per-particle ones gathered in id order (host arrays), the others subdomain 0's."""
        first = self.sims[0]
        rows = {id(a) for a in first.state.carried_rows()}
        order = np.argsort(np.concatenate(self.comm.everyone([s.ids() for s in self.sims])), kind="stable")
        out = {}
        for name, a in first.state_arrays().items():
            if id(a) in rows:
                data = np.concatenate(self.comm.everyone([s.host(s.state_arrays()[name]) for s in self.sims]))[order]
                out[name] = wp.array(data, dtype=a.dtype, device="cpu")
            else:
                out[name] = a
        return out

    def state_flags(self):
        return {**self.sims[0].state_flags(), "num_fluid": self.global_count}

    time = property(lambda self: self.sims[0].time)
    step_count = property(lambda self: self.sims[0].step_count)
    particle_mass = property(lambda self: self.sims[0].particle_mass)
    fluid_volume = property(lambda self: self.sims[0].fluid_volume)

    @property
    def frame(self):
        return self.sims[0].frame

    @frame.setter
    def frame(self, value):
        for s in self.sims:
            s.state.frame = value

    def check_health(self):
        """The first subdomain's failed health check (an :class:`InstabilityError`, the same in every process), or
        None."""
        mine = {s.halo.index: s.check_health() for s in self.sims}
        for k, problem in enumerate(self.comm.everyone([_problem_fields(p) for p in mine.values()])):
            if problem is not None:
                return mine[k] if k in mine else InstabilityError(*problem)  # another process's: its fields
        return None

    def statistics(self):
        return self.sims[0].statistics()  # the solvers iterate together: the same counts everywhere

    def _gathered(self, read):
        """One per-particle quantity of every subdomain's own particles, rows ordered by id."""
        ids = np.concatenate(self.comm.everyone([s.ids() for s in self.sims]))
        values = np.concatenate(self.comm.everyone([read(s) for s in self.sims]))
        return values[np.argsort(ids, kind="stable")]

    def ids(self):
        return np.sort(np.concatenate(self.comm.everyone([s.ids() for s in self.sims])))

    def positions(self):
        return self._gathered(lambda s: s.positions())

    def velocities(self):
        return self._gathered(lambda s: s.velocities())

    def densities(self):
        return self._gathered(lambda s: s.densities())

    def kinetic_energy(self):
        return sum(self.comm.everyone([s.kinetic_energy() for s in self.sims]))

    def owned_counts(self):
        """Particles per subdomain (its own, without ghosts).

        Example:

        ```python
        import warpsph

        scene = warpsph.load_scene("scenes/dam_break.json", scale=0.05)
        sim = warpsph.DecomposedSimulation(scene, ["cpu"], subdomains=2)
        assert sum(sim.owned_counts()) == sim.num_fluid
        ```
        """
        return self.comm.everyone([s.num_fluid for s in self.sims])

    def _advance_to(self, target, on_step=None):
        """Steps until ``time >= target``, stopping at the first failed health check (``on_step(self)`` after each
        step that passed it)."""
        while self.time < target - 1e-9:
            self.step()
            problem = self.check_health()
            if problem is not None:
                raise problem
            if on_step is not None:
                on_step(self)

    run = Simulation.run
