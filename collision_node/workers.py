"""A kernel's loop spread over ``threads`` pooled helper threads, each on a CPU of its own.

Kernels release the GIL (``nogil``), so plain Python threads run them on several cores at
once; no numba threading layer is involved (no ``prange``, so no layer that can abort when two
threads call in, and nothing to configure). The items are cut into chunks and every helper
takes the next chunk from one shared counter until none is left: a helper whose core is busy
elsewhere takes fewer chunks instead of holding the tick back by a fixed share. With one
thread the loop runs in the caller as one chunk, with no cost at all.

With several threads the caller hands the loop to the helpers and waits, and helper i is pinned
to the i-th CPU the process may use (when it may use at least ``threads``). Measured on the
project's 2-core virtual machine at 10,000 bodies with 10 ms between ticks, as a node sees
input at 100 Hz: the World's tick on 2 threads took 4.1-4.3 ms this way against 5.4-5.5 ms
with an unpinned helper working beside the caller (1 thread: 5.1-5.2 ms), and back to back the
same 3.5-3.6 ms either way. Unpinned, the woken helper and the caller share one CPU after an
idle gap until the scheduler moves one of them; pinning only the helper does not help, since
the caller may then wake on the helper's CPU. The caller's own affinity is never changed.

Each chunk writes only its own rows of the output, so the result does not depend on which
thread ran which chunk, nor on the number of threads.
"""
from concurrent.futures import ThreadPoolExecutor, wait
import itertools
import os

CHUNKS_PER_THREAD = 4  # more chunks: finer balance, but each costs a dispatch (~10 µs)


class Workers:
    """The calling thread alone, or ``threads`` pooled helpers pinned one per CPU."""

    def __init__(self, threads=1):
        if isinstance(threads, bool) or not isinstance(threads, int) or threads < 1:
            raise ValueError('threads must be a positive integer, got %r' % (threads,))
        self.threads = threads
        self._pool = None
        if threads > 1:
            cpus = _allowed_cpus()
            next_helper = itertools.count()  # next() is atomic under the GIL
            self._pool = ThreadPoolExecutor(
                threads, 'collision_worker',
                initializer=None if len(cpus) < threads
                else lambda: _pin_to(cpus[next(next_helper)]))

    @property
    def max_chunks(self):
        """Return the most ranges :meth:`map_ranges` cuts a loop into."""
        return CHUNKS_PER_THREAD * self.threads

    def map_ranges(self, task, count, min_chunk):
        """Call ``task(chunk, start, stop)`` on consecutive ranges covering ``range(count)``.

        ``chunk`` numbers the ranges from 0 (below :attr:`max_chunks`), e.g. to pick an output
        buffer. Ranges hold at least ``min_chunk`` items, so that small loops stay in one call
        (with one thread, always one call, in the caller). Returns the results in the order of
        the ranges.
        """
        chunks = max(1, min(count // max(min_chunk, 1), self.max_chunks))
        if self._pool is None or chunks == 1:
            return [task(0, 0, count)]
        bounds = [count * k // chunks for k in range(chunks + 1)]
        results = [None] * chunks
        claims = itertools.count()  # next() is atomic under the GIL

        def work():
            for k in claims:
                if k >= chunks:
                    return
                results[k] = task(k, bounds[k], bounds[k + 1])

        helpers = [self._pool.submit(work) for _ in range(min(self.threads, chunks))]
        wait(helpers)  # never return while a helper still writes into the caller's arrays
        for helper in helpers:
            helper.result()  # raises a helper's exception here
        return results

    def close(self):
        if self._pool is not None:
            self._pool.shutdown()


def _allowed_cpus():
    """Return the CPUs this process may run on, sorted; empty where the OS does not say."""
    return sorted(os.sched_getaffinity(0)) if hasattr(os, 'sched_getaffinity') else []


def _pin_to(cpu):
    """Keep the calling thread on ``cpu`` (Linux: affinity is per thread)."""
    os.sched_setaffinity(0, {cpu})
