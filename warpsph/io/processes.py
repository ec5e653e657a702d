"""Processes of a run's own: the surface meshers and the single-file cache's writer.

Warp's launches, pysplashsurf and pxr (USD) each hold the GIL through long calls, which the simulation's host thread
needs for every step; work that is not the simulation's goes to spawned processes, each with its GIL (and, for
a preview mesher, its own Warp device state). They start with :func:`start_workers` and stop with
:func:`stop_workers`; a worker ignores SIGINT and SIGTERM (the run's process finishes the frame, saves and stops
it) and exits when the run's process dies.

Arrays go to and fro through files in a folder of the owner's own (in /dev/shm where there is one): a file is
written or read in one system call, outside the GIL (:func:`store`, :func:`load`; :func:`store_tree` and
:func:`load_tree` for the arrays inside tuples, lists, dicts and dataclasses). By pickle the run's process
pickled a 1M-particle frame's 36 MB and unpickled its ~100 MB mesh, read off the pipe in 64 KB pieces, holding
the GIL: 190-310 ms of the simulation's thread a frame on a 2-core VM (``python tools/bench_internals.py surface-host``).
"""

from __future__ import annotations

import dataclasses
import os
import time
from dataclasses import dataclass

import numpy as np


def exchange_root():
    """Where the workers' folders go: /dev/shm (memory) where there is one, else the temp folder (None)."""
    shm = "/dev/shm"
    return shm if os.path.isdir(shm) and os.access(shm, os.W_OK | os.X_OK) else None


@dataclass(frozen=True)
class Stored:
    """An array in a file of its own (raw bytes in C order): what goes between processes instead of it."""

    path: str
    dtype: str
    shape: tuple


def store(path, array):
    """``array`` written to ``path`` (one write, outside the GIL) as a :class:`Stored`; None stays None. Where the
    file cannot be written (no space: /dev/shm is small in some containers), the array itself (goes by pickle)."""
    if array is None:
        return None
    array = np.ascontiguousarray(array)
    try:
        with open(path, "wb", buffering=0) as f:
            view = memoryview(array.reshape(-1).view(np.uint8))
            while len(view):
                view = view[f.write(view):]
    except OSError:
        try:
            os.unlink(path)
        except OSError:
            pass
        return array
    return Stored(path, array.dtype.str, array.shape)


def load(item):
    """The array of a :class:`Stored` (read in one call, outside the GIL); anything else as it is."""
    if not isinstance(item, Stored):
        return item
    array = np.empty(item.shape, np.dtype(item.dtype))
    with open(item.path, "rb", buffering=0) as f:
        view = memoryview(array.reshape(-1).view(np.uint8))
        while len(view):
            n = f.readinto(view)
            if not n:
                raise EOFError(f"{item.path}: {len(view)} bytes short")
            view = view[n:]
    return array


def _convert(value, convert):
    """``value`` with ``convert(array)`` of each numpy array (or :class:`Stored`) inside it: tuples, lists, dicts
    and dataclasses are rebuilt around them."""
    if isinstance(value, (np.ndarray, Stored)):
        return convert(value)
    if isinstance(value, dict):
        return {k: _convert(v, convert) for k, v in value.items()}
    if isinstance(value, (tuple, list)):
        return type(value)(_convert(v, convert) for v in value)
    if dataclasses.is_dataclass(value) and not isinstance(value, type):
        return dataclasses.replace(value, **{f.name: _convert(getattr(value, f.name), convert)
                                             for f in dataclasses.fields(value) if f.init})
    return value


def store_tree(value, folder):
    """``value`` with every numpy array inside it stored in a file of ``folder`` (:func:`store`; files 0, 1, ...)."""
    from itertools import count

    names = count()
    return _convert(value, lambda a: store(os.path.join(folder, str(next(names))), a) if isinstance(a, np.ndarray)
                    else a)


def load_tree(value):
    """``value`` from :func:`store_tree` with its arrays read back (the files stay: the caller removes them)."""
    return _convert(value, load)


def start_workers(owner, workers, threads=1, setup=None, setup_args=(), prefix="warpsph-worker"):
    """(folder, its remover, pool): ``workers`` spawned processes (:func:`_init_worker`: ``threads`` cores
    each; ``setup(*setup_args)`` once in each, a module-level function) and a folder of ``owner``'s own for
    the arrays that go to and fro (:func:`store`; in /dev/shm where there is one), removed by the remover, when
    ``owner`` is collected, or at exit."""
    import multiprocessing
    import shutil
    import tempfile
    import weakref
    from concurrent.futures import ProcessPoolExecutor

    folder = tempfile.mkdtemp(prefix=f"{prefix}-{os.getpid()}-", dir=exchange_root())
    remove = weakref.finalize(owner, shutil.rmtree, folder, True)
    pool = ProcessPoolExecutor(max_workers=workers, mp_context=multiprocessing.get_context("spawn"),
                               initializer=_init_worker, initargs=(threads, setup, setup_args))
    return folder, remove, pool


def stop_workers(pool, remove):
    """Waits for ``pool``'s jobs and stops its processes, then removes their folder (``remove``)."""
    try:
        pool.shutdown(wait=True)
    finally:
        remove()


WORKER_NICENESS = 10  # the simulation's host thread launches the GPU's work: it goes first on a busy CPU


def _init_worker(threads, setup=None, setup_args=()):
    """A worker: its share of the cores (splashsurf's rayon pool reads RAYON_NUM_THREADS when it starts) at a
    lower CPU priority than the simulation, then ``setup(*setup_args)``. It ignores SIGINT and SIGTERM, which a
    terminal or a process-group kill sends to the whole group: the run's process finishes the frame, saves and
    stops it. It exits when the run's process dies (:func:`_exit_with_parent`): a run SIGKILLed alone, by the
    out-of-memory killer, left its worker running."""
    import signal

    signal.signal(signal.SIGINT, signal.SIG_IGN)
    signal.signal(signal.SIGTERM, signal.SIG_IGN)
    _exit_with_parent()
    os.environ.setdefault("RAYON_NUM_THREADS", str(threads))
    if hasattr(os, "nice"):
        os.nice(WORKER_NICENESS)
    if setup is not None:
        setup(*setup_args)


PARENT_POLL_SECONDS = 0.25  # how often a worker looks for its run's process


def _exit_with_parent():
    """Ends this worker process (``os._exit``) soon after the process that started it dies: a daemon thread
    compares ``os.getppid()`` with the parent's pid every :data:`PARENT_POLL_SECONDS` (a system call; the
    parent's death reparents the worker at once). The worker ignores SIGINT and SIGTERM, and its pool's
    pipes are shared with the other workers, so before this a run SIGKILLed alone (not its group: the
    out-of-memory killer) left its workers, and multiprocessing's resource tracker, running for ever.

    Not ``prctl(PR_SET_PDEATHSIG)``: Linux sends that signal when the *thread* that started the process ends,
    and a pool starts its workers on the thread that first submits to it (a mesher's or the writer's), which
    ends before the pool is shut down. The thread needs the GIL, so a worker inside a call that holds it
    (pysplashsurf, a USD save) exits when that call is done."""
    import multiprocessing
    import threading

    parent = multiprocessing.parent_process()  # its pid as the parent wrote it, not the getppid() of now
    if parent is None:
        return
    if os.getppid() != parent.pid:  # it died while this worker started
        os._exit(1)
    threading.Thread(target=_watch_parent, args=(parent.pid,), name="warpsph-parent-watch", daemon=True).start()


def _watch_parent(pid):
    while os.getppid() == pid:
        time.sleep(PARENT_POLL_SECONDS)
    os._exit(1)
