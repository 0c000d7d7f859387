"""A ROS program's life: init, start its node, spin, and end with status 0 on SIGINT or SIGTERM.

rclpy's signal handler runs in C on SIGINT and SIGTERM, at any moment: it shuts the context
down and wakes the executor. Whatever the program does next with that context raises
``RCLError``: the wait set of a ``spin_once`` that began just after a ``context.ok()`` check,
or a publish from a callback that was running when the signal came. No check before a call can
close that window, so this module handles the outcome instead:

- An error raised once the context is shut down is the shutdown's, not a fault: the program
  ends quietly. An error while the context is valid is a real one and goes on up.
- The process's signal latch (collision_node.ros.signal_latch) is installed before
  ``rclpy.init``, which chains its handler to it: a signal while the node is being made (on a
  cold numba cache, minutes of compiling) ends the start at once; later it raises nothing.
"""
import contextlib
import threading
import time

import rclpy
from rclpy.callback_groups import MutuallyExclusiveCallbackGroup
from rclpy.executors import ExternalShutdownException, SingleThreadedExecutor
from rclpy.task import Future

from collision_node.ros.signal_latch import LATCH, Stopped


class InitError(RuntimeError):
    """rclpy.init refused the program's arguments (e.g. a params file rcl cannot parse)."""


class RosProgram:
    """One ROS program in ``main``: ``with RosProgram(args) as program:``.

    ``program.start(make_node)`` inits rclpy with ``args`` and makes the node (a signal
    meanwhile ends the start); ``program.spin_until(future)`` runs it. Leaving the block
    destroys the node and shuts rclpy down; it swallows :class:`Stopped` and every error raised
    after a shutdown signal, so the program exits with status 0 whenever SIGINT or SIGTERM
    came.
    """

    def __init__(self, args=None):
        self.args = args
        self.node = None
        self._initialised = False

    def __enter__(self):
        LATCH.install()
        return self

    def start(self, make_node):
        """Init rclpy, return ``make_node()``; a shutdown signal meanwhile raises Stopped."""
        LATCH.start()
        try:
            try:
                rclpy.init(args=self.args)
            except RuntimeError as error:
                raise InitError(str(error)) from None
            self._initialised = True
            self.node = make_node()
        finally:
            LATCH.started()
        return self.node

    def spin_until(self, future, timeout_sec=None):
        """Spin the node until ``future`` is done, ``timeout_sec`` passed or rclpy shut down.

        A node with ``priority_inputs`` (:class:`PriorityInputs`) has those answered on a
        thread and executor of their own meanwhile.
        """
        spin_node_until(self.node, future, timeout_sec)

    @property
    def shut_down(self):
        """Tell whether a shutdown signal came or the context was shut down."""
        return LATCH.received is not None or (self._initialised and not rclpy.ok())

    def __exit__(self, kind, error, traceback):
        # Judged before this shutdown: an error while the context was valid is a real one.
        quiet = kind is Stopped or (kind is not None and issubclass(kind, Exception)
                                    and self.shut_down)
        try:
            if self.node is not None:
                self.node.destroy_node()
        except Exception:  # noqa: B902 - a destroy on a shut-down context may complain
            if not self.shut_down:
                raise
        finally:
            rclpy.try_shutdown()
        return quiet


def spin_node_until(node, future, timeout_sec=None):
    """Spin ``node`` on this thread as :func:`spin_until`; its ``priority_inputs`` on theirs."""
    priority = getattr(node, 'priority_inputs', None)
    if priority is None:
        spin_until(SingleThreadedExecutor(context=node.context), node, future, timeout_sec)
        return
    executor = _PartExecutor(node, priority.left_out)
    ended = Future()  # the future, or the priority thread's error
    future.add_done_callback(lambda _: ended.done() or ended.set_result(None))
    with priority.spinning(ended, executor.wake):
        spin_until(executor, node, ended, timeout_sec)
    if ended.done() and ended.result() is not None:  # as a callback's error on this thread
        raise ended.result()


class PriorityInputs:
    """A node's inputs answered on an executor and a thread of their own (RosProgram.spin_until).

    rclpy's executor walks every entity it waits on at each wake-up: ~3 µs each when warm
    (collision_node.benchmarks.executor_cost), more from the cold caches an input meets at
    200 Hz. A lifecycle node with parameters waits on ~20 (its lifecycle and parameter
    services, its inputs, timers and guards), a plain node on ~10. The inputs whose answer
    someone waits for go on an executor that waits on them alone, in their own callback group
    (:attr:`group`), so the other executor never holds them back; the rest (services,
    timers, the other inputs) stay on the main thread's executor. Their callbacks then run
    on two threads: the node serialises them as its own (collision_node.ros.node's gate).
    """

    def __init__(self, node):
        self.group = MutuallyExclusiveCallbackGroup()
        self._node = node
        # Wakes the thread's executor when the inputs change, so that it waits on the new ones.
        self._changed = node.create_guard_condition(_nothing, self.group)
        self._entities = {self._changed}

    def add(self, entity):
        """Answer ``entity`` (made in :attr:`group`) on the thread from now on."""
        self._entities.add(entity)
        self._changed.trigger()

    def discard(self, entity):
        """Forget ``entity`` (destroyed, or about to be)."""
        self._entities.discard(entity)
        self._changed.trigger()

    def left_out(self, entity):
        """Tell whether ``entity`` is not one of these inputs: the main executor's part."""
        return entity not in self._entities

    @contextlib.contextmanager
    def spinning(self, failed, wake):
        """Answer the inputs on a thread of their own while in the block.

        An error of their callbacks ends the thread: ``failed`` (a Future) then holds it, and
        ``wake()`` wakes the main thread's executor to see it.
        """
        executor = _PartExecutor(self._node, self._entities.__contains__)
        stop = threading.Event()

        def spin():
            try:
                while not stop.is_set() and executor.context.ok():
                    with ending_on_shutdown(executor.context):
                        executor.spin_once()
            except Exception as error:  # noqa: B902 - whatever it is, the main thread raises it
                if not failed.done():
                    failed.set_result(error)
                wake()

        thread = threading.Thread(target=spin, name='priority_inputs', daemon=True)
        thread.start()
        try:
            yield
        finally:
            stop.set()
            executor.wake()
            thread.join()
            executor.shutdown()


class _PartExecutor(SingleThreadedExecutor):
    """Runs the callbacks of the entities of ``node`` that ``takes(entity)`` picks."""

    def __init__(self, node, takes):
        # rclpy's __del__ reads it: set before an __init__ that a shutdown may interrupt
        # (SIGINT at any moment) leaves the executor half made.
        self._sigint_gc = None
        super().__init__(context=node.context)
        self._node = node
        self._takes = takes

    def get_nodes(self):
        return [self._node]

    def can_execute(self, entity):
        return self._takes(entity) and super().can_execute(entity)


def _nothing():
    """Do nothing: a guard condition's trigger only wakes the executor."""


def spin_until(executor, node, future, timeout_sec=None):
    """Run ``node``'s callbacks on ``executor`` until ``future`` is done or rclpy shuts down.

    Not rclpy.spin_until_future_complete: rclpy 7 adds a callback to the future on every
    wake-up of the executor, so a node running for days would keep one for each message it
    ever took. An error of a call that met a shut-down context ends the spin quietly (see the
    module's docstring); any other goes on up.
    """
    deadline = None if timeout_sec is None else time.monotonic() + timeout_sec
    executor.add_node(node)
    try:
        while not future.done() and executor.context.ok():
            remaining = None if deadline is None else deadline - time.monotonic()
            if remaining is not None and remaining <= 0.0:
                break
            with ending_on_shutdown(executor.context):
                executor.spin_once(timeout_sec=remaining)
    finally:
        with ending_on_shutdown(executor.context):
            executor.remove_node(node)


@contextlib.contextmanager
def ending_on_shutdown(context):
    """Swallow an error raised because ``context`` was shut down meanwhile."""
    try:
        yield
    except ExternalShutdownException:
        pass
    except Exception:  # noqa: B902 - RCLError, InvalidHandle, RuntimeError: rclpy's choice
        if context.ok():
            raise
