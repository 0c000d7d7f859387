"""ClusterChecker: a World's batch checks cut into chunks, each answered by a Ray actor.

Replicas. Every worker is a Ray actor holding a World built once from the caller's World's
:class:`~collision_node.pipeline.world.Description` (settings, colliders, filters, robot). The
checker keeps one more replica in the caller, the source of truth: a scene verb is tried on it
first (a ValueError there changes nothing anywhere), then sent to every worker with the next
version number. A worker answers a chunk only at the version the chunk names; a worker at
another version (an actor restarted from an older description, say) answers "stale", is
loaded again from the current description and the chunk is rerun. Verbs are refused while a
batch runs, so every chunk of a batch is answered at one version.

Order. A batch is cut into chunks of consecutive states; a worker adds its chunk's first
state to ``state``, and chunks are put back in order. Each state is checked alone by the same
World, so the whole answer is one World's to the bit, whatever the chunking and the workers.

Faults. A chunk whose worker died (``ray.kill``, killed for memory, its node lost) is queued
again; the dead actor is replaced by a new one built from the current description while the
restart budget lasts. When no worker is left, :class:`ClusterError` says how many states were
answered: a partial answer is never returned as a whole one.
"""
import collections
import contextlib
import os
import time

import numpy as np
import ray
from ray.exceptions import OutOfMemoryError, RayActorError, WorkerCrashedError

from collision_node.pipeline.contacts import STATE_CONTACT_DTYPE
from collision_node.pipeline.obb import check_boxes, InvalidBox
from collision_node.pipeline.world import Result, World

# Ray's guidance: a task under about 10 ms gains nothing from running remotely. A state of
# the 7-box arm costs about 1 µs, so 10^4 states make a chunk of about 10 ms.
DEFAULT_CHUNK = 10_000
# Chunks queued per worker: one being checked, one on its way, so a worker never waits.
DEFAULT_IN_FLIGHT = 2
# How a chunk's worker can be lost: killed (ray.kill, memory monitor) or its process crashed.
_LOST = (RayActorError, WorkerCrashedError, OutOfMemoryError)
STATES, JOINTS = 'states', 'joints'
# A worker's glibc keeps the memory a chunk frees for the next chunk rather than handing it
# back to the system: otherwise a Ray worker page-faults again on every chunk's few MB (its
# input's copy, the World's buffers, the contacts: about 900 faults, and a 10^4-state chunk
# of the arm took 17-25 ms against 11 ms on the benchmark's VM), which a warm World in the
# caller's process does not.
# Ignored where malloc is not glibc's. Costs a worker up to the trim threshold of kept memory.
_WORKER_ENV = {'env_vars': {'MALLOC_MMAP_THRESHOLD_': str(32 << 20),
                            'MALLOC_TRIM_THRESHOLD_': str(128 << 20)}}


class ClusterError(RuntimeError):
    """A batch that could not be completed: ``answered`` of ``total`` states were answered.

    ``total`` is None for a stream, whose length is not known ahead.
    """

    def __init__(self, answered, total, reason):
        of = '' if total is None else ' of %d' % total
        super().__init__('batch not completed, %d%s states answered: %s'
                         % (answered, of, reason))
        self.answered = answered
        self.total = total


class Replica:
    """A worker: a World built from a Description, answering chunks at one scene version."""

    def __init__(self, description, version, threads=1):
        self._threads = threads
        self._world = None
        self.load(description, version)

    def load(self, description, version):
        """Build the World again from ``description``, at ``version``."""
        if self._world is not None:
            self._world.close()
        self._world = World.from_description(description, threads=self._threads)
        self._version = version

    def apply(self, version, verb, arguments):
        """Call the scene verb (``move_static``...) with ``arguments``; then at ``version``."""
        getattr(self._world, verb)(*arguments)
        self._version = version

    def check(self, version, kind, first, block, half_extents):
        """Return (version, contacts of the chunk's states, ``state`` from ``first``).

        (this worker's version, None) when it is not at ``version``: nothing is checked.
        """
        if version != self._version:
            return self._version, None
        if kind == STATES:
            contacts = self._world.check_states(block, half_extents).contacts
        else:
            contacts = self._world.check_joints(block).contacts
        contacts = rows_copy(contacts)  # the World's answer is read-only
        contacts['state'] += first
        return version, contacts

    def where(self):
        """Return (Ray node id, process id) of this worker."""
        return ray.get_runtime_context().get_node_id(), os.getpid()


_RemoteReplica = ray.remote(Replica)


# Contacts are copied as bytes: numpy copies a structured array field by field, some 20 times
# slower (0.7 ms against 0.04 ms for a chunk's 1.6 MB of contacts), work that every chunk's
# worker and the caller would otherwise do on top of the check itself.
def rows_copy(contacts):
    """Return a writable copy of the contacts array ``contacts``."""
    return np.ascontiguousarray(contacts).view(np.uint8).copy().view(contacts.dtype)


def rows_concatenated(parts):
    """Return the contacts arrays ``parts`` (one dtype, at least one) end to end.

    One part is returned as it is, read-only as Ray hands it over: no copy for one chunk.
    """
    if len(parts) == 1:
        return parts[0]
    return np.concatenate([np.ascontiguousarray(part).view(np.uint8) for part in parts]) \
        .view(parts[0].dtype)


class _Echo:
    """An actor that answers any chunk with the contacts it was given, checking nothing."""

    def __init__(self, contacts):
        self._contacts = contacts

    def answer(self, chunk):
        """Return the contacts (``chunk`` only travels)."""
        return self._contacts


def transport_only(contacts):
    """Return ``send(chunk)``: a chunk's trip to an actor and ``contacts``' trip back, no check.

    Ray's floor under a checker's chunk of the same size and answer, for the benchmark
    (benchmarks/cluster_bench.py) to print beside it.
    """
    echo = ray.remote(num_cpus=1)(_Echo).remote(contacts)
    return lambda chunk: ray.get(echo.answer.remote(chunk))


@contextlib.contextmanager
def local_ray(num_cpus=None):
    """Run a local Ray of ``num_cpus`` CPUs (default: all) for the block; checkers join it."""
    ray.init(num_cpus=num_cpus, include_dashboard=False, log_to_driver=False)
    try:
        yield
    finally:
        ray.shutdown()


class ClusterChecker:
    """``check_states`` and ``check_joints`` of a World, answered by Ray actors (module doc)."""

    def __init__(self, world, workers=2, chunk=DEFAULT_CHUNK, in_flight=DEFAULT_IN_FLIGHT,
                 restarts=None, threads=1, address=None):
        """Replicate ``world`` (a configured World) on ``workers`` new Ray actors.

        ``chunk``: states a call to a worker; ``in_flight``: chunks queued per worker;
        ``restarts``: actors that may be started to replace lost ones over the checker's life
        (default: ``workers``); ``threads``: each worker World's threads (and CPUs asked of
        Ray). Joins the Ray of this process if there is one, else the cluster at ``address``
        ('auto': the one ``ray start`` runs on this machine) if given, else starts a local
        Ray. Raises ValueError on a bad count.
        """
        for name, value in (('workers', workers), ('chunk', chunk), ('in_flight', in_flight),
                            ('threads', threads)):
            if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < 1:
                raise ValueError('%s must be a positive integer, got %r' % (name, value))
        restarts = workers if restarts is None else restarts
        if isinstance(restarts, bool) or not isinstance(restarts, (int, np.integer)) \
                or restarts < 0:
            raise ValueError('restarts must be a non-negative integer, got %r' % (restarts,))
        self._chunk, self._in_flight, self._threads = int(chunk), int(in_flight), int(threads)
        self._restarts_left = int(restarts)
        self.restarts = 0  # actors started to replace lost ones
        self.reruns = 0    # chunks sent again (a lost worker, a stale one)
        self._world = World.from_description(world.describe(), threads=1)
        self._robot = self._world.describe().robot
        self._version = 0
        self._description_ref = None  # the current description in Ray's object store
        self._running = False
        self._started_ray = False
        if not ray.is_initialized():
            if address is not None:
                ray.init(address=address)
            else:
                ray.init(include_dashboard=False)
                self._started_ray = True
        self._slots = [self._new_worker() for _ in range(workers)]

    # ------------------------------------------------------------------ workers

    @property
    def workers(self):
        """Return the live workers' Ray actor handles."""
        return [worker for worker in self._slots if worker is not None]

    def _description(self):
        if self._description_ref is None:
            self._description_ref = ray.put(self._world.describe())
        return self._description_ref

    def _new_worker(self):
        return _RemoteReplica.options(num_cpus=self._threads, max_restarts=0,
                                      scheduling_strategy='SPREAD',
                                      runtime_env=_WORKER_ENV).remote(
            self._description(), self._version, self._threads)

    def _lost(self, slot, worker):
        """Replace ``worker`` of ``slot``, lost, while the budget lasts; else leave it empty."""
        if self._slots[slot] is not worker:
            return  # replaced already, at its first lost chunk
        if self._restarts_left > 0:
            self._restarts_left -= 1
            self.restarts += 1
            self._slots[slot] = self._new_worker()
        else:
            self._slots[slot] = None

    def close(self):
        """Kill the workers (and shut down the Ray this checker started)."""
        for worker in self.workers:
            ray.kill(worker)
        self._slots = []
        if self._started_ray:
            ray.shutdown()
            self._started_ray = False

    def __enter__(self):
        return self

    def __exit__(self, *exception):
        self.close()

    # ------------------------------------------------------------------ the scene

    def add_static(self, ids, poses, half_extents, margins=0.0, categories=1, masks=-1,
                   enabled=True):
        """World.add_static on every worker (then the next version)."""
        return self._verb('add_static', ids, poses, half_extents, margins, categories, masks,
                          enabled)

    def move_static(self, ids, poses=None, half_extents=None):
        """World.move_static on every worker (then the next version)."""
        return self._verb('move_static', ids, poses, half_extents)

    def remove_static(self, ids):
        """World.remove_static on every worker (then the next version)."""
        return self._verb('remove_static', ids)

    def enable_static(self, ids, enabled):
        """World.enable_static on every worker (then the next version)."""
        return self._verb('enable_static', ids, enabled)

    def update_static(self, ids, margins=None, categories=None, masks=None):
        """World.update_static on every worker (then the next version)."""
        return self._verb('update_static', ids, margins, categories, masks)

    @property
    def static_colliders(self):
        """Return the colliders every worker holds (World.static_colliders)."""
        return self._world.static_colliders

    @property
    def version(self):
        """Return the scene version: the number of scene changes so far."""
        return self._version

    def _verb(self, verb, *arguments):
        if self._running:
            raise RuntimeError('a batch is being answered: change the scene between batches')
        answer = getattr(self._world, verb)(*arguments)  # a ValueError here: nothing sent
        self._version += 1
        self._description_ref = None
        for worker in self.workers:  # an actor runs its calls in the order they were sent
            worker.apply.remote(self._version, verb, arguments)
        return answer

    # ------------------------------------------------------------------ batches

    def check_states(self, states, half_extents):
        """Answer K states of box poses as the replicated World, in one process, answers them.

        The same contacts in the same order (``state`` the index in the whole batch); its
        ``stats`` count states, chunks, reruns and replaced workers. Every state is checked
        for a ValueError (World's message) before anything is sent; ClusterError when the
        batch cannot be completed.
        """
        start = time.perf_counter()
        states, extents = self._checked_states(states, half_extents)
        pieces = self._pieces(states)
        return self._batch(self._stream(STATES, pieces, extents, len(states)), len(states),
                           start)

    def check_joints(self, q):
        """Answer K joint states q as the replicated World's check_joints answers them."""
        start = time.perf_counter()
        states = self._checked_joints(q)
        return self._batch(self._stream(JOINTS, self._pieces(states), None, len(states)),
                           len(states), start)

    def stream_states(self, blocks, half_extents):
        """Yield (first state, count, contacts) per chunk of the (n, D, 7) ``blocks``, in order.

        For batches too large to hold: ``blocks`` may be a generator; each block is checked
        (a ValueError) before any chunk of it is sent, and ``state`` counts from the first
        block's first state. Chunks in flight are bounded, so memory is too.
        """
        def pieces():
            first = 0
            for block in blocks:
                block, extents = self._checked_states(block, half_extents)
                for piece in self._pieces(block, first):
                    yield piece
                first += len(block)
        extents = np.asarray(half_extents, np.float64)
        return self._stream(STATES, pieces(), extents, None)

    def stream_joints(self, blocks):
        """Yield (first state, count, contacts) per chunk of the (n, dof) ``blocks`` of q."""
        def pieces():
            first = 0
            for block in blocks:
                block = self._checked_joints(block)
                for piece in self._pieces(block, first):
                    yield piece
                first += len(block)
        return self._stream(JOINTS, pieces(), None, None)

    def _checked_states(self, states, half_extents):
        """Return states (K, D, 7) and half extents as World reads them; ValueError as World."""
        states = np.require(states, np.float64, ['C', 'A', 'W'])
        extents = np.asarray(half_extents, np.float64)
        if states.ndim != 3 or states.shape[2] != 7:
            raise ValueError('states must have shape (K, D, 7): K states of D poses '
                             'x y z qx qy qz qw, got %s' % (states.shape,))
        count, bodies = states.shape[:2]
        self._world.check_states(states[:0], extents)  # the sizes and the filters' body count
        for first in range(0, count, self._chunk):
            block = states[first:first + self._chunk]
            rows = extents if extents.shape == (3,) else np.tile(extents, (len(block), 1))
            try:
                check_boxes(block.reshape(-1, 7), rows)
            except InvalidBox as error:
                raise ValueError('state %d: dynamic body %d: %s' % (
                    first + error.body // bodies, error.body % bodies, error.reason)) from None
        return states, extents

    def _checked_joints(self, q):
        if self._robot is None:
            raise ValueError('no robot: the World given to the ClusterChecker has none '
                             '(World.set_robot)')
        return self._robot.checked_states(q)

    def _pieces(self, states, offset=0):
        """Return (first state, chunk) of consecutive chunks of ``states``, state from offset."""
        return ((offset + first, states[first:first + self._chunk])
                for first in range(0, len(states), self._chunk))

    def _batch(self, stream, total, start):
        parts = [contacts for _, _, contacts in stream]
        contacts = rows_concatenated(parts) if parts else np.zeros(0, STATE_CONTACT_DTYPE)
        contacts.flags.writeable = False
        return Result(contacts, {'states': total, 'chunks': len(parts), 'reruns': self.reruns,
                                 'restarts': self.restarts, 'workers': len(self.workers),
                                 'version': self._version,
                                 'total_ms': 1e3 * (time.perf_counter() - start)})

    def _stream(self, kind, pieces, extents, total):
        """Yield (first, count, contacts) of each piece, in order, answered by the workers.

        At most ``in_flight`` chunks per live worker are queued or waiting for their turn to
        be yielded; a lost worker's chunks are queued again (module docstring, Faults).
        """
        if self._running:
            raise RuntimeError('a batch is being answered already')
        self._running = True
        try:
            version, description = self._version, self._description()
            pieces = iter(pieces)
            waiting = collections.deque()  # (index, first, chunk) to send, lowest index first
            pending = {}  # ObjectRef -> (index, first, chunk, slot, worker)
            done = {}     # index -> (first, count, contacts) until it is its turn
            sent = turn = answered = 0
            more = True
            while True:
                live = [slot for slot, worker in enumerate(self._slots) if worker is not None]
                while len(pending) + len(done) < self._in_flight * len(live):
                    if not waiting:
                        piece = next(pieces, None) if more else None
                        if piece is None:
                            more = False
                            break
                        waiting.append((sent,) + piece)
                        sent += 1
                    index, first, chunk = waiting.popleft()
                    slot = min(live, key=lambda s: sum(p[3] == s for p in pending.values()))
                    worker = self._slots[slot]
                    ref = worker.check.remote(version, kind, first, chunk, extents)
                    pending[ref] = (index, first, chunk, slot, worker)
                if not pending:
                    if not live and (waiting or (more and next(pieces, None) is not None)):
                        raise ClusterError(answered, total,
                                           'every worker is lost and no restart is left')
                    break
                ready, _ = ray.wait(list(pending), num_returns=1)
                for ref in ready:
                    index, first, chunk, slot, worker = pending.pop(ref)
                    try:
                        at, contacts = ray.get(ref)
                    except _LOST:
                        self._lost(slot, worker)
                        waiting.appendleft((index, first, chunk))
                        self.reruns += 1
                        continue
                    if contacts is None:  # the worker is at another version: load, rerun
                        worker.load.remote(description, version)
                        waiting.appendleft((index, first, chunk))
                        self.reruns += 1
                        continue
                    done[index] = (first, len(chunk), contacts)
                    answered += len(chunk)
                if len(waiting) > 1:  # lost chunks go first, in their order
                    waiting = collections.deque(sorted(waiting, key=lambda item: item[0]))
                while turn in done:
                    yield done.pop(turn)
                    turn += 1
        finally:
            self._running = False
