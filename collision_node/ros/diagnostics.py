"""Per-period statistics of the node's ticks, as diagnostic_updater would report them.

Plain Python and numpy (no rclpy import): the node feeds a :class:`Monitor` every tick and asks
it once per period for a level, a message and key/value strings, which it copies into a
diagnostic_msgs/DiagnosticStatus. Recording a tick is O(1) (one row written into a fixed ring
buffer); the medians and percentiles are computed once per period.

The node's lifecycle state comes into the report too (doc/lifecycle.md): a node that is not
active checks nothing, and its level says so, so that "not checking" never reads as "no
collisions".
"""
import numpy as np

# diagnostic_msgs/DiagnosticStatus levels (byte values of the message's constants).
OK, WARN, ERROR, STALE = 0, 1, 2, 3
LEVEL_NAMES = {OK: 'OK', WARN: 'WARN', ERROR: 'ERROR', STALE: 'STALE'}
# The node's status is named '<node name>: collision_check', as diagnostic_updater would.
STATUS_SUFFIX = ': collision_check'
STAGES = ('parse', 'broad', 'narrow', 'output', 'publish', 'total')
TOTAL = STAGES.index('total')
# Ticks kept per period for the median and p99; faster ticking reports them over the newest
# this many ticks (the max is exact over the whole period). 4096 covers 1 kHz for 4 s.
SAMPLES_PER_PERIOD = 4096
WORLD_KEYS = ('broad_phase', 'dynamic_bodies', 'static_bodies', 'still_bodies', 'compared',
              'candidate_pairs', 'filtered_pairs', 'sat_tests', 'colliding_pairs', 'near_pairs',
              'continuous', 'swept_pairs', 'unresolved_pairs')
# stats['continuous'] of a tick checked at its poses only although continuous is on.
DISCRETE_FALLBACK = 'discrete'
ACTIVE = 'active'  # the lifecycle state in which the node checks its inputs


class Monitor:
    """Counts and stage timings since the last report; totals since the start."""

    def __init__(self, start_s, samples=SAMPLES_PER_PERIOD):
        """Start counting at ``start_s`` (seconds on a monotonic clock)."""
        # Per tick, tuples in plain lists: a tick records without a numpy call (from a cold
        # cache, as at 100 Hz, three small numpy calls took ~10 µs); report() makes the array.
        self._times = [None] * samples  # ms, ring buffer of the period's ticks
        self._period_max = (0.0,) * len(STAGES)
        self._last = (0.0,) * len(STAGES)
        self._period_start = start_s
        self._ticks = 0             # this period
        self._received = 0          # this period: input messages that arrived
        self._dropped = 0           # this period
        self._rejected = 0          # this period
        self._dropped_total = 0     # since start
        self._rejected_total = 0    # since start
        self._rejected_since_valid = 0  # since the last valid input (or the start)
        self._last_rejection = ''   # since start
        self._last_valid_s = start_s
        self._world = dict.fromkeys(WORLD_KEYS, 0)
        self._world['broad_phase'] = ''
        self._world['continuous'] = 'off'
        self._discrete_ticks = 0  # since start: continuous ticks that fell back to discrete
        self._world['reused_result'] = False
        self._world['min_distance'] = ''       # m, signed, in the last tick ('' without pairs)
        self._world['min_distance_pair'] = ''  # as collision_monitor writes it: d3-s1
        self._phase_stats = {}  # the broad phase's own counters (octree leaves, sorts, ...)
        self._last_result = None  # the last tick's World result, not yet read into _world
        self._scene_version = 0
        self._static_ids = ''  # name:id of every static collider, in static_colliders order
        self._ignored = 0        # this period: inputs that came while the node was not active
        self._ignored_total = 0  # since start
        # The node's lifecycle state (a lifecycle_msgs/State label); a Monitor told nothing else
        # reports as the node checking its inputs.
        self._state = ACTIVE
        self._state_problem = ''      # why the node is not active, when that is a fault
        self._state_requests = 0      # this period: check_states requests answered
        self._states = 0              # this period: states they held
        self._state_request_ms = ''   # the last one's time
        self._robot = ''              # 'N joints, B boxes' of the robot model, '' without one
        self._box_links = ''          # index:link of every box, made once per model
        self._robot_refused = ''      # why the last robot model was refused
        self._missing_joints = []     # joints without a joint_states value yet
        self._trajectory_requests = 0     # this period: check_trajectory requests answered
        self._trajectory_request_ms = ''  # the last one's time

    def lifecycle(self, now_s, state, problem=''):
        """Record the node's lifecycle state at ``now_s``; ``problem``: why, when it is a fault.

        Becoming active starts the wait for a valid input afresh: a node that was paused has
        not been silent.
        """
        if state == ACTIVE and self._state != ACTIVE:
            self._last_valid_s = now_s
            self._rejected_since_valid = 0
        self._state, self._state_problem = state, problem

    def states_checked(self, states, ms):
        """Count a check_states request of ``states`` states, answered in ``ms``."""
        self._state_requests += 1
        self._states += states
        self._state_request_ms = ms

    def robot(self, joint_names, box_links):
        """Record a new robot model: its joints and each box's link (body i is box i)."""
        self._robot = '%d joints, %d boxes' % (len(joint_names), len(box_links))
        self._box_links = ' '.join('%d:%s' % item for item in enumerate(box_links))

    def robot_refused(self, reason):
        """Record why a robot model was refused (the one before stays), as a rejection too."""
        self._robot_refused = reason
        self.rejected(reason)

    def missing_joints(self, names):
        """Record the joints that have no joint_states value yet (WARN while there are any)."""
        self._missing_joints = list(names)

    def trajectory_checked(self, ms):
        """Count a check_trajectory request answered in ``ms``."""
        self._trajectory_requests += 1
        self._trajectory_request_ms = ms

    def ignored(self, count=1):
        """Count inputs that came while the node was not active: never checked, never answered."""
        self._ignored += count
        self._ignored_total += count

    def scene(self, version, colliders=None):
        """Record the static scene's version and, when given, its colliders' names and ids.

        ``colliders`` (with ``name`` and ``static_id``) only when the list changed: its text
        takes ~0.3 µs a collider.
        """
        self._scene_version = version
        if colliders is not None:
            self._static_ids = ' '.join('%s:%d' % (c.name, c.static_id) for c in colliders)

    def received(self):
        """Count an input message arriving (it sets the input period)."""
        self._received += 1

    def dropped(self, count=1):
        """Count inputs that were never processed."""
        self._dropped += count
        self._dropped_total += count

    def rejected(self, reason):
        """Count an input refused for ``reason`` (no collisions were published for it)."""
        self._rejected += 1
        self._rejected_total += 1
        self._rejected_since_valid += 1
        self._last_rejection = reason

    def tick(self, now_s, stage_ms, result):
        """Record a processed input: its stage times (ms, in STAGES order) and World result.

        ``result``: the World's Result (its ``continuous`` mode is read now, its ``stats``,
        which a small scene's step builds only when read, by the next report).
        """
        stage_ms = tuple(stage_ms)
        self._times[self._ticks % len(self._times)] = stage_ms
        self._last = stage_ms
        self._period_max = tuple(map(max, self._period_max, stage_ms))
        self._ticks += 1
        self._last_valid_s = now_s
        self._rejected_since_valid = 0
        self._discrete_ticks += str(result.continuous).startswith(DISCRETE_FALLBACK)
        self._last_result = result

    def _read_last_stats(self):
        """Take the World stats of the last tick, if one came since, into the report's values."""
        result, self._last_result = self._last_result, None
        if result is None:
            return
        world_stats = result.stats
        for key in WORLD_KEYS:
            self._world[key] = world_stats[key]
        self._world['reused_result'] = world_stats.get('reused', False)
        pair = world_stats.get('min_distance_pair')
        self._world['min_distance'] = '' if pair is None else \
            '%.6g' % world_stats['min_distance']
        self._world['min_distance_pair'] = '' if pair is None else pair_name(*pair)
        self._phase_stats = world_stats.get('broad_phase_stats', self._phase_stats)

    def report(self, now_s, input_timeout_s, tick_period_s=0.0):
        """Return (level, message, [(key, value)]) for the period ending now, then reset it.

        ``tick_period_s`` is the timer period when a timer ticks (0: ticks follow the inputs,
        whose period is measured from the inputs that arrived or were dropped on the way).
        ``input_timeout_s`` 0 disables the ERROR level. A node that is not active reports WARN
        (ERROR with a problem, e.g. a failed configure), whatever its inputs did.
        """
        elapsed = max(now_s - self._period_start, 1e-9)
        inputs = self._received + self._dropped
        input_period = tick_period_s or (elapsed / inputs if inputs else 0.0)
        self._read_last_stats()
        count = min(self._ticks, len(self._times))
        times = np.array(self._times[:count], np.float64)
        if count:  # 'higher': a reported percentile is always a time some tick really took
            median, p99 = np.percentile(times, (50.0, 99.0), axis=0, method='higher')
        else:
            median = p99 = np.zeros(len(STAGES))
        values = [(key, _text(value)) for key, value in self._world.items()]
        values += [('%s.%s' % (self._world['broad_phase'], key), _text(value))
                   for key, value in sorted(self._phase_stats.items())]
        for stage, name in enumerate(STAGES):
            values += [('%s_ms_last' % name, _ms(self._last[stage])),
                       ('%s_ms_median' % name, _ms(median[stage])),
                       ('%s_ms_p99' % name, _ms(p99[stage])),
                       ('%s_ms_max' % name, _ms(self._period_max[stage]))]
        values += [('scene_version', str(self._scene_version)),
                   ('static_ids', self._static_ids)]
        values += [('continuous_discrete_ticks', str(self._discrete_ticks)),
                   ('ticks', str(self._ticks)), ('rate_hz', '%.3f' % (self._ticks / elapsed)),
                   ('input_period_ms', _ms(1e3 * input_period)),
                   ('state_requests', str(self._state_requests)),
                   ('states_checked', str(self._states)),
                   ('state_request_ms', self._state_request_ms if self._state_request_ms == ''
                    else _ms(self._state_request_ms)),
                   ('trajectory_requests', str(self._trajectory_requests)),
                   ('trajectory_request_ms', self._trajectory_request_ms
                    if self._trajectory_request_ms == '' else _ms(self._trajectory_request_ms)),
                   ('robot', self._robot), ('box_links', self._box_links),
                   ('missing_joints', ' '.join(self._missing_joints)),
                   ('robot_refused', self._robot_refused),
                   ('lifecycle_state', self._state),
                   ('ignored_inputs', str(self._ignored_total)),
                   ('dropped_inputs', str(self._dropped_total)),
                   ('rejected_inputs', str(self._rejected_total)),
                   ('last_rejection', self._last_rejection)]

        silent_s = now_s - self._last_valid_s
        slowest_ms = self._period_max[TOTAL]
        if self._state != ACTIVE:
            level, message = ERROR if self._state_problem else WARN, \
                '%s: not checking collisions' % self._state
            if self._ignored:
                message += ', %d inputs ignored' % self._ignored
            if self._state_problem:
                message += '; ' + self._state_problem
        elif input_timeout_s > 0.0 and silent_s >= input_timeout_s:
            level, message = ERROR, 'no valid input for %.3g s' % silent_s
            if self._rejected_since_valid:  # inputs came, all bad: say why they were refused
                message += '; ' + self._rejections(self._rejected_since_valid)
            if self._missing_joints:
                message += '; ' + self._waiting_for_joints()
        elif self._rejected:
            level, message = WARN, self._rejections(self._rejected)
        elif self._missing_joints:
            level, message = WARN, self._waiting_for_joints()
        elif self._ticks and input_period and slowest_ms > 1e3 * input_period:
            level, message = WARN, 'a tick took %.3g ms, longer than the input period %.3g ms' \
                % (slowest_ms, 1e3 * input_period)
        else:
            level, message = OK, '%d ticks at %.1f Hz' % (self._ticks, self._ticks / elapsed)

        self._period_start = now_s
        self._ticks = self._received = self._dropped = self._rejected = self._ignored = 0
        self._state_requests = self._states = self._trajectory_requests = 0
        self._period_max = (0.0,) * len(STAGES)
        return level, message, values

    def _waiting_for_joints(self):
        return 'no answer until joint_states gives %s' % ', '.join(self._missing_joints)

    def _rejections(self, count):
        return '%d inputs rejected, last: %s' % (count, self._last_rejection)


def pair_name(id_a, type_a, id_b, type_b):
    """Name a pair as collision_monitor prints it: d3-s1 is dynamic body 3, static id 1."""
    return '%s%d-%s%d' % ('ds'[type_a], id_a, 'ds'[type_b], id_b)


def _ms(value):
    return '%.3f' % value


def _text(value):
    return str(value).lower() if isinstance(value, bool) else str(value)
