"""A growable output buffer for the pair-finding kernels.

Kernels never allocate: they write pairs into a preallocated (capacity, 2) array, keep
counting past its end and return the full count. When the count did not fit, the buffer grows
and the kernel runs again, so the cost of growing is paid once per new maximum, not per tick.
"""
import numpy as np

INITIAL_CAPACITY = 4096
GROWTH = 1.5


class PairBuffer:

    def __init__(self, capacity=INITIAL_CAPACITY):
        self.pairs = np.empty((capacity, 2), np.int64)

    def fill(self, find_pairs_kernel, *args):
        """Run ``find_pairs_kernel(*args, pairs) -> (count, compared)`` until it fits."""
        while True:
            count, compared = find_pairs_kernel(*args, self.pairs)
            if count <= len(self.pairs):
                return self.pairs[:count], compared
            self.pairs = np.empty((int(count * GROWTH) + 1, 2), np.int64)


