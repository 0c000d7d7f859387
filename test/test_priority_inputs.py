"""Priority inputs: answered on an executor and thread of their own (ros/lifetime.py).

A node spun by ``spin_node_until`` (as main() spins it) answers the inputs of its
``priority_inputs`` on a thread of their own and everything else (other inputs, timers) on
the spinning thread; an input added or removed while it spins is taken or let go; the
thread ends with the spin. Then the node's own dynamic_poses and joint_states are among them.
"""
import threading

import pytest
import rclpy
from rclpy.task import Future
from std_msgs.msg import String

from collision_node.ros.lifetime import PriorityInputs, spin_node_until
from collision_node.ros.node import CollisionNode

TIMEOUT_S = 20.0


@pytest.fixture
def context():
    context = rclpy.Context()
    rclpy.init(context=context)
    yield context
    rclpy.try_shutdown(context=context)


def priority_threads():
    return [thread for thread in threading.enumerate() if thread.name == 'priority_inputs']


def test_priority_inputs_run_on_their_own_thread_and_follow_changes(context):
    node = rclpy.create_node('priority_test', context=context)
    node.priority_inputs = PriorityInputs(node)
    threads = {}  # topic: the threads that ran its callback
    done = Future()

    def listen(topic, group=None):
        def heard(_):
            threads.setdefault(topic, set()).add(threading.get_ident())
        subscription = node.create_subscription(String, topic, heard, 10, callback_group=group)
        return subscription

    fast = listen('fast', node.priority_inputs.group)
    node.priority_inputs.add(fast)
    listen('slow')
    publishers = {topic: node.create_publisher(String, topic, 10)
                  for topic in ('fast', 'slow', 'late')}
    steps = []

    def tick():  # a timer: on the spinning thread
        threads.setdefault('timer', set()).add(threading.get_ident())
        for publisher in publishers.values():
            publisher.publish(String(data='x'))
        if 'fast' in threads and 'slow' in threads and not steps:
            steps.append('late')  # an input added while the node spins
            late = listen('late', node.priority_inputs.group)
            node.priority_inputs.add(late)
            steps.append(late)
        elif 'late' in threads and len(steps) == 2:
            node.priority_inputs.discard(fast)  # and one taken away
            node.destroy_subscription(fast)
            steps.append('gone')
        elif len(steps) == 3:
            done.set_result(True)

    node.create_timer(0.01, tick)
    main = threading.get_ident()
    spin_node_until(node, done, TIMEOUT_S)
    assert done.done(), threads
    assert threads['timer'] == threads['slow'] == {main}
    assert len(threads['fast']) == 1 and threads['fast'] == threads['late'] != {main}
    assert priority_threads() == []  # the spin ended it
    node.destroy_node()


def test_the_node_answers_dynamic_poses_and_joint_states_first(context):
    node = CollisionNode(context=context)
    try:
        topics = {subscription.topic_name for subscription in node.subscriptions
                  if not node.priority_inputs.left_out(subscription)}
        assert topics == {'/dynamic_poses', '/joint_states'}
    finally:
        node.destroy_node()


def test_an_error_of_a_priority_input_ends_the_spin_with_it(context):
    node = rclpy.create_node('priority_error', context=context)
    node.priority_inputs = PriorityInputs(node)

    def fail(_):
        raise ZeroDivisionError('a bug in a callback')

    failing = node.create_subscription(String, 'fast', fail, 10,
                                       callback_group=node.priority_inputs.group)
    node.priority_inputs.add(failing)
    publisher = node.create_publisher(String, 'fast', 10)
    node.create_timer(0.01, lambda: publisher.publish(String(data='x')))
    with pytest.raises(ZeroDivisionError, match='a bug'):
        spin_node_until(node, Future(), TIMEOUT_S)  # as on the main thread: raised, not lost
    assert priority_threads() == []
    node.destroy_node()
