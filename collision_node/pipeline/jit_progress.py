"""Progress lines while numba compiles the package's kernels, for whoever waits on a start.

numba compiles a kernel on its first call, or loads it from its cache. Compiling what a node
configured as config/arm.yaml runs takes about 35 s of CPU on the 2-vCPU Intel Xeon of the
README (with the node's warm-up printing nothing, a first start looked hung); loading it takes
a fraction of a second. numba announces
only compiling (its ``numba:compile`` event; a load from the cache is silent), so a start
that finds every kernel in the cache reports nothing at all::

    with compile_progress(print):
        warm_up()

Kernels are counted as they finish, with the kernels a kernel calls (compiled with it) counted
too; the estimate of the time left assumes the kernels still to come take as long, on
average, as those done (over the node's warm-up it was within a third of the time measured).
"""
from contextlib import contextmanager
import math
import time

from numba.core import event

from collision_node.pipeline._jit import KERNELS

REPORT_PERIOD_S = 5.0  # a line at the first compile, then at most one this often, then a total


class CompileProgress(event.Listener):
    """Counts the package's kernels numba compiles and reports on them through ``report``."""

    def __init__(self, report, period_s=REPORT_PERIOD_S, clock=time.monotonic):
        """Report lines by calling ``report(line)``; ``clock()`` gives seconds."""
        self._report = report
        self._period_s = period_s
        self._clock = clock
        # A kernel compiled before in this process is not counted, even if it compiles another
        # type now (the time it takes still counts); lazily imported modules add kernels to
        # KERNELS while the warm-up runs, so the count to do is taken each time.
        self._ready_before = {dispatcher for dispatcher in KERNELS if dispatcher.overloads}
        self._compiled = set()  # kernels compiled since; a kernel may compile several types
        self._started_s = None
        self._reported_s = -math.inf

    def on_start(self, compile_event):
        """Report the first compile at once, then which kernel compiles, once a period."""
        dispatcher = compile_event.data['dispatcher']
        if dispatcher not in KERNELS:  # numba's own helpers compile too
            return
        now = self._clock()
        if self._started_s is None:
            self._started_s = self._reported_s = now
            self._report('compiling the numba kernels missing from its cache (every kernel, '
                         'on a first start); they are cached for later starts')
        elif now - self._reported_s >= self._period_s:
            self._reported_s = now
            done = len(self._compiled)
            to_do = len(KERNELS) - len(self._ready_before)
            counted = dispatcher in self._compiled or dispatcher in self._ready_before
            line = 'compiling kernel %d of %d (%s), %.0f s so far' % (
                done + (not counted), to_do, _name(dispatcher), now - self._started_s)
            if done:
                left = to_do - done
                line += ', about %.0f s left' % ((now - self._started_s) * left / done)
            self._report(line)

    def on_end(self, compile_event):
        """Count a kernel once it compiled."""
        dispatcher = compile_event.data['dispatcher']
        if dispatcher in KERNELS and dispatcher not in self._ready_before:
            self._compiled.add(dispatcher)

    @property
    def compiled(self):
        """How many kernels compiled so far."""
        return len(self._compiled)

    def finish(self):
        """Report how many kernels compiled and how long it took, if any did."""
        if self._started_s is not None:
            self._report('compiled %d kernels in %.1f s' % (
                len(self._compiled), self._clock() - self._started_s))


@contextmanager
def compile_progress(report, period_s=REPORT_PERIOD_S):
    """Report, through ``report(line)``, on the package's kernels numba compiles in the block.

    Nothing is reported when nothing compiles (every kernel came from numba's cache).
    """
    progress = CompileProgress(report, period_s)
    with event.install_listener('numba:compile', progress):
        yield progress
    progress.finish()


def _name(dispatcher):
    """``sat._collide_pairs`` for collision_node.pipeline.sat._collide_pairs."""
    module = dispatcher.py_func.__module__
    for prefix in ('collision_node.pipeline.', 'collision_node.'):
        if module.startswith(prefix):
            module = module[len(prefix):]
            break
    return '%s.%s' % (module, dispatcher.py_func.__name__)
