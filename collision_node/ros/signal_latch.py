"""SIGINT and SIGTERM turned into a quiet stop, with the standard library only.

It must be importable before numpy, numba and rclpy, whose imports take seconds.

While a program is ``starting`` (importing, loading or compiling kernels, making its node and
its autostart transitions) a signal ends the process at once with status 0. An exception raised
there would land inside numba's or rclpy's half-made objects (seen: llvmlite's destructor then
prints a traceback), and nothing the program made is in use yet; numba writes each cache file
whole (a temporary file, renamed), so an exit mid-compile leaves no broken cache. After the
start the latch only records the first signal: an exception landing in a callback, a
lifecycle transition or ``destroy_node`` would leave a traceback. rclpy's own handler, which
rclpy.init installs over this one and which calls it after its own work, shuts the context
down: that ends a running program's spin (collision_node.ros.lifetime). A second signal ends
the process at once, with status 0 too: whoever sends it (a second Ctrl-C, a launcher's
SIGTERM after its SIGINT) will not wait for a shutdown that hangs.
"""
import os
import signal
import sys

SHUTDOWN_SIGNALS = (signal.SIGINT, signal.SIGTERM)


class Stopped(BaseException):
    """A shutdown signal came before the program's start began."""


class SignalLatch:
    """The process's record of SIGINT and SIGTERM; :data:`LATCH` is the one instance."""

    def __init__(self):
        self.received = None  # the first shutdown signal's number, once one came
        self.starting = False

    def install(self):
        """Handle SIGINT and SIGTERM with this latch from now until the process ends.

        Never uninstalled: a signal in the last moments of a program, after rclpy shut down,
        must be as quiet as one in its middle.
        """
        for signum in SHUTDOWN_SIGNALS:
            if signal.getsignal(signum) is not self:
                signal.signal(signum, self)

    def start(self):
        """Enter the start: a signal ends the process; one received before raises Stopped."""
        self.starting = True
        if self.received is not None:
            self.starting = False
            raise Stopped()

    def started(self):
        """Leave the start: signals are only recorded again."""
        self.starting = False

    def __call__(self, signum, frame):
        """Record ``signum``; end the process with status 0 if starting or signalled before."""
        if self.starting or self.received is not None:
            for stream in (sys.stdout, sys.stderr):
                try:
                    stream.flush()
                except (OSError, RuntimeError, ValueError):  # e.g. a reentrant write
                    pass
            os._exit(0)
        self.received = signum


LATCH = SignalLatch()
