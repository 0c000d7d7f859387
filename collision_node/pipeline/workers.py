"""A kernel's loop over items spread over threads: the calling thread plus ``threads - 1``.

Kernels release the GIL (``nogil``), so plain Python threads run them on several cores at
once; no numba threading layer is involved (no ``prange``, so no layer that can abort when two
threads call in, and nothing to configure). The items are cut into chunks and every thread
takes the next chunk from one shared counter until none is left: a helper whose core is busy
elsewhere takes fewer chunks instead of holding the tick back by a fixed share, and with one
thread the loop runs in the caller as one chunk, with no cost at all.

Each chunk writes only its own rows of the output, so the result does not depend on which
thread ran which chunk, nor on the number of threads.

Hand-over. Waking a sleeping thread costs ~25 µs on a virtual machine (the idle vCPU has to be
woken by the host), twice per loop (the helper, then the caller when the helper is done): a
thread pool's futures cost ~75 µs a loop, a tenth of a 10,000-body tick on two threads with
three such loops. So a job is published by an atomic counter that the helpers watch, and the
caller watches the job's own counter of finished chunks, each spinning (without the GIL) for
up to SPIN_CHECKS reads before it sleeps (the helpers on a Condition, the caller on the job's
Event): within a tick the stages follow each other closer than that, so no thread sleeps
there; between ticks the helpers spin that long once, then sleep. The counters are read with
acquire and written with release ordering, so what a chunk wrote is seen by the caller on any
CPU, x86 or ARM. Measured on the AMD EPYC machine: 10 µs for a loop of two empty chunks, and
40 µs over the chunks' own time for two chunks of 0.4 ms (most of it the helper's wait for the
GIL), against 57 and 75 µs with a thread pool.
"""
import itertools
import threading

from numba import types
from numba.core import cgutils
from numba.extending import intrinsic
import numpy as np

from collision_node.pipeline._jit import kernel

CHUNKS_PER_THREAD = 4  # more chunks: finer balance, but each costs a claim (~2 µs)
# Reads of a counter before a thread gives up spinning and sleeps: 0.5 ms on the AMD EPYC
# machine, longer than the serial stages between two loops of a 10,000-body tick (box writes
# and table build before the pair search: ~0.5 ms), far shorter than the time between ticks.
SPIN_CHECKS = 2_000_000


class Workers:
    """The calling thread and ``threads - 1`` helper threads."""

    def __init__(self, threads=1):
        if isinstance(threads, bool) or not isinstance(threads, int) or threads < 1:
            raise ValueError('threads must be a positive integer, got %r' % (threads,))
        self.threads = threads
        self._epoch = np.zeros(1, np.int64)  # the number of the job published last
        self._job = None
        # Helpers that stopped spinning wait here; every job is published under its lock.
        self._sleep = threading.Condition()
        self._closing = False
        self._helpers = [threading.Thread(target=self._serve, name='collision_worker',
                                          daemon=True) for _ in range(threads - 1)]
        for helper in self._helpers:
            helper.start()

    @property
    def max_chunks(self):
        """Return the most ranges :meth:`map_ranges` cuts a loop into."""
        return CHUNKS_PER_THREAD * self.threads

    def map_ranges(self, task, count, min_chunk):
        """Call ``task(chunk, start, stop)`` on consecutive ranges covering ``range(count)``.

        ``chunk`` numbers the ranges from 0 (below :attr:`max_chunks`), e.g. to pick an output
        buffer. Ranges hold at least ``min_chunk`` items, so that small loops stay in one call
        (with one thread, always one call). Returns the results in the order of the ranges;
        an exception of a chunk is raised once every chunk is done.
        """
        chunks = max(1, min(count // max(min_chunk, 1), self.max_chunks))
        if not self._helpers or chunks == 1:
            return [task(0, 0, count)]
        bounds = [count * k // chunks for k in range(chunks + 1)]
        job = _Job(task, bounds, chunks)
        self._job = job
        self._publish_job()
        self._run(job)
        if not _spin_until(job.finished, 0, chunks, SPIN_CHECKS):
            job.done.wait()
        if job.errors:
            raise min(job.errors, key=lambda error: error[0])[1]
        return job.results

    def close(self):
        """Stop the helper threads."""
        self._closing = True
        self._publish_job()
        for helper in self._helpers:
            helper.join()
        self._helpers = []

    def _publish_job(self):
        """Count one more job, for spinning helpers and for sleeping ones."""
        with self._sleep:
            _publish(self._epoch, 0, self._epoch[0] + 1)
            self._sleep.notify_all()

    def _run(self, job):
        """Take chunks of ``job`` until none is left."""
        for k in job.claims:  # next() is atomic under the GIL
            if k >= job.chunks:
                return
            try:
                job.results[k] = job.task(k, job.bounds[k], job.bounds[k + 1])
            except BaseException as error:  # raised by the caller, once all chunks are done
                job.errors.append((k, error))
            finally:
                if _add_release(job.finished, 0, 1) == job.chunks:
                    job.done.set()

    def _serve(self):
        """Run each published job's chunks, as a helper; spin, then sleep, between jobs."""
        seen = 0
        while True:
            if not _spin_until(self._epoch, 0, seen + 1, SPIN_CHECKS):
                # Looked at under the lock the job is published under: none is missed.
                with self._sleep:
                    while _read(self._epoch, 0) < seen + 1:
                        self._sleep.wait()
                continue
            seen = _read(self._epoch, 0)
            if self._closing:
                return
            self._run(self._job)


class _Job:
    """One map_ranges call: its chunks, their claims, what they gave, how many are finished.

    All of it belongs to the one call, so a helper still leaving the last job (it may take
    its last look at the claims, or signal ``done``, after the caller went on) cannot touch
    the next one.
    """

    def __init__(self, task, bounds, chunks):
        self.task = task
        self.bounds = bounds
        self.chunks = chunks
        self.claims = itertools.count()
        self.results = [None] * chunks
        self.errors = []
        self.finished = np.zeros(1, np.int64)  # chunks finished, by any thread (atomic adds)
        self.done = threading.Event()  # set with the last chunk: for a caller done spinning


def _element_pointer(context, builder, array_type, array, index):
    return cgutils.get_item_pointer(context, builder, array_type,
                                    context.make_array(array_type)(context, builder, array),
                                    [index])


@intrinsic
def _load_acquire(typing_context, counters, index):
    """Return ``counters[index]`` (int64), read with acquire ordering."""
    def codegen(context, builder, signature, args):
        pointer = _element_pointer(context, builder, signature.args[0], args[0], args[1])
        return builder.load_atomic(pointer, 'acquire', 8)
    return types.int64(counters, index), codegen


@intrinsic
def _store_release(typing_context, counters, index, value):
    """Write ``counters[index] = value`` (int64) with release ordering."""
    def codegen(context, builder, signature, args):
        pointer = _element_pointer(context, builder, signature.args[0], args[0], args[1])
        builder.store_atomic(args[2], pointer, 'release', 8)
        return context.get_dummy_value()
    return types.void(counters, index, value), codegen


@intrinsic
def _fetch_add(typing_context, counters, index, value):
    """Add ``value`` to ``counters[index]`` atomically (acquire and release); return the old."""
    def codegen(context, builder, signature, args):
        pointer = _element_pointer(context, builder, signature.args[0], args[0], args[1])
        return builder.atomic_rmw('add', pointer, args[2], 'acq_rel')
    return types.int64(counters, index, value), codegen


@kernel
def _read(counters, index):
    """Return ``counters[index]``, read with acquire ordering."""
    return _load_acquire(counters, index)


@kernel
def _publish(counters, index, value):
    """Write ``counters[index] = value`` with release ordering."""
    _store_release(counters, index, value)


@kernel
def _add_release(counters, index, value):
    """Add ``value`` to ``counters[index]`` atomically; return the new value."""
    return _fetch_add(counters, index, value) + value


@kernel
def _spin_until(counters, index, target, checks):
    """Whether ``counters[index]`` reached ``target`` within ``checks`` reads (no GIL held)."""
    for _ in range(checks):
        if _load_acquire(counters, index) >= target:
            return True
    return False
