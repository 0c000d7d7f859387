"""The one place where numba JIT flags are set.

Every kernel in the package is decorated with :func:`kernel` (or :func:`inlined_kernel`, the
same flags, for a small helper numba inlines into its callers), so the flags cannot drift
between modules. ``fastmath`` stays off everywhere: it lets LLVM assume no NaN/Inf, which
turns ``np.isnan`` into ``False`` and reassociates the SAT's sums (doc/accuracy.md).

Constant arguments. numba types a constant passed to a kernel (``0``, ``False``) as a literal,
which compiles that kernel (and what it inlines) once more for that constant alone. A call
that passes a constant where other calls pass variables passes ``np.int64(0)`` or
``np.bool_(False)`` instead: values of the variables' types.

Typed calls. A dispatcher types every argument at every call before it runs the compiled
code (~0.15 µs an array warm; for the PoseArray lane's 17 arrays, 2.5 µs warm and ~30 µs
after 5 ms of idle time on the AMD EPYC VM). A caller that makes one call many times with
arguments of the same types takes :func:`compiled_for` once and calls that instead.

Cache. numba caches next to the sources when that directory is writable, else in the user's
cache directory (~/.cache/numba), and NUMBA_CACHE_DIR overrides both. When none of them is
writable (a read-only install run by a user without a writable home, e.g. a service), numba
refuses to decorate a ``cache=True`` function at all; the kernels then cache in
FALLBACK_CACHE_DIR, so the node still starts and a restart still loads instead of compiling.

Several processes may fill one cache at once (collision_node.tools.compile_kernels compiles in
parallel; a node may start meanwhile). numba writes each file whole (a temporary file, then a
rename), so a reader never sees half a file; but it adds an entry to a kernel's index by
reading the index, picking a free data file name and writing both back, and two processes
adding different types of one kernel at once could both pick the same data file and leave an
index that names the other's code. :func:`_locked` makes that read-modify-write one step: a
process holds CACHE_LOCK (an flock beside the index) from reading the index to writing it.
"""
import fcntl
import functools
import os
import tempfile

import numba
from numba.core.caching import IndexDataCacheFile

JIT_OPTIONS = {
    'cache': True,            # ~0.2 s to load a warm cache instead of ~6 s to compile
    'nogil': True,            # kernels release the GIL so rclpy's executor stays responsive
    'error_model': 'numpy',   # a division by zero gives inf/nan instead of raising in a kernel
    'fastmath': False,
    'boundscheck': False,
}
# One directory per user: another user's cache directory would not be writable.
FALLBACK_CACHE_DIR = os.path.join(tempfile.gettempdir(),
                                  'collision_node-numba-cache-%d' % os.getuid())
CACHE_LOCK = 'collision_node.lock'  # in each cache directory: see _locked
# Every kernel decorated so far (numba dispatchers), for the compile progress to count
# (collision_node.pipeline.jit_progress).
KERNELS = set()


def kernel(function):
    """Compile ``function`` with the package's JIT options."""
    dispatcher = _njit(function, JIT_OPTIONS)
    KERNELS.add(dispatcher)
    return dispatcher


def inlined_kernel(function):
    """Compile ``function`` with the package's JIT options, inlined into each caller.

    For a small helper handed arrays in a hot loop: a call numba does not inline
    reference-counts every array it is handed (a RobotModel is 15), which can cost more than
    the helper's work. numba inlines it into its callers' code instead (inline='always').
    """
    dispatcher = _njit(function, dict(JIT_OPTIONS, inline='always'))
    KERNELS.add(dispatcher)
    return dispatcher


def compiled_for(dispatcher, arguments):
    """Return the compiled function ``dispatcher`` runs for ``arguments``; compile it if need be.

    It skips the dispatcher's typing of each argument, and so its check: every later call
    must pass arguments of these types (dtype, dimensions, layout), or it reads them wrong.
    """
    signature = tuple(dispatcher.typeof_pyval(argument) for argument in arguments)
    if signature not in dispatcher.overloads:
        dispatcher.compile(signature)
    return dispatcher.get_overload(signature)


def _njit(function, options):
    try:
        return numba.njit(**options)(function)
    except RuntimeError as error:
        if 'no locator available' not in str(error):
            raise
    # numba picks a function's cache directory when it decorates it: the fallback is set for
    # this decoration only, so other numba users in the process keep their own choice.
    previous, numba.config.CACHE_DIR = numba.config.CACHE_DIR, FALLBACK_CACHE_DIR
    try:
        return numba.njit(**options)(function)
    finally:
        numba.config.CACHE_DIR = previous


def _locked(save):
    """Wrap numba's IndexDataCacheFile.save so that one process at a time adds to an index."""
    @functools.wraps(save)
    def locked_save(self, key, data):
        with open(os.path.join(self._cache_path, CACHE_LOCK), 'a') as lock:
            fcntl.flock(lock, fcntl.LOCK_EX)  # released as the file closes
            save(self, key, data)
    return locked_save


IndexDataCacheFile.save = _locked(IndexDataCacheFile.save)
