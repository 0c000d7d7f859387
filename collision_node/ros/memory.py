"""Keep freed heap memory in the process, so that large messages cost no page faults.

glibc returns large freed blocks to the kernel (blocks over the mmap threshold are unmapped,
and the heap's top is trimmed), so the next block of that size is fresh memory, and every page
of it faults on first touch, every tick, for the node's input, its output and Fast DDS's
buffers. With this module's setting in both processes they reuse the same pages tick after
tick (what that saves is measured in doc/benchmarks.md). It is the ROS 2 real-time
guidelines' advice (no trimming, no mmap for working-size blocks), applied with mallopt.

A process-wide setting, so it belongs to the process's owner: the node's ``main`` and the
benchmarks call it; a process that hosts the node among others may call it too. Not glibc
(musl, macOS): nothing to do, and :func:`keep_heap_memory` says so by returning False.
"""
import ctypes

# mallopt parameters (malloc.h).
M_TRIM_THRESHOLD = -1
M_MMAP_THRESHOLD = -3
# Blocks up to 32 MB (glibc's largest mmap threshold; a 100,000-body PoseArray is 5.6 MB) come
# from the heap; up to 256 MB of freed heap is kept before the top is trimmed.
MMAP_THRESHOLD_BYTES = 32 * 1024 * 1024
TRIM_THRESHOLD_BYTES = 256 * 1024 * 1024


def keep_heap_memory():
    """Make glibc keep freed memory for reuse; return False where that is not possible."""
    try:
        mallopt = ctypes.CDLL(None).mallopt
    except (OSError, AttributeError):  # not glibc
        return False
    mallopt.argtypes = (ctypes.c_int, ctypes.c_int)
    mallopt.restype = ctypes.c_int
    return bool(mallopt(M_MMAP_THRESHOLD, MMAP_THRESHOLD_BYTES)
                and mallopt(M_TRIM_THRESHOLD, TRIM_THRESHOLD_BYTES))
