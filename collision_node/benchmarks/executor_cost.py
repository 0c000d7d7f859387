"""What an rclpy executor's wake-up costs per entity it waits on (a developer's tool).

    python -m collision_node.benchmarks.executor_cost
    python -m collision_node.benchmarks.executor_cost --services 0 6 13 26 --wakes 2000

The node's wait set holds about 20 entities (its inputs, the lifecycle's and the parameters'
services, its timers), an echo node's about 7, and rclpy walks every one on every wake-up. To
see what that costs apart from any collision work: one node per row, with one subscription
and a given number of extra services, on an executor of its own; a message is published, the
process sleeps as between two inputs at 200 Hz (caches go cold), then ``spin_once`` takes the
message. The rows take turns. Printed: the median time of that ``spin_once``, per count of
extra services.
"""
import argparse
import statistics
import time

import rclpy
from rclpy.executors import SingleThreadedExecutor
from std_msgs.msg import String
from std_srvs.srv import Trigger

WARM_UP_WAKES = 50
PAUSE_S = 0.002  # between publishing and taking: the idle time of a 200 Hz input, about


class Row:
    """A node with one subscription and ``services`` extra services, on its own executor."""

    def __init__(self, context, services):
        self.services = services
        self.node = rclpy.create_node('executor_cost_%d' % services, context=context,
                                      start_parameter_services=False)
        self.executor = SingleThreadedExecutor(context=context)
        topic = 'executor_cost_%d' % services
        self.node.create_subscription(String, topic, lambda message: None, 10)
        self.publisher = self.node.create_publisher(String, topic, 10)
        for i in range(services):
            self.node.create_service(Trigger, '%s_service_%d' % (topic, i),
                                     lambda request, response: response)
        self.executor.add_node(self.node)
        self.taken = []

    def wake(self, message, timed):
        """Publish, pause, and time the spin_once that takes the message."""
        self.publisher.publish(message)
        time.sleep(PAUSE_S)
        start = time.perf_counter()
        self.executor.spin_once(timeout_sec=1.0)
        if timed:
            self.taken.append(time.perf_counter() - start)

    def close(self):
        self.executor.shutdown()
        self.node.destroy_node()


def wake_up_costs(context, services, wakes):
    """Return {extra services: median seconds of a spin_once taking a waiting message}.

    The rows take turns, a wake-up each, so that the machine's drift reaches them alike.
    """
    rows = [Row(context, count) for count in services]
    try:
        message = String(data='x')
        for wake in range(WARM_UP_WAKES + wakes):
            for row in rows:
                row.wake(message, wake >= WARM_UP_WAKES)
        return {row.services: statistics.median(row.taken) for row in rows}
    finally:
        for row in rows:
            row.close()


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    parser.add_argument('--services', type=int, nargs='+', default=[0, 6, 13, 26],
                        help='extra services per row (default: 0 6 13 26)')
    parser.add_argument('--wakes', type=int, default=2000, help='timed wake-ups per row')
    options = parser.parse_args(argv)
    context = rclpy.Context()
    rclpy.init(context=context)
    try:
        for services, median in wake_up_costs(context, options.services,
                                              options.wakes).items():
            print('%2d extra services: spin_once taking a waiting message: median %.1f us'
                  % (services, 1e6 * median), flush=True)
    finally:
        context.try_shutdown()


if __name__ == '__main__':
    main()
