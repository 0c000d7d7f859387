"""Print the node's `collisions` and `/diagnostics` as readable lines.

    collision_monitor                 # a collisions summary every second, each diagnostics status
    collision_monitor --once          # the next collisions message and the status after it

Contacts are written ``d3-s1 0.012 m at (x, y, z) n (nx, ny, nz)``: dynamic body 3 (index in
the PoseArray) touches static collider 1 (index in static_colliders), 12 mm deep, at that
contact point, with the unit normal from the first body to the second. A status is its level,
name and message, then one ``key=value`` line per value, so that grep finds any of them.

``--once`` prints the first collisions message, then the first status of the node
(``<name>: collision_check``) published after it, which describes that answer: a status from
before the answer may still be the ERROR of the time before any input came. When the node's
``collisions`` publisher is matched, it says so on standard error; it gives up ``--timeout``
seconds after that (or after its own start, when no publisher ever matches) with exit status 1,
so a node that first compiles its kernels for minutes is waited for.
"""
import argparse
import sys

from diagnostic_msgs.msg import DiagnosticArray
from rclpy.event_handler import SubscriptionEventCallbacks
from rclpy.node import Node
from rclpy.qos import HistoryPolicy, QoSProfile, ReliabilityPolicy
from rclpy.task import Future
from rclpy.utilities import remove_ros_args
from sensor_msgs.msg import PointCloud2

from collision_node.ros.diagnostics import LEVEL_NAMES, STATUS_SUFFIX
from collision_node.ros.messages import cloud_to_contacts
from collision_node.tools.processes import spin_until_finished

BODY_TYPE_LETTERS = {0: 'd', 1: 's'}  # type 0 = dynamic, 1 = static (doc/design.md)
# A value's line breaks are written as \n: a value never continues on the next line. (A
# rejection reason quotes the input's frame_id, which may hold anything.)
LINE_BREAKS = str.maketrans({'\n': '\\n', '\r': '\\r'})
ONCE_TIMEOUT_S = 60.0


def format_contacts(contacts, limit):
    """Format up to ``limit`` contacts (CLOUD_DTYPE) as one line, then how many are left."""
    parts = []
    for contact in contacts[:limit]:
        parts.append('%s%d-%s%d %.4g m at (%.3f, %.3f, %.3f) n (%.3f, %.3f, %.3f)' % (
            BODY_TYPE_LETTERS.get(int(contact['type_a']), '?'), contact['id_a'],
            BODY_TYPE_LETTERS.get(int(contact['type_b']), '?'), contact['id_b'],
            contact['depth'], contact['x'], contact['y'], contact['z'],
            contact['normal_x'], contact['normal_y'], contact['normal_z']))
    if len(contacts) > limit:
        parts.append('+%d more' % (len(contacts) - limit))
    return '; '.join(parts)


def format_status(status):
    """Format a DiagnosticStatus as a header line, then one indented key=value line per value."""
    level = LEVEL_NAMES.get(int.from_bytes(status.level, 'little'), repr(status.level))
    lines = ['%s %s: %s' % (level, status.name, status.message)]
    lines += ['    %s=%s' % (item.key, item.value) for item in status.values]
    return '\n'.join(line.translate(LINE_BREAKS) for line in lines)


class CollisionMonitor(Node):
    """Subscribes to collisions and /diagnostics and prints them."""

    def __init__(self, period_s, contact_limit, once, timeout_s=ONCE_TIMEOUT_S):
        super().__init__('collision_monitor')
        self.contact_limit = contact_limit
        self.once = once
        self.timeout_s = timeout_s
        self.finished = Future()  # result: the exit status
        self.clouds_in_period = 0
        self.latest_cloud = None
        self.printed_cloud = False
        self.printed_status = False
        # Reliable to match the node's outputs; depth 10 because only the latest is shown.
        qos = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=10,
                         reliability=ReliabilityPolicy.RELIABLE)
        events = SubscriptionEventCallbacks(matched=self.on_matched) if once else None
        self.create_subscription(PointCloud2, 'collisions', self.on_collisions, qos,
                                 event_callbacks=events)
        self.create_subscription(DiagnosticArray, '/diagnostics', self.on_diagnostics, qos)
        if once:
            self.timeout_timer = self.create_timer(timeout_s, self.give_up)
            self.matched = False
        else:
            self.create_timer(period_s, self.print_collisions)

    def on_matched(self, status):
        """Restart the wait when the first publisher of ``collisions`` is matched."""
        if status.current_count > 0 and not self.matched:
            self.matched = True
            self.timeout_timer.reset()
            print('collision_monitor: listening to %d collisions publisher(s); waiting up to '
                  '%g s for an answer' % (status.current_count, self.timeout_s),
                  file=sys.stderr, flush=True)

    def on_collisions(self, msg):
        self.latest_cloud = msg
        self.clouds_in_period += 1
        if self.once and not self.printed_cloud:
            self.print_collisions()

    def print_collisions(self):
        msg = self.latest_cloud
        if msg is None:
            return
        try:
            contacts = cloud_to_contacts(msg)
        except ValueError as error:
            print('collisions: unreadable cloud: %s' % error, flush=True)
        else:
            stamp = msg.header.stamp.sec + msg.header.stamp.nanosec * 1e-9
            line = 'collisions at %.3f in %r: %d pairs, %d msgs since last line' % (
                stamp, msg.header.frame_id, len(contacts), self.clouds_in_period)
            if len(contacts):
                line += ': ' + format_contacts(contacts, self.contact_limit)
            print(line, flush=True)
        self.latest_cloud = None
        self.clouds_in_period = 0
        self.printed_cloud = True
        self.check_done()

    def on_diagnostics(self, msg):
        statuses = msg.status
        if self.once:
            if not self.printed_cloud or self.printed_status:
                return
            statuses = [s for s in statuses if s.name.endswith(STATUS_SUFFIX)][:1]
        for status in statuses:
            print('diagnostics ' + format_status(status), flush=True)
            self.printed_status = True
        self.check_done()

    def check_done(self):
        if self.once and self.printed_cloud and self.printed_status:
            self.finish(0)

    def give_up(self):
        if self.printed_cloud:
            problem = 'no status of the node after the collisions message within %g s'
        elif self.matched:
            problem = 'no collisions message within %g s of matching its publisher (did an ' \
                'input reach collision_node?)'
        else:
            problem = 'no collisions publisher matched within %g s (is collision_node running, ' \
                'in this ROS domain?)'
        print('collision_monitor: ' + problem % self.timeout_s, file=sys.stderr, flush=True)
        self.finish(1)

    def finish(self, exit_status):
        if self.once:
            self.timeout_timer.cancel()
        if not self.finished.done():
            self.finished.set_result(exit_status)


def parse_arguments(argv):
    parser = argparse.ArgumentParser(
        prog='collision_monitor', description=__doc__.split('\n\n')[0],
        epilog='ROS arguments may follow --ros-args (e.g. -r collisions:=/other).')
    parser.add_argument('--once', action='store_true',
                        help="print the next collisions message and the node's status after "
                        'it, then exit')
    parser.add_argument('--timeout', type=float, default=ONCE_TIMEOUT_S, metavar='S',
                        help="with --once: give up S seconds after the node's collisions "
                        'publisher matched (or after the start, if none does), exit status 1 '
                        '(default: %g)' % ONCE_TIMEOUT_S)
    parser.add_argument('--period', type=float, default=1.0, metavar='S',
                        help='seconds between collisions lines (default: 1)')
    parser.add_argument('--contacts', type=int, default=5, metavar='N',
                        help='contacts shown per line (default: 5)')
    options = parser.parse_args(argv)
    if not options.period > 0.0:
        parser.error('--period must be positive, got %s' % options.period)
    if options.contacts < 0:
        parser.error('--contacts must not be negative, got %d' % options.contacts)
    if not options.timeout > 0.0:
        parser.error('--timeout must be positive, got %s' % options.timeout)
    return options


def main(args=None):
    """Run the monitor; the exit status is 1 when --once timed out, else 0."""
    options = parse_arguments(remove_ros_args(args)[1:])
    return spin_until_finished(args, lambda: CollisionMonitor(
        options.period, options.contacts, options.once, options.timeout))


if __name__ == '__main__':
    sys.exit(main())
