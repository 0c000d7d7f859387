"""Run the demo: collision_node on config/default.yaml, fed by pose_publisher's moving room.

    collision_demo                  # until Ctrl-C
    collision_demo --duration 10    # stop after 10 seconds

Starts the node and the pose publisher as child processes (same Python, same ROS_DOMAIN_ID),
then prints the node's diagnostics as one line a second: ticks per second, bodies, colliding
pairs, tick time median and p99, and the broad phase in use. On Ctrl-C (or after --duration)
the children are stopped with SIGINT, then SIGTERM and SIGKILL if they hang.
"""
import argparse
import os
import subprocess
import sys

from ament_index_python.packages import get_package_share_directory, PackageNotFoundError
from diagnostic_msgs.msg import DiagnosticArray
from rclpy.node import Node
from rclpy.qos import HistoryPolicy, QoSProfile, ReliabilityPolicy
from rclpy.task import Future
from rclpy.utilities import remove_ros_args

from collision_node.pipeline.scenes import scene_body_count, SCENE_BODY_COUNTS
from collision_node.ros.diagnostics import LEVEL_NAMES, STATUS_SUFFIX
from collision_node.ros.lifetime import RosProgram
from collision_node.tools.processes import stop_process
from collision_node.tools.programs import child_command

PACKAGE = 'collision_node'
CONFIGS = {'room': os.path.join('config', 'default.yaml'),  # scene: its node parameters
           'arm': os.path.join('config', 'arm.yaml')}
CHILD_CHECK_PERIOD_S = 0.5
STOP_TIMEOUT_S = 5.0  # per signal: SIGINT, then SIGTERM, then SIGKILL


def default_config(scene='room'):
    """Find a scene's config file: installed (ament index, this Python's prefix) or in source."""
    config = CONFIGS[scene]
    candidates = []
    try:
        candidates.append(os.path.join(get_package_share_directory(PACKAGE), config))
    except (PackageNotFoundError, OSError):  # no ament prefix (OSError: none set), e.g. a venv
        pass
    candidates.append(os.path.join(sys.prefix, 'share', PACKAGE, config))
    source_root = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
    candidates.append(os.path.join(source_root, config))
    for path in candidates:
        if os.path.isfile(path):
            return path
    raise FileNotFoundError('cannot find %s in any of: %s' % (config, ', '.join(candidates)))


def summary(status):
    """Format the node's DiagnosticStatus as one line."""
    values = {item.key: item.value for item in status.values}
    line = ('%6s ticks/s | %s bodies | %s collisions | %s near | tick ms median %s p99 %s '
            '| broad phase %s') % (
        '%.1f' % float(values.get('rate_hz', 'nan')),
        _count(values, 'dynamic_bodies') + _count(values, 'static_bodies'),
        values.get('colliding_pairs', '?'), values.get('near_pairs', '?'),
        values.get('total_ms_median', '?'),
        values.get('total_ms_p99', '?'), values.get('broad_phase') or '-')
    level = int.from_bytes(status.level, 'little')
    if level != 0:
        line += ' | %s: %s' % (LEVEL_NAMES.get(level, level), status.message)
    return line


def _count(values, key):
    try:
        return int(values.get(key, 0))
    except ValueError:
        return 0


class Demo(Node):
    """Prints the node's diagnostics and watches the child processes."""

    def __init__(self, children):
        super().__init__('collision_demo')
        self.children = children
        self.finished = Future()
        qos = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=10,
                         reliability=ReliabilityPolicy.RELIABLE)
        self.create_subscription(DiagnosticArray, '/diagnostics', self.on_diagnostics, qos)
        self.create_timer(CHILD_CHECK_PERIOD_S, self.check_children)

    def on_diagnostics(self, msg):
        for status in msg.status:
            if status.name.endswith(STATUS_SUFFIX):
                print(summary(status), flush=True)

    def check_children(self):
        for name, process in self.children.items():
            code = process.poll()
            if code is not None and not self.finished.done():
                print('%s stopped unexpectedly with exit code %d' % (name, code), flush=True)
                self.finished.set_result(1)


def start_children(config, scene, bodies, rate):
    """Start the node and the pose publisher with this Python; return {name: Popen}."""
    # Own process groups: Ctrl-C reaches only the demo, which stops each child once, in order.
    commands = {
        'collision_node': child_command('collision_node', '--ros-args', '--params-file', config),
        'pose_publisher': child_command('pose_publisher', '--scene', scene, '--bodies',
                                        str(bodies), '--rate', str(rate)),
    }
    children = {}
    try:
        for name, command in commands.items():
            children[name] = subprocess.Popen(command, start_new_session=True)
            print('started %s (pid %d)' % (name, children[name].pid), flush=True)
    except OSError:
        stop_children(children)
        raise
    return children


def stop_children(children):
    """Stop the children in reverse start order: SIGINT, then SIGTERM, then SIGKILL."""
    for name, process in reversed(list(children.items())):
        stop_process(process, STOP_TIMEOUT_S, lambda signal_name, name=name: print(
            '%s did not stop on %s' % (name, signal_name), flush=True))
        print('stopped %s (pid %d)' % (name, process.pid), flush=True)


def parse_arguments(argv):
    parser = argparse.ArgumentParser(prog='collision_demo', description=__doc__.split('\n\n')[0])
    parser.add_argument('--duration', type=float, metavar='S',
                        help='stop after S seconds (default: run until Ctrl-C)')
    parser.add_argument('--scene', choices=sorted(CONFIGS), default='room',
                        help="room: boxes drifting through config/default.yaml's room; arm: "
                        'a robot arm with filters and a margin, config/arm.yaml (default: room)')
    parser.add_argument('--bodies', type=int, metavar='N',
                        help='moving boxes in the room (default: %d)' % SCENE_BODY_COUNTS['room'])
    parser.add_argument('--rate', type=float, default=30.0, metavar='HZ',
                        help='pose messages per second (default: 30)')
    parser.add_argument('--params-file', metavar='FILE',
                        help="the node's parameters (default: the scene's config file)")
    options = parser.parse_args(argv)
    if options.duration is not None and not options.duration > 0.0:
        parser.error('--duration must be positive, got %s' % options.duration)
    try:
        options.bodies = scene_body_count(options.scene, options.bodies)
    except ValueError as error:
        parser.error('--bodies: %s' % error)
    if options.bodies < 0:
        parser.error('--bodies must not be negative, got %d' % options.bodies)
    if not options.rate > 0.0:
        parser.error('--rate must be positive, got %s' % options.rate)
    if options.params_file is None:
        try:
            options.params_file = default_config(options.scene)
        except FileNotFoundError as error:
            parser.error('%s; pass --params-file' % error)
    elif not os.path.isfile(options.params_file):
        parser.error('--params-file %s: no such file' % options.params_file)
    return options


def main(args=None):
    options = parse_arguments(remove_ros_args(args)[1:])
    print('collision_node on %s, scene %s with %d moving boxes at %g Hz; Ctrl-C stops'
          % (options.params_file, options.scene, options.bodies, options.rate), flush=True)
    children = {}
    with RosProgram(args) as program:  # Ctrl-C or SIGTERM at any moment: status 0
        try:
            children.update(start_children(options.params_file, options.scene, options.bodies,
                                           options.rate))
            node = program.start(lambda: Demo(children))
            print('waiting for the first diagnostics (the node loads its numba kernels first)',
                  flush=True)
            program.spin_until(node.finished, timeout_sec=options.duration)
        finally:
            stop_children(children)
    finished = program.node.finished if program.node is not None else None
    return (finished.result() or 0) if finished is not None and finished.done() else 0


if __name__ == '__main__':
    sys.exit(main())
