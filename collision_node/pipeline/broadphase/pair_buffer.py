"""A growable output buffer for the pair-finding kernels.

Kernels never allocate: they write pairs into a preallocated (capacity, 2) array, keep
counting past its end and return the full count. When the count did not fit, the buffer grows
and the kernel runs again, so the cost of growing is paid once per new maximum, not per tick.
"""
import numpy as np

from collision_node.pipeline._jit import kernel

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


@kernel
def emit(out, count, a, b, n_static):
    """Store pair (dynamic ``a``, any ``b``) in interface order if it fits; return count + 1.

    Interface order: column 0 dynamic, column 1 static or the larger dynamic row.
    """
    if count < out.shape[0]:
        if b >= n_static and b < a:
            a, b = b, a
        out[count, 0] = a
        out[count, 1] = b
    return count + 1


@kernel
def emit_if(out, count, hit, a, b):
    """Store pair (a, b), already in interface order, when ``hit``; return the new count.

    Branch-free: the slot is written either way (the last one once full) and only a hit
    advances the count. In a grid cell a hit is a coin flip, and a mispredicted branch per
    pair cost more than the test itself (measured: 2x slower with ``if hit: emit(...)``).
    """
    slot = min(count, out.shape[0] - 1)
    out[slot, 0] = a
    out[slot, 1] = b
    return count + hit
