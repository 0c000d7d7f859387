"""Child processes of the tools (the node, the pose publisher): stopping them cleanly."""
import signal
import subprocess


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
