"""A kernel's loop over items spread over threads: the calling thread plus ``threads - 1``.

Kernels release the GIL (``nogil``), so plain Python threads run them on several cores at
once; no numba threading layer is involved (no ``prange``, so no layer that can abort when two
threads call in, and nothing to configure). The items are cut into chunks and every thread
takes the next chunk from one shared counter until none is left: a helper whose core is busy
elsewhere takes fewer chunks instead of holding the tick back by a fixed share, and with one
thread the loop runs in the caller as one chunk, with no cost at all.

Each chunk writes only its own rows of the output, so the result does not depend on which
thread ran which chunk, nor on the number of threads.
"""
from concurrent.futures import ThreadPoolExecutor, wait
import itertools

CHUNKS_PER_THREAD = 4  # more chunks: finer balance, but each costs a dispatch (~10 µs)


class Workers:
    """The calling thread and ``threads - 1`` pooled helpers."""

    def __init__(self, threads=1):
        if isinstance(threads, bool) or not isinstance(threads, int) or threads < 1:
            raise ValueError('threads must be a positive integer, got %r' % (threads,))
        self.threads = threads
        self._pool = ThreadPoolExecutor(threads - 1, 'collision_worker') if threads > 1 \
            else None

    @property
    def max_chunks(self):
        """Return the most ranges :meth:`map_ranges` cuts a loop into."""
        return CHUNKS_PER_THREAD * self.threads

    def map_ranges(self, task, count, min_chunk):
        """Call ``task(chunk, start, stop)`` on consecutive ranges covering ``range(count)``.

        ``chunk`` numbers the ranges from 0 (below :attr:`max_chunks`), e.g. to pick an output
        buffer. Ranges hold at least ``min_chunk`` items, so that small loops stay in one call
        (with one thread, always one call). Returns the results in the order of the ranges.
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

        helpers = [self._pool.submit(work) for _ in range(min(self.threads, chunks) - 1)]
        try:
            work()
        finally:  # never return while a helper still writes into the caller's arrays
            wait(helpers)
        for helper in helpers:
            helper.result()  # raises a helper's exception here
        return results

    def close(self):
        if self._pool is not None:
            self._pool.shutdown()
