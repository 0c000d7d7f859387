"""The console scripts: each quiets SIGINT and SIGTERM before it imports its program.

A program's imports take seconds (numpy, numba, rclpy, the kernels' cache index). A signal in
that time would end it with a KeyboardInterrupt traceback or be killed by SIGTERM; here it
ends it with status 0, as a signal does at any later moment (collision_node.ros.lifetime).
A program started as a child process goes through here too::

    python -m collision_node.tools.programs collision_node --ros-args --params-file default.yaml
"""
import importlib
import sys

from collision_node.ros.signal_latch import LATCH, Stopped


def _run(module):
    """Import ``module`` with the latch installed, then return its ``main()``."""
    LATCH.install()
    try:
        LATCH.start()
        main = importlib.import_module(module).main
        LATCH.started()
    except Stopped:
        return 0
    return main()


def collision_node():
    """Run the collision node (``ros2 run collision_node collision_node``)."""
    return _run('collision_node.ros.node')


def pose_publisher():
    """Run the pose publisher."""
    return _run('collision_node.tools.pose_publisher')


def collision_monitor():
    """Run the collision monitor."""
    return _run('collision_node.tools.collision_monitor')


def collision_demo():
    """Run the demo: the node, a pose publisher and the diagnostics printed."""
    return _run('collision_node.tools.demo')


PROGRAMS = {'collision_node': collision_node, 'pose_publisher': pose_publisher,
            'collision_monitor': collision_monitor, 'collision_demo': collision_demo}


def child_command(program, *arguments):
    """Return the command line that runs ``program`` (a console script's name) with this Python."""
    return [sys.executable, '-m', 'collision_node.tools.programs', program, *arguments]


if __name__ == '__main__':
    sys.exit(PROGRAMS[sys.argv.pop(1)]())
