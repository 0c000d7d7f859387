"""The tools' processes: a tool's node run until it is done, child processes stopped cleanly."""
import signal
import subprocess

from collision_node.ros.lifetime import RosProgram


def spin_until_finished(args, make_node):
    """Init rclpy with ``args``, spin ``make_node()`` until its ``finished`` future is done.

    Returns the future's result, or None when SIGINT or SIGTERM ended the program first
    (quietly, status 0: collision_node.ros.lifetime). The node is destroyed and rclpy shut down
    either way.
    """
    with RosProgram(args) as program:
        node = program.start(make_node)
        program.spin_until(node.finished)
    finished = program.node.finished if program.node is not None else None
    return finished.result() if finished is not None and finished.done() else None


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
