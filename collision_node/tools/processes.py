"""The tools' processes: a tool's node run until it is done, child processes stopped cleanly."""
import signal
import subprocess

import rclpy
from rclpy.executors import ExternalShutdownException


def spin_until_finished(args, make_node):
    """Init rclpy with ``args``, spin ``make_node()`` until its ``finished`` future is done.

    Returns the future's result, or None when Ctrl-C or an external shutdown ended the spin
    first (quietly). The node is destroyed and rclpy shut down either way.
    """
    rclpy.init(args=args)
    node = make_node()
    try:
        rclpy.spin_until_future_complete(node, node.finished)
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    finally:
        node.destroy_node()
        rclpy.try_shutdown()
    return node.finished.result() if node.finished.done() else None


def stop_process(process, timeout_s, on_timeout=lambda signal_name: None):
    """Stop ``process`` with SIGINT, then SIGTERM, then SIGKILL; return its exit code.

    Each signal gets ``timeout_s`` seconds; ``on_timeout(signal name)`` hears of each that
    did not stop it. SIGINT first lets a ROS node shut down as on Ctrl-C.
    """
    for stop in (signal.SIGINT, signal.SIGTERM, signal.SIGKILL):
        if process.poll() is not None:
            break
        process.send_signal(stop)
        try:
            process.wait(timeout_s)
        except subprocess.TimeoutExpired:
            on_timeout(signal.Signals(stop).name)
    return process.wait()
