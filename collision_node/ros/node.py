"""The collision_node ROS 2 node: dynamic poses in, colliding pairs out (doc/design.md).

A thin layer over :class:`~collision_node.pipeline.world.World`: it reads the PoseArray as raw
CDR bytes (numpy, no per-pose Python), checks the input against the parameters, steps the World and
writes the `collisions` cloud as raw CDR bytes too. Everything geometric lives in the World.

A managed (lifecycle) node (doc/lifecycle.md). Made, it declares its parameters and publishes
/diagnostics, nothing else; configure reads the parameters, builds the World, loads the kernels
and creates the endpoints; activate opens the gate every input callback goes through
(:meth:`CollisionNode._create_input`); deactivate closes it; cleanup releases the World and the
endpoints. ``autostart`` (the default) configures and activates in the constructor. A new input
topic is one line in :meth:`CollisionNode._configure`, ``self._create_input(type, topic,
callback)``, and a new output one ``self._create_output(type, topic)``: both then follow the
lifecycle. Every attribute is declared in ``__init__``; what configure makes, cleanup sets back
to None (the ros2/demos lifecycle talker's pattern).

Inputs. Every pose topic's message is read and checked by one function, :func:`_read_poses`
(the CDR parse, the frame, the size: max_bodies and the topic's own rule on its count); every
refused input, on any topic, is one of REFUSALS and is reported by ``_reject`` as
``<topic>: <reason>``, with no answer.

Ticks. ``tick_rate_hz`` 0: each input is checked in the subscription callback. ``> 0``: the
callback only keeps the newest input and a timer checks it; a timer tick without a new input
does nothing (re-publishing the last answer would repeat an old stamp as if it were news).

``dropped_inputs`` counts inputs the node never checked: in timer mode those replaced by a
newer one before the timer came; in both modes, the gaps in the publisher's sequence numbers
(DDS message info), i.e. messages overwritten in the depth-1 queue while a tick ran or lost on
the way. Gaps are only counted while exactly one publisher is matched, because the message
info does not say which publisher a sequence number belongs to, and only after a first message
of that publisher came through (earlier ones may predate the subscription). While the node is
not active, an input and the gap before it count as ``ignored_inputs`` instead.

Stage times in /diagnostics: ``parse`` is the CDR parse and the input checks (the message at
the edge); ``broad`` is the World's: its boxes from the poses (rotation matrices, AABBs) and
the pair search; ``narrow`` the World's SAT and contacts; ``output`` writes the collisions
cloud (and the markers when they are built) as CDR bytes; ``publish`` hands those bytes to
rclpy; ``total`` is the whole tick. A World answer reused for an unchanged input counts as
broad time (the World's comparison with the last input).

Markers are built only while ``~/markers`` has a subscriber, at most 30 times a second and
at most a tenth of the node's time (see MARKER_COST_FACTOR). They are written as CDR bytes by
:mod:`collision_node.ros.markers` (numpy, ~0.2 µs a marker instead of rclpy's ~13 µs).

JIT. The kernels the configured World runs are compiled (or loaded from numba's cache) by a
warm-up before the subscription exists (pipeline.warm_up.warm_up_like), so the first ticks do not
compile; a compile is logged as it goes. The kernels of other settings and body counts are readied
in the background from then on (warm_up_in_background: on a cold or partial cache compiled in
other processes, then loaded here), so that a later tick does not compile either. .ci/setup-venv
compiles every kernel ahead with collision_node.tools.compile_kernels. numba caches next to
the sources when that directory is writable and otherwise in its user-wide cache
(~/.cache/numba); NUMBA_CACHE_DIR overrides both. The node leaves that choice to numba: the
variable must be set before numba is imported, which is the launching environment's business,
not the node's.
"""
import contextlib
import copy
import functools
import gc
import math
import threading
import time
from typing import Optional

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from geometry_msgs.msg import PoseArray
import numpy as np
from rcl_interfaces.msg import SetParametersResult
import rclpy
from rclpy.event_handler import PublisherEventCallbacks, SubscriptionEventCallbacks
from rclpy.lifecycle import LifecycleNode, LifecyclePublisher, TransitionCallbackReturn
from rclpy.parameter import Parameter
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
from rclpy.qos_overriding_options import QoSOverridingOptions
from rclpy.subscription import Subscription
from rclpy.task import Future
from sensor_msgs.msg import JointState, PointCloud2
from std_msgs.msg import Header, String
from trajectory_msgs.msg import JointTrajectory
from visualization_msgs.msg import MarkerArray

from collision_node.pipeline.contacts import CONTACT_DTYPE, STATE_CONTACT_DTYPE
from collision_node.pipeline.jit_progress import compile_progress
from collision_node.pipeline.robot import Robot
from collision_node.pipeline.static_scene import InvalidCollider
from collision_node.pipeline.warm_up import (cache_complete, warm_up_in_background,
                                             warm_up_like)
from collision_node.pipeline.world import World
from collision_node.ros import diagnostics, params
from collision_node.ros.cdr import parse_joint_state, parse_pose_array
from collision_node.ros.joints import JointValues
from collision_node.ros.lanes import compile_ros_kernels, JointLane, PoseLane
from collision_node.ros.lifetime import InitError, PriorityInputs, RosProgram
from collision_node.ros.markers import MarkerWriter
from collision_node.ros.memory import keep_heap_memory
from collision_node.ros.messages import CloudWriter

# Newest input wins (doc/design.md, "Topics"); reliable, because Fast DDS delivers nothing
# best-effort once a PoseArray passes ~512 KB. Overridable through the qos_overrides.*
# parameters.
INPUT_QOS = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=1,
                       reliability=ReliabilityPolicy.RELIABLE,
                       durability=DurabilityPolicy.VOLATILE)
OUTPUT_QOS = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=10,
                        reliability=ReliabilityPolicy.RELIABLE,
                        durability=DurabilityPolicy.VOLATILE)
# check_states requests and their answers: every request is answered, none dropped (a planner
# waits for each), so both queues keep everything until it is taken (reliable, keep all).
REQUEST_QOS = QoSProfile(history=HistoryPolicy.KEEP_ALL,
                         reliability=ReliabilityPolicy.RELIABLE,
                         durability=DurabilityPolicy.VOLATILE)
# robot_description and robot_description_semantic as robot_state_publisher and move_group
# publish them: the last model is kept for subscribers that come later.
MODEL_QOS = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=1,
                       reliability=ReliabilityPolicy.RELIABLE,
                       durability=DurabilityPolicy.TRANSIENT_LOCAL)
# joint_states: a best-effort subscription matches reliable and best-effort publishers alike;
# 10 deep, so that an arm's and a gripper's messages that arrive together are both taken.
JOINT_STATES_QOS = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=10,
                              reliability=ReliabilityPolicy.BEST_EFFORT,
                              durability=DurabilityPolicy.VOLATILE)
MODEL_TOPICS = ('robot_description', 'robot_description_semantic')
# No endpoint watches QoS events: rclpy gives every publisher and subscription two handlers by
# default (incompatible QoS, incompatible type), only to log a warning, and its executor walks
# every handler on every wake-up: ~4.5 µs each, ~60 µs a wake-up for the node's 14 (an idle
# spin took 207 µs with them, 152 µs without, on the machine of doc/benchmarks.md). The other
# side of a mismatch still logs it (rclcpp and rclpy endpoints watch by default), and an input
# that never arrives turns the diagnostics to ERROR after input_timeout.
NO_PUBLISHER_EVENTS = PublisherEventCallbacks(use_default_callbacks=False)
NO_SUBSCRIPTION_EVENTS = SubscriptionEventCallbacks(use_default_callbacks=False)
# RViz draws at most ~30 frames/s, so faster markers are never seen. Markers run on the tick's
# thread and a large scene makes a large MarkerArray (232 bytes a marker: 23 MB at 100,000
# bodies): they are rebuilt only after this many times their last build and publish time, so
# they take at most 1/10 of the node's time, however large the scene.
MARKER_PERIOD_S = 1.0 / 30.0
MARKER_COST_FACTOR = 10.0
# Sequence number 0 means the rmw does not report publication sequence numbers.
SEQUENCE_UNSUPPORTED = 0
LOG_THROTTLE_S = 5.0


class InputError(ValueError):
    """An input message the node refuses; the text is the reason in the diagnostics."""


# What refuses an input, on every topic. ValueError: a message that does not parse (CdrError),
# is in another frame or of another size (InputError), holds bad joint values
# (JointInputError), or a body the World refuses (it names the first one: the whole message
# is refused rather than that body left out, which would report it as free). ArithmeticError
# and RuntimeError: finite values near the float64 limit (|x| ~ 1e308, e.g. a flipped exponent
# bit) overflow inside a broad phase or the SAT; one refused input costs less than the node,
# and the World's next step starts afresh from its input.
REFUSALS = (ValueError, ArithmeticError, RuntimeError)


class CollisionNode(LifecycleNode):
    """Checks the dynamic boxes of each PoseArray against each other and the static colliders."""

    def __init__(self, **kwargs):
        # A collider added at run time brings its block (<name>.pose, ...): parameters the node
        # could not declare before. _on_set_parameters refuses every name it does not know.
        kwargs.setdefault('allow_undeclared_parameters', True)
        super().__init__('collision_node', **kwargs)
        # Declared now, so that a manager can set them before configure; a wrong-typed value is
        # kept here and fails configure (params.declare).
        self._declaration_errors = params.declare(self)
        self._config = None  # params.Parameters while configured
        self._world = None
        # Parameter changes may come from another thread (Node.set_parameters); ticks run on
        # the executor's. The lock keeps a World change from landing in the middle of a step.
        self._world_lock = threading.Lock()
        # The lifecycle gate (_gated): an input callback runs whole under it, and a transition
        # takes it to open or close the gate, so it never lands in the middle of a tick.
        self._gate = threading.RLock()
        self._active = False
        # The thread of a transition that declares or sets parameters itself (configure, cleanup):
        # its changes are not a user's, to check or apply. Another thread's still are.
        self._own_changes = None
        self._autostarting = False
        self._configure_error = None  # why the last configure failed
        self._file_colliders = []  # names configure added to static_colliders (the scene file)
        # Made by configure, set back to None (destroyed) by cleanup, as in the ros2/demos
        # lifecycle talker. Every endpoint is in _inputs or _outputs, for cleanup to destroy;
        # the named ones are those a callback uses.
        self._inputs, self._outputs = [], []
        self._subscription: Optional[Subscription] = None  # dynamic_poses: its publisher count
        self._collisions_publisher: Optional[LifecyclePublisher] = None
        self._markers_publisher: Optional[LifecyclePublisher] = None
        self._states_publisher: Optional[LifecyclePublisher] = None
        self._trajectory_publisher: Optional[LifecyclePublisher] = None
        self._cloud_writer: Optional[CloudWriter] = None   # collisions
        self._joints_writer: Optional[CloudWriter] = None  # collisions of check_joints
        self._states_writer: Optional[CloudWriter] = None  # state and trajectory collisions
        self._marker_writer: Optional[MarkerWriter] = None
        # The thread readying every kernel this configuration did not (pipeline.warm_up).
        self._background_warm_up: Optional[threading.Thread] = None
        self._tick_timer = None  # checks the newest input, when tick_rate_hz > 0
        self._pending = None  # the newest unchecked input, in timer mode
        self._last_sequence = None  # the publication sequence number of the last input
        self._next_markers_s = -math.inf  # monotonic s: no markers are built before
        self._scene_version = 0  # counts the accepted changes of the colliders (diagnostics)
        # The robot (doc/robot.md, "Through ROS"): its model while one is loaded, the XML it was
        # built from (topic name: text), and its joint values from joint_states.
        self._robot = None
        self._model_texts = dict.fromkeys(MODEL_TOPICS, '')
        self._joints = None
        self._joint_state = None  # the last joint_states message taken (its names are reused)
        self._joint_lane = JointLane()  # its layout, for the next messages of it
        self._pose_lane = PoseLane()  # the layout of the last dynamic_poses read
        self.finalized = Future()  # done once the shutdown transition has run
        # dynamic_poses and joint_states: answered on an executor and thread of their own,
        # which waits on nothing else (lifetime.PriorityInputs), when main() spins the node.
        self.priority_inputs = PriorityInputs(self)
        self.add_on_set_parameters_callback(self._on_set_parameters)
        self.add_post_set_parameters_callback(self._after_set_parameters)

        # Diagnostics in every state: they are how a watcher learns that the node is not
        # checking. Their period is checked here already, as configure would.
        self._monitor = diagnostics.Monitor(time.monotonic())
        self._monitor.lifecycle(time.monotonic(), 'unconfigured')
        self._diagnostics_publisher = self.create_publisher(
            DiagnosticArray, '/diagnostics', OUTPUT_QOS, event_callbacks=NO_PUBLISHER_EVENTS)
        self._diagnostics_timer = self.create_timer(
            params.diagnostic_period_s(self.get_parameter('diagnostic_updater.period').value),
            self._publish_diagnostics)
        if self.get_parameter('autostart').value:
            self._autostart()

    def _autostart(self):
        """Configure and activate, as a manager would; raise configure's error if it fails."""
        self._autostarting = True
        try:
            configured = self.trigger_configure()
        finally:
            self._autostarting = False
        if configured != TransitionCallbackReturn.SUCCESS:
            error = self._configure_error
            self.destroy_node()
            raise error
        self.trigger_activate()

    # Lifecycle transitions (doc/lifecycle.md). rclpy calls them from the change_state service,
    # or from trigger_*; the lifecycle publishers follow through super().

    def on_configure(self, state):
        """Read and check the parameters, build the World, load the kernels, make the endpoints."""
        try:
            self._configure()
        except params.ParameterError as error:
            self._release()
            self._unlist_file_colliders()
            self._failed_configure(error)
            return TransitionCallbackReturn.FAILURE
        except Exception as error:  # noqa: B902 (anything else: rclpy would swallow it)
            self.get_logger().error('configure failed: %s: %s' % (type(error).__name__, error))
            self._release()
            self._unlist_file_colliders()
            self._failed_configure(error)
            return TransitionCallbackReturn.ERROR
        self._configure_error = None
        self._monitor.lifecycle(time.monotonic(), 'inactive')
        return super().on_configure(state)

    def _failed_configure(self, error):
        self._configure_error = error
        self._monitor.lifecycle(time.monotonic(), 'unconfigured', 'configure failed: %s' % error)
        if not self._autostarting:  # under autostart, main() says it once, as FATAL
            self.get_logger().error('configure failed: %s' % error)

    def _configure(self):
        listed = list(self.get_parameter_or('static_colliders').value or [])
        with self._changing_parameters():
            self._config = config = params.read(self, self._declaration_errors)
        self._file_colliders = [c.name for c in config.colliders if c.name not in listed]
        # The World owns the static scene; the node only turns parameters and static_poses
        # messages into its verbs, by each collider's id (params.Collider.static_id).
        world = World(config.broad_phase, config.sphere_prefilter, config.octree_max_depth,
                      config.octree_leaf_cooldown_ticks, config.threads, config.margin,
                      config.continuous, config.continuous_tolerance)
        with self._world_lock:
            self._world = world
        _add_colliders(world, config.colliders)
        world.set_filters(*config.filters())
        self._scene_version = 0
        self._robot, self._joints, self._joint_state = None, None, None
        self._joint_lane = JointLane()
        self._model_texts = {topic: getattr(config, topic) for topic in MODEL_TOPICS}
        if config.robot_description:  # a model from the parameters: built now, or no start
            try:
                robot = self._build_robot(self._model_texts)
            except Exception as error:  # noqa: B902 (as _on_model)
                raise params.ParameterError('robot_description', str(error)) from None

        # The kernels this configuration runs now; every other one (other settings, other
        # body counts) in the background from here on, while the node answers (pipeline.warm_up).
        start = time.perf_counter()
        with compile_progress(self.get_logger().info) as progress:
            warm_up_like(world, config.dynamic_half_extents,
                         robot if config.robot_description else None)
            compile_ros_kernels(margins=(world.has_margins,),
                                robot=bool(config.robot_description))
        self._background_warm_up = warm_up_in_background(
            progress.compiled > 0 or not cache_complete(), self._background_ready,
            also=('clouds and lanes', compile_ros_kernels))
        self._cloud_writer = CloudWriter()
        # The robot's answers carry their state (World.check_joints); collisions does not.
        self._joints_writer = CloudWriter(STATE_CONTACT_DTYPE, CONTACT_DTYPE.names)
        self.get_logger().info('JIT warm-up of the configured World took %.2f s'
                               % (time.perf_counter() - start))

        self._monitor.scene(self._scene_version, config.colliders)
        if self._diagnostics_timer.timer_period_ns != round(1e9 * config.diagnostic_period_s):
            self.destroy_timer(self._diagnostics_timer)
            self._diagnostics_timer = self.create_timer(config.diagnostic_period_s,
                                                        self._publish_diagnostics)
        self._collisions_publisher = self._create_output(PointCloud2, 'collisions')
        self._markers_publisher = self._create_output(MarkerArray, '~/markers')
        self._states_publisher = self._create_output(PointCloud2, 'state_collisions',
                                                     REQUEST_QOS)
        self._states_writer = CloudWriter(STATE_CONTACT_DTYPE)
        self._marker_writer = MarkerWriter(config.frame_id)
        if config.robot_description:
            self._load_robot(robot)
        self._trajectory_publisher = self._create_output(PointCloud2, 'trajectory_collisions',
                                                         REQUEST_QOS)
        if config.tick_rate_hz > 0.0:
            self._tick_timer = self.create_timer(1.0 / config.tick_rate_hz,
                                                 self._gated(self._on_tick_timer, lambda: None))
            self._tick_timer.cancel()  # activate starts it
        # Last, after the warm-up: no input is taken before the node can answer it in time.
        self._subscription = self._create_input(PoseArray, 'dynamic_poses', self._on_input,
                                                self._ignore_input, priority=True)
        self._create_input(PoseArray, 'static_poses', self._on_static_poses, scene=True)
        self._create_input(PoseArray, 'check_states', self._on_check_states, qos=REQUEST_QOS)
        # The robot: a model topic only when its parameter is empty; models and joint values
        # are kept while inactive too (scene inputs), only answers wait for the activate.
        for topic, callback in zip(MODEL_TOPICS, (self._on_robot_description,
                                                  self._on_robot_description_semantic)):
            if not getattr(config, topic):
                self._create_input(String, topic, callback, scene=True, qos=MODEL_QOS,
                                   raw=False)
        self._create_input(JointState, 'joint_states', self._on_joint_states,
                           self._keep_joint_states, qos=JOINT_STATES_QOS, priority=True)
        self._create_input(JointTrajectory, 'check_trajectory', self._on_check_trajectory,
                           qos=REQUEST_QOS, raw=False)
        self.get_logger().info(
            '%d static colliders (%d enabled), broad phase %s, %s, %d thread%s' % (
                len(config.colliders), self._world.static_count, config.broad_phase,
                'tick on every input' if not config.tick_rate_hz
                else 'tick at %g Hz' % config.tick_rate_hz,
                config.threads, '' if config.threads == 1 else 's'))

    def _background_ready(self, line):
        """Log ``line`` (every other kernel is ready), and freeze what the warm-up made.

        The background warm-up loads every kernel after main froze the start's objects: some
        50,000 more that live as long as the process. Left to the collector, a full pass over
        them took 9 ms here (a tick of 200 Hz input missed); frozen, none does.
        """
        self.get_logger().info(line)
        gc.freeze()

    def on_activate(self, state):
        """Answer inputs from now on: the publishers first, then the gate."""
        result = super().on_activate(state)
        with self._gate:
            self._active = True
            if self._tick_timer is not None:
                self._tick_timer.reset()
            self._monitor.lifecycle(time.monotonic(), 'active')
        self.get_logger().info('active: checking inputs')
        return result

    def on_deactivate(self, state):
        """Answer nothing from now on; an input waiting for the timer is ignored, not kept."""
        with self._gate:  # waits for a tick under way: it is answered whole
            self._close_gate('inactive')
        self.get_logger().info('inactive: not checking inputs')
        return super().on_deactivate(state)

    def on_cleanup(self, state):
        """Release the World and the endpoints; the parameters stay, settable until configure."""
        self._release()
        self._unlist_file_colliders()
        self._monitor.lifecycle(time.monotonic(), 'unconfigured')
        return super().on_cleanup(state)

    def on_shutdown(self, state):
        """Release everything from any state; main() then ends the process."""
        self._release()
        self._monitor.lifecycle(time.monotonic(), 'finalized')
        result = super().on_shutdown(state)
        self.finalized.set_result(True)
        return result

    def on_error(self, state):
        """Release what a transition that raised made, and go back to unconfigured."""
        self._release()
        self._unlist_file_colliders()
        if self._configure_error is None:  # else configure's own reason stays
            self._monitor.lifecycle(time.monotonic(), 'unconfigured',
                                    'a transition from %s raised' % state.label)
        return TransitionCallbackReturn.SUCCESS

    def _close_gate(self, state):
        self._active = False
        if self._tick_timer is not None:
            self._tick_timer.cancel()
        if self._pending is not None:
            self._pending = None
            self._monitor.ignored()
        self._monitor.lifecycle(time.monotonic(), state)

    def _release(self):
        """Destroy the endpoints and the World configure made (any part of them), if any."""
        with self._gate:
            if self._active:
                self._close_gate('inactive')
            while self._inputs:
                subscription = self._inputs.pop()
                self.priority_inputs.discard(subscription)
                self.destroy_subscription(subscription)
            while self._outputs:
                self.destroy_lifecycle_publisher(self._outputs.pop())
            if self._tick_timer is not None:
                self.destroy_timer(self._tick_timer)
            self._subscription = self._tick_timer = None
            self._collisions_publisher = self._markers_publisher = None
            self._states_publisher = self._trajectory_publisher = None
            self._cloud_writer = self._joints_writer = self._states_writer = None
            self._marker_writer = None
            self._background_warm_up = None
            self._pending, self._last_sequence, self._next_markers_s = None, None, -math.inf
            with self._world_lock:
                world, self._world, self._config = self._world, None, None
                self._robot, self._joints, self._joint_state = None, None, None
                self._joint_lane = JointLane()
            if world is not None:
                world.close()

    def _unlist_file_colliders(self):
        """Take the scene file's colliders out of static_colliders: configure lists them again."""
        if self._file_colliders:
            names = [name for name in self.get_parameter('static_colliders').value
                     if name not in self._file_colliders]
            self._file_colliders = []
            with self._changing_parameters():
                self.set_parameters([Parameter('static_colliders', value=names)])

    @contextlib.contextmanager
    def _changing_parameters(self):
        """Set parameters from this thread without the user's checks and effects."""
        self._own_changes = threading.get_ident()
        try:
            yield
        finally:
            self._own_changes = None

    # Inputs.

    def _create_input(self, message_type, topic, callback, ignore=None, scene=False,
                      qos=INPUT_QOS, raw=True, priority=False):
        """Subscribe ``callback`` to an input topic, behind the lifecycle gate (at configure).

        Every input is made here: raw CDR bytes, the input QoS with its qos_overrides
        parameters, and the callback run by :meth:`_gated`, which calls ``ignore`` (the same
        arguments; by default: count one ignored input) for an input it turns away. ``scene``:
        the input changes the scene rather than asking for an answer (static_poses): it is
        applied while inactive too. ``raw=False`` for the small messages of the robot (rclpy
        deserialises them). ``priority``: answered on the thread of :attr:`priority_inputs`.
        """
        # A copy: rclpy writes the qos_overrides into the profile it is given, and the next
        # node of this process would start from them.
        subscription = self.create_subscription(
            message_type, topic, self._gated(callback, ignore, scene), copy.copy(qos),
            raw=raw, qos_overriding_options=QoSOverridingOptions.with_default_policies(),
            event_callbacks=NO_SUBSCRIPTION_EVENTS,
            callback_group=self.priority_inputs.group if priority else None)
        if priority:
            self.priority_inputs.add(subscription)
        self._inputs.append(subscription)  # cleanup destroys it
        return subscription

    def _create_output(self, message_type, topic, qos=OUTPUT_QOS):
        """Return a lifecycle publisher for an output topic (at configure; cleanup destroys it).

        It publishes nothing while the node is not active, whatever calls it.
        """
        publisher = self.create_lifecycle_publisher(message_type, topic, qos,
                                                    event_callbacks=NO_PUBLISHER_EVENTS)
        self._outputs.append(publisher)
        return publisher

    def _gated(self, callback, ignore=None, scene=False):
        """Return ``callback`` run only while the node is active (configured, for a ``scene``).

        It runs whole under the gate's lock, which the transitions take: a deactivate waits
        for an input under way, which is answered whole, and an input after it is not answered
        at all. An input the gate turns away goes to ``ignore`` (None: counted as one ignored
        input in the diagnostics), never kept for later.
        """
        @functools.wraps(callback)  # rclpy reads the signature: message info or not
        def gated(*args):
            with self._gate:
                if self._active or scene and self._world is not None:
                    callback(*args)
                elif ignore is None:
                    self._monitor.ignored()
                else:
                    ignore(*args)
        gated.lifecycle_gated = True  # test_lifecycle checks every subscription for it
        return gated

    def _on_input(self, buffer, info):
        if self._config.tick_rate_hz > 0.0:
            self._count_input(info)
            if self._pending is not None:
                self._monitor.dropped()
            self._pending = buffer
        else:
            self._check(buffer)  # first: after idle time, all that runs before it is latency
            self._count_input(info)

    def _count_input(self, info):
        self._monitor.received()
        self._monitor.dropped(self._sequence_gap(info))

    def _on_tick_timer(self):
        buffer, self._pending = self._pending, None
        if buffer is not None:
            self._check(buffer)

    def _ignore_input(self, buffer, info):
        """Count an input that came while the node was not active, and those lost before it."""
        self._monitor.ignored(1 + self._sequence_gap(info))

    def _sequence_gap(self, info):
        """Return how many inputs of the publisher were lost just before this one."""
        sequence = info.get('publication_sequence_number')
        if sequence in (None, SEQUENCE_UNSUPPORTED):
            return 0
        previous, self._last_sequence = self._last_sequence, sequence
        # A smaller number is another (or a restarted) publisher: start counting from it.
        if previous is not None and sequence > previous + 1 \
                and self._subscription.get_publisher_count() == 1:
            return sequence - previous - 1
        return 0

    def _check(self, buffer):
        """Collide one input and publish the answer; a refused input publishes nothing."""
        config = self._config
        start = time.perf_counter()
        try:
            if self._robot is not None:
                raise InputError('refused while a robot model is loaded: its boxes are the '
                                 'dynamic bodies (publish joint_states)')
            if self._answer_poses_in_lane(buffer, config, start):
                return
            message = self._pose_lane.read(buffer, config)
            if message is None:  # not of the last layout read: the full way (lanes.py)
                message = _read_poses(buffer, config, _dynamic_count_problem)
                self._pose_lane.learn(buffer, message, config)
            checked = time.perf_counter()
            with self._world_lock:
                result = self._world.step(message.poses, config.dynamic_half_extents)
        except REFUSALS as error:
            self._reject('dynamic_poses', error)
            return
        self._publish_tick(start, checked, result, message.sec, message.nanosec, message.poses,
                           config.dynamic_half_extents)

    def _answer_poses_in_lane(self, buffer, config, start):
        """Answer a PoseArray in the pose lane (lanes.py); False: the full way.

        Read, checked and its cloud written in one kernel; the cloud is published first.
        """
        with self._world_lock:
            answer = self._pose_lane.answer(buffer, config, self._world, self._cloud_writer)
            if answer is None:
                return False
            cloud, poses, sec, nanosec = answer
            stepped = time.perf_counter()
            try:
                self._collisions_publisher.publish(cloud)  # then what the answer needs not
            finally:  # the World keeps the answer it reuses for the same input
                result = self._pose_lane.result(start, stepped)
        self._record_tick(start, start, stepped, 0.0, result, sec, nanosec, poses,
                          config.dynamic_half_extents)
        return True

    def _publish_tick(self, start, checked, result, sec, nanosec, poses, half_extents,
                      writer=None):
        """Publish a check's answer, then its markers and record (perf_counter times).

        ``writer``: the CloudWriter of the result's contacts (default: a step's).
        """
        stepped = time.perf_counter()
        cloud = (writer or self._cloud_writer).serialize(result.contacts, sec, nanosec,
                                                         self._config.frame_id)
        output_ms = 1e3 * (time.perf_counter() - stepped)
        self._collisions_publisher.publish(cloud)
        self._record_tick(start, checked, stepped, output_ms, result, sec, nanosec, poses,
                          half_extents)

    def _record_tick(self, start, checked, stepped, output_ms, result, sec, nanosec, poses,
                     half_extents):
        """Publish the markers when due and record the tick, once the answer is out.

        perf_counter times: ``start`` the input came, ``checked`` its checks were done,
        ``stepped`` the check was; ``output_ms`` spent writing the cloud after it; ``poses``
        None: no markers this time.
        """
        now = time.monotonic()
        if poses is not None and now >= self._next_markers_s:
            output_ms += 1e3 * self._publish_markers(sec, nanosec, poses, half_extents,
                                                     result, now)
        done = time.perf_counter()

        # Not result.stats: a small scene's step builds them only when read (by the report).
        phase_ms = result.phase_ms
        if phase_ms is None:  # the World answered from its last result: no phase ran
            phase_ms = 1e3 * (stepped - checked), 0.0
        publish_ms = 1e3 * (done - stepped) - output_ms
        self._monitor.tick(now, (1e3 * (checked - start), *phase_ms, output_ms, publish_ms,
                                 1e3 * (done - start)), result)

    def _publish_markers(self, sec, nanosec, poses, half_extents, result, now):
        """Publish the markers if someone subscribes; return the seconds spent writing them.

        Whether anyone subscribes is asked at most once a MARKER_PERIOD_S: it is a query of the
        ROS graph, not worth an input's time while nobody watches.
        """
        if self._markers_publisher.get_subscription_count() == 0:
            self._next_markers_s = now + MARKER_PERIOD_S
            return 0.0
        start = time.perf_counter()
        with self._world_lock:
            colliders = self._world.static_colliders
            on = colliders.enabled
            statics = colliders.poses[on], colliders.half_extents[on], colliders.ids[on]
        markers = self._marker_writer.serialize(sec, nanosec, *statics, poses, half_extents,
                                                result.contacts)
        written = time.perf_counter() - start
        self._markers_publisher.publish(markers)
        cost = time.perf_counter() - start
        self._next_markers_s = now + max(MARKER_PERIOD_S, MARKER_COST_FACTOR * cost)
        return written

    def destroy_node(self):
        self._release()
        super().destroy_node()

    def _on_check_states(self, buffer):
        """Answer a check_states request: K states of the D bodies, in one state_collisions.

        A bad request gets no answer (an empty cloud would read as "no collisions"), and the
        diagnostics name the state and body at fault.
        """
        config = self._config
        start = time.perf_counter()
        try:
            if self._robot is not None:
                raise InputError('refused while a robot model is loaded: its boxes are the '
                                 'dynamic bodies (send joint-space paths to check_trajectory)')
            message = _read_poses(buffer, config, _states_count_problem)
            states = message.poses.reshape(-1, config.state_bodies, 7)
            with self._world_lock:  # the World names the state and body it refuses
                result = self._world.check_states(states, config.dynamic_half_extents)
        except REFUSALS as error:
            self._reject('check_states', error)
            return
        self._states_publisher.publish(self._states_writer.serialize(
            result.contacts, message.sec, message.nanosec, config.frame_id))
        self._monitor.states_checked(len(states), 1e3 * (time.perf_counter() - start))

    # The robot (doc/robot.md, "Through ROS").

    def _build_robot(self, texts):
        """Return the Robot of the model ``texts`` (topic name: XML); raise the parser's error."""
        if not texts['robot_description'].strip():
            raise ValueError('the URDF is empty')
        return Robot.from_urdf(texts['robot_description'],
                               srdf=texts['robot_description_semantic'] or None,
                               package_paths=self._config.robot_package_paths)

    def _on_robot_description(self, message):
        self._on_model('robot_description', message.data)

    def _on_robot_description_semantic(self, message):
        self._on_model('robot_description_semantic', message.data)

    def _on_model(self, topic, text):
        """Build the robot of a new URDF or SRDF and swap it in; a bad one leaves the old.

        The newest URDF is built with the newest SRDF, each kept even when their robot is
        refused: a new robot's URDF and SRDF come one after the other, and the first alone
        may not fit the other's old text (an SRDF naming links of the old robot).
        """
        self._model_texts = texts = dict(self._model_texts, **{topic: text})
        if topic != 'robot_description' and not texts['robot_description']:
            return  # an SRDF before any URDF: kept for it
        try:
            # Outside the world lock (meshes are read from files): ticks go on meanwhile.
            robot = self._build_robot(texts)
        except Exception as error:  # noqa: B902 - XML, files, trimesh: no model stops the node
            self._refuse_model('%s: %s' % (topic, error))
            return
        self._load_robot(robot)

    def _load_robot(self, robot):
        """Make ``robot`` the World's robot at once, its joints keeping the values they had."""
        with self._world_lock:
            try:
                self._world.set_robot(robot, self._config.robot_base_pose)
            except ValueError as error:
                self._refuse_model('robot_description: %s' % error)
                return False
            self._robot = robot
            self._joints = JointValues(robot.joint_names, self._joints)
            missing = self._joints.missing
        self._marker_writer.name_bodies(robot.box_links)
        self._monitor.robot(robot.joint_names, robot.box_links)
        self._monitor.missing_joints(missing)
        self.get_logger().info('robot model: %d joints, %d boxes on %d links'
                               % (robot.dof, len(robot.box_links), len(set(robot.box_links))))
        return True

    def _refuse_model(self, reason):
        self._monitor.robot_refused(reason)
        self.get_logger().warn('robot model refused, the previous one stays: %s' % reason)

    def _on_joint_states(self, buffer):
        """Take a joint_states message's values; once every joint has one, answer on collisions."""
        start = time.perf_counter()
        if self._answer_joints_in_lane(buffer, start):
            return
        message = self._merge_joint_states(buffer)
        if message is None:
            return
        self._monitor.received()
        try:
            with self._world_lock:
                robot, joints = self._robot, self._joints
                missing = joints.missing
                if not missing:
                    checked = time.perf_counter()
                    q = joints.q()
                    if self._world.continuous:  # swept since the last input: a step of boxes
                        poses = self._world.robot_poses(q)[0]
                        result = self._world.step(poses, robot.half_extents)
                        writer = self._cloud_writer
                    else:  # the robot's pass: the same answer, forward kinematics inside
                        result = self._world.check_joints(q)
                        writer = self._joints_writer
                        poses = self._marker_poses(joints)
        except REFUSALS as error:  # ValueError: the World's filters sized for other bodies
            self._reject('joint_states', error)
            return
        self._monitor.missing_joints(missing)
        if missing:
            self.get_logger().warn('no answer on collisions until joint_states gives %s'
                                   % ', '.join(missing), throttle_duration_sec=LOG_THROTTLE_S)
            return
        self._publish_tick(start, checked, result, message.sec, message.nanosec, poses,
                           robot.half_extents, writer)

    def _answer_joints_in_lane(self, buffer, start):
        """Answer a message in the joint_states lane (lanes.py); False: the full way."""
        with self._world_lock:
            world = self._world
            rows = None if world.continuous else world.robot_pass()
            answer = self._joint_lane.answer(buffer, self._joints, rows, self._joints_writer,
                                             self._config.frame_id)
            if answer is None:
                return False
            contacts, passed, sat_tests, sec, nanosec, cloud = answer
            stepped = time.perf_counter()
            self._collisions_publisher.publish(cloud)  # then what the answer needs not
            result = rows.result(contacts, passed, sat_tests, 1e3 * (stepped - start), 1)
            half_extents = self._robot.half_extents
            poses = self._marker_poses(self._joints)
        self._monitor.received()
        self._monitor.missing_joints(())
        self._record_tick(start, start, stepped, 0.0, result, sec, nanosec, poses, half_extents)
        return True

    def _marker_poses(self, joints):
        """Return the box poses at the values of ``joints`` for the markers when due, else None."""
        if time.monotonic() < self._next_markers_s:
            return None
        return self._world.robot_poses(joints.q())[0]

    def _keep_joint_states(self, buffer):
        """While not active: keep the joint values (answer nothing); count an ignored input."""
        self._monitor.ignored()
        self._merge_joint_states(buffer)

    def _merge_joint_states(self, buffer):
        """Merge a message into the joint values; return it, or None without a robot or refused.

        Read from its CDR: a driver's names, the same in every message, are read once
        (cdr.parse_joint_state), and its positions go to q as one array.
        """
        if self._joints is None:  # no model yet: nothing to check against
            return None
        try:
            message = parse_joint_state(buffer, self._joint_state)
            self._joints.merge(message.names, message.positions)
        except REFUSALS as error:
            self._reject('joint_states', error)
            return None
        self._joint_state = message
        self._joint_lane.learn(buffer, message, self._joints)
        return message

    def _on_check_trajectory(self, message):
        """Answer a check_trajectory request on trajectory_collisions; refuse a bad one."""
        start = time.perf_counter()
        try:
            with self._world_lock:
                if self._robot is None:
                    raise InputError('no robot model yet (robot_description)')
                # JointInputError names the waypoint and joint at fault.
                waypoints = self._joints.waypoints(
                    list(message.joint_names), [point.positions for point in message.points])
                result = self._world.check_trajectory(waypoints)
        except REFUSALS as error:
            self._reject('check_trajectory', error)
            return
        stamp = message.header.stamp
        self._trajectory_publisher.publish(self._states_writer.serialize(
            result.contacts, stamp.sec, stamp.nanosec, self._config.frame_id))
        self._monitor.trajectory_checked(1e3 * (time.perf_counter() - start))

    def _on_static_poses(self, buffer):
        """Move the static colliders from the next tick on; refuse an invalid message whole."""
        try:
            # Checked against the colliders as they are: a parameter change (maybe from
            # another thread) comes before or after the whole message.
            with self._world_lock:
                config = self._config
                message = _read_poses(buffer, config, _static_count_problem, bounded=False)
                # Disabled colliders are moved (and checked) too: they may be enabled later.
                try:
                    moved = self._world.move_static([c.static_id for c in config.colliders],
                                                    message.poses)
                except InvalidCollider as error:  # by its name, as the parameters know it
                    raise InputError('collider %d (%s): %s' % (
                        error.body, config.colliders[error.body].name, error.reason)) from None
                if moved:
                    self._scene_version += 1
        except REFUSALS as error:
            self._reject('static_poses', error)
        else:
            self._monitor.scene(self._scene_version)

    def _reject(self, topic, error):
        """Refuse an input of ``topic`` for ``error`` (one of REFUSALS): no answer, a reason."""
        if isinstance(error, (ArithmeticError, RuntimeError)):
            reason = '%s: an input the World cannot check (%s: %s)' % (
                topic, type(error).__name__, error)
        else:
            reason = '%s: %s' % (topic, error)
        self._monitor.rejected(reason)
        self.get_logger().warn('input rejected: %s' % reason,
                               throttle_duration_sec=LOG_THROTTLE_S)

    def _on_set_parameters(self, changes):
        """Accept run-time changes that are valid together, or refuse them all with why.

        Validation only (rclpy may still refuse the call after this): the changes are
        applied by :meth:`_after_set_parameters`. While unconfigured, any parameter the node
        has may be set to a value of its type: configure checks them all together.
        """
        if self._own_changes == threading.get_ident():  # configure's own, or cleanup's
            return SetParametersResult(successful=True)
        try:
            if self._config is None:
                for change in changes:
                    params.check_unconfigured(change.name, change.value)
            else:
                self._changed_parameters(changes)
        except params.ParameterError as error:
            return SetParametersResult(successful=False, reason=str(error))
        return SetParametersResult(successful=True)

    def _after_set_parameters(self, changes):
        """Apply accepted run-time changes to the World: from the next tick on, all at once."""
        if self._own_changes == threading.get_ident():
            return
        for change in changes:  # a value of the right type replaces one that had the wrong one
            self._declaration_errors.pop(change.name, None)
        if self._config is None:
            return  # configure reads them
        with self._world_lock:
            old, changed = self._config, self._changed_parameters(changes)
            world = self._world
            world.configure(
                broad_phase=changed.broad_phase, octree_max_depth=changed.octree_max_depth,
                octree_leaf_cooldown_ticks=changed.octree_leaf_cooldown_ticks)
            world.sphere_prefilter = changed.sphere_prefilter
            if changed.colliders is not old.colliders:  # a collider or the list was set
                _change_colliders(world, old.colliders, changed.colliders)
                self._scene_version += 1
                self._monitor.scene(self._scene_version, changed.colliders)
            filters = ('dynamic_collision_category', 'dynamic_collision_mask', 'ignored_pairs')
            if any(getattr(changed, name) != getattr(old, name) for name in filters) \
                    or _ids(changed) != _ids(old):  # a name in ignored_pairs may have a new id
                world.set_filters(*changed.filters())
            world.margin = changed.margin
            world.continuous = changed.continuous
            world.continuous_tolerance = changed.continuous_tolerance
            self._config = changed

    def _changed_parameters(self, changes):
        """Return the parameters with ``changes`` made; ParameterError if they are refused."""
        given = {change.name: change.value for change in changes}

        def block_value(name):
            """Return a new collider's block value: this call's, else as set before, else None."""
            return given[name] if name in given else self.get_parameter_or(name).value

        changed = self._config
        # The list first, so that the other changes find the colliders it adds.
        for change in sorted(changes, key=lambda change: change.name != 'static_colliders'):
            changed = params.run_time_change(changed, change.name, change.value, block_value)
        params.check_run_time(changed)
        return changed

    def _publish_diagnostics(self):
        config = self._config
        timeout_s, rate_hz = (config.input_timeout_s, config.tick_rate_hz) if config else (0, 0)
        with self._gate:  # not while an input's callback, on its own thread, counts
            level, message, values = self._monitor.report(
                time.monotonic(), timeout_s, 1.0 / rate_hz if rate_hz else 0.0)
        status = DiagnosticStatus(
            level=bytes([level]), name=self.get_name() + diagnostics.STATUS_SUFFIX,
            message=message, hardware_id='none',
            values=[KeyValue(key=key, value=value) for key, value in values])
        self._diagnostics_publisher.publish(DiagnosticArray(
            header=Header(stamp=self.get_clock().now().to_msg()), status=[status]))


def _read_poses(buffer, config, count_problem, bounded=True):
    """Return the PoseArray of an input, checked as every pose input is; InputError if refused.

    The one input check of the pose topics: the CDR parses (CdrError says why not), the frame
    is the node's (an empty one counts as the node's), a ``bounded`` input holds at most
    max_bodies poses, and ``count_problem(count, config)``, the topic's own rule on its pose
    count, gives no reason to refuse it (None).
    """
    message = parse_pose_array(buffer)
    if message.frame_id and message.frame_id != config.frame_id:
        raise InputError("frame_id '%s' is not the node's frame_id '%s'"
                         % (message.frame_id, config.frame_id))
    count = len(message.poses)
    if bounded and count > config.max_bodies:
        raise InputError('%d poses exceed max_bodies %d' % (count, config.max_bodies))
    problem = count_problem(count, config)
    if problem:
        raise InputError(problem)
    return message


def _dynamic_count_problem(count, config):
    """dynamic_poses: one pose per size, when dynamic.half_extents gives one per body."""
    extents = config.dynamic_half_extents
    if extents.ndim == 2 and len(extents) != count:
        return 'dynamic.half_extents sizes %d bodies, the input has %d poses' % (
            len(extents), count)
    return None


def _states_count_problem(count, config):
    """check_states: whole states of check_states.bodies poses each."""
    bodies = config.state_bodies
    if not bodies:
        return ('the bodies of a state are not known: dynamic.half_extents gives one size for '
                'all; set check_states.bodies')
    if count % bodies:
        return '%d poses are not whole states of %d bodies (check_states.bodies)' % (
            count, bodies)
    return None


def _static_count_problem(count, config):
    """static_poses: one pose per collider, its count and not max_bodies its bound."""
    if count != len(config.colliders):
        return ('%d poses for %d static colliders (one per name in static_colliders, in its '
                'order)' % (count, len(config.colliders)))
    return None


def _add_colliders(world, colliders):
    """Give ``world`` the ``colliders`` (params.Collider) as new static colliders."""
    if colliders:
        world.add_static([c.static_id for c in colliders], [c.pose for c in colliders],
                         [c.half_extents for c in colliders],
                         margins=[c.margin for c in colliders],
                         categories=[c.collision_category for c in colliders],
                         masks=[c.collision_mask for c in colliders],
                         enabled=[c.enabled for c in colliders])


def _change_colliders(world, old, new):
    """Turn a change of the collider parameters from ``old`` to ``new`` into World verbs.

    Colliders are matched by id. A kept collider moves only when its pose parameter was set
    now (a new value object): else it stays where static_poses put it.
    """
    before = {c.static_id: c for c in old}
    after = {c.static_id: c for c in new}
    world.remove_static([i for i in before if i not in after])
    _add_colliders(world, [c for c in new if c.static_id not in before])
    kept = [(before[c.static_id], c) for c in new if c.static_id in before]
    posed = [c for b, c in kept if c.pose is not b.pose]
    if posed:
        world.move_static([c.static_id for c in posed], [c.pose for c in posed])
    sized = [c for b, c in kept if not np.array_equal(c.half_extents, b.half_extents)]
    if sized:
        world.move_static([c.static_id for c in sized],
                          half_extents=[c.half_extents for c in sized])
    switched = [c for b, c in kept if c.enabled != b.enabled]
    if switched:
        world.enable_static([c.static_id for c in switched], [c.enabled for c in switched])
    settings = ('margin', 'collision_category', 'collision_mask')
    tuned = [c for b, c in kept if any(getattr(c, key) != getattr(b, key) for key in settings)]
    if tuned:
        world.update_static([c.static_id for c in tuned], [c.margin for c in tuned],
                            [c.collision_category for c in tuned],
                            [c.collision_mask for c in tuned])


def _ids(config):
    """Return each collider's (name, static id)."""
    return [(c.name, c.static_id) for c in config.colliders]


def main(args=None):
    """Run the node until shutdown; exit with status 2 on a bad parameter under autostart.

    Shutdown is SIGINT (Ctrl-C), SIGTERM or the lifecycle shutdown transition: a finalized
    node has nothing left to do, so the process ends, with status 0, once the transition is
    answered. A signal ends it with status 0 whenever it comes (collision_node.ros.lifetime).
    """
    keep_heap_memory()  # before the first large message: see collision_node.ros.memory
    try:
        with RosProgram(args) as program:
            node = program.start(CollisionNode)
            # What the start made (modules, kernels, the World) lives as long as the process:
            # frozen, it is not walked by the garbage collector's passes during ticks.
            gc.freeze()
            program.spin_until(node.finalized)
    except (InitError, params.ParameterError) as error:
        rclpy.logging.get_logger('collision_node').fatal(str(error))
        raise SystemExit(2) from None


if __name__ == '__main__':
    main()
