"""The node's parameters (doc/parameters.md): the table, their validation and declaration.

Validation is plain Python on plain values, so tests call it without ROS:

    params = parse({'frame_id': 'world', 'static_colliders': ['table'],
                    'table.pose': [0, 0, 0.4, 0, 0, 0, 1], 'table.half_extents': [0.6, 0.4, 0.02]})

:func:`declare` and :func:`read` are the rclpy side: the node declares every parameter with its
type when it is made, and reads them back through :func:`parse` at each lifecycle configure
(doc/lifecycle.md). Every problem raises :class:`ParameterError`, whose text names the parameter
and says what is wrong with it.

Each row of the table names the field it sets and the check of its value. The rules of a valid
box, margin, tolerance or broad phase are the pipeline's own (``obb.check_boxes``,
``obb.check_margin``, ``obb.check_tolerance``, the broad phases' checks): the checks here call
them and name the parameter in their errors, so the node refuses at a parameter exactly what the
World would refuse at a step. The rules between parameters (colliders named in ignored_pairs, a
file that replaces a list, the bodies of a check_states state) are in :func:`parse` and
:func:`run_time_change`.
"""
import math
import re
import reprlib
from typing import Callable, NamedTuple

import numpy as np

from collision_node.pipeline.broadphase import check_broad_phase, check_settings, NAMES, Settings
from collision_node.pipeline.contacts import DYNAMIC, STATIC
from collision_node.pipeline.continuous import CONTINUOUS_TOLERANCE
from collision_node.pipeline.filters import (ALL_CATEGORIES, collision_bits, DEFAULT_CATEGORY,
                                             MAX_ID)
from collision_node.pipeline.obb import (check_boxes, check_margin, check_tolerance, InvalidBox,
                                         InvalidDistance)

# Type names as in doc/parameters.md; declare() maps them to rclpy's Parameter.Type.
STRING, BOOL, INTEGER, DOUBLE = 'string', 'bool', 'integer', 'double'
DOUBLE_ARRAY, STRING_ARRAY, INTEGER_ARRAY = 'double[]', 'string[]', 'integer[]'
MAX_THREADS = 64  # far more than a collision check can use; a larger value is a typo
# Above this a timer mostly wakes the executor to find no new input; a faster pose source is
# better served by tick_rate_hz 0 (a tick on every input).
MAX_TICK_RATE_HZ = 1000.0
MAX_COUNT = 2**32 - 1  # a body count: the messages' uint32
POSE_SIZE = 7
IDENTITY_POSE = np.array([0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0])


class ParameterError(ValueError):
    """A parameter value the node cannot run with; ``name`` is the parameter's name."""

    def __init__(self, name, problem):
        super().__init__("parameter '%s': %s" % (name, problem))
        self.name = name
        self.problem = problem


# The checks of the table: check(parameter name, value of the table's type) returns the value
# of the parameter's field, or raises ParameterError naming the parameter.

def _as_given(name, value):
    """Return ``value``: the check of a parameter whose type is its only rule."""
    return value


def _frame_id(name, value):
    if not value or '\x00' in value:
        raise ParameterError(name, 'must name the frame of the poses (e.g. world), got %r'
                             % value)
    return value


def _in_range(low, high):
    """Return the check of a number in [low, high]."""
    def check(name, value):
        if not low <= value <= high:  # also refuses NaN
            raise ParameterError(name, 'must be in [%s, %s], got %r' % (low, high, value))
        return value
    return check


def _positive(name, value):
    if not 0.0 < value < math.inf:
        raise ParameterError(name, 'must be a positive number of seconds, got %r' % value)
    return value


def _margin(name, value):
    try:
        return check_margin(value)
    except InvalidDistance as error:
        raise ParameterError(name, error.problem) from None


def _tolerance(name, value):
    try:
        return check_tolerance(value)
    except InvalidDistance as error:
        raise ParameterError(name, error.problem) from None


def _bits(name, value):
    if not -2**63 <= value < 2**63:
        raise ParameterError(name, 'must be a 64-bit integer (bits; -1 sets all), got %r' % value)
    return value


def _bits_list(name, values):
    if not values:
        raise ParameterError(name, 'needs one value for every dynamic body, or one per body')
    return [_bits(name, value) for value in values]


def _pose(name, values):
    """Return ``values`` as a pose (7,): the pose of a valid box (obb.check_boxes)."""
    if values is None:
        raise ParameterError(name, 'missing; give x y z qx qy qz qw')
    if len(values) != POSE_SIZE:
        raise ParameterError(name, 'needs 7 values x y z qx qy qz qw, got %d' % len(values))
    pose = np.array(values, dtype=np.float64)
    try:
        check_boxes(pose.reshape(1, POSE_SIZE), np.zeros(3))
    except InvalidBox as error:
        raise ParameterError(name, '%s; x y z qx qy qz qw = %s' % (error.reason, list(values))) \
            from None
    return pose


def _collider_half_extents(name, values):
    if values is None:
        raise ParameterError(name, 'missing; give 3 half extents in metres')
    if len(values) != 3:
        raise ParameterError(name, 'needs 3 values, got %d' % len(values))
    return _checked_half_extents(name, np.array(values, dtype=np.float64))


def _dynamic_half_extents(name, values):
    if len(values) == 0 or len(values) % 3:
        raise ParameterError(name, 'needs 3 values (one size for all dynamic bodies) or 3 per '
                                   'body, got %d' % len(values))
    extents = np.array(values, dtype=np.float64)
    return _checked_half_extents(name, extents if len(extents) == 3 else extents.reshape(-1, 3))


def _checked_half_extents(name, extents):
    """Return ``extents``, (3,) or (N, 3), if they are sizes of valid boxes (obb.check_boxes)."""
    rows = extents.reshape(-1, 3)
    try:
        check_boxes(np.tile(IDENTITY_POSE, (len(rows), 1)), rows)
    except InvalidBox as error:
        where = 'row %d: ' % error.body if extents.ndim == 2 else ''
        raise ParameterError(name, '%s%s, got %s' % (where, error.reason,
                                                     rows[error.body].tolist())) from None
    return extents


def check_world_setting(name, value):
    """Return ``value`` unless the World would refuse it for the parameter ``name``.

    The broad phases' own checks, without building anything; their error becomes a
    ParameterError naming the parameter.
    """
    try:
        if name == 'broad_phase':
            check_broad_phase(value)
        else:
            check_settings(Settings(**{PARAMETERS[name].field: value}))
    except ValueError as error:
        raise ParameterError(name, str(error)) from None
    return value


class Spec(NamedTuple):
    """One row of the parameter table."""

    value_type: str
    default: object
    description: str
    run_time: bool = False  # may change while the node runs; others only while unconfigured
    field: str = ''  # the field of Parameters (Collider) it sets; '': read with another one
    check: Callable = _as_given  # check(name, value) -> the field's value, or ParameterError


PARAMETERS = {
    'frame_id': Spec(STRING, 'world', 'frame of all poses; inputs in another frame are rejected',
                     field='frame_id', check=_frame_id),
    'broad_phase': Spec(STRING, 'auto', 'one of: ' + ', '.join(NAMES), True,
                        'broad_phase', check_world_setting),
    'sphere_prefilter': Spec(BOOL, True, 'bounding-sphere test before the SAT', True,
                             'sphere_prefilter'),
    'octree.max_depth': Spec(INTEGER, 0, '0: chosen from the body count; else a fixed depth',
                             True, 'octree_max_depth', check_world_setting),
    'octree.leaf_cooldown_ticks': Spec(INTEGER, 15,
                                       'ticks an emptied leaf lives before it is dropped', True,
                                       'octree_leaf_cooldown_ticks', check_world_setting),
    'dynamic.half_extents': Spec(DOUBLE_ARRAY, [0.5, 0.5, 0.5],
                                 'm; 3 values for every dynamic body, or 3 per body',
                                 field='dynamic_half_extents', check=_dynamic_half_extents),
    # Its file replaces the list: parse() reads it into dynamic_half_extents.
    'dynamic.half_extents_file': Spec(
        STRING, '', '.npy file of (N, 3) or (3,) half extents in m; replaces '
                    'dynamic.half_extents'),
    'dynamic.collision_category': Spec(
        INTEGER_ARRAY, [DEFAULT_CATEGORY], 'bits; one for every dynamic body, or one per body',
        True, 'dynamic_collision_category', _bits_list),
    'dynamic.collision_mask': Spec(
        INTEGER_ARRAY, [ALL_CATEGORIES], 'bits (-1: all); one for every dynamic body, or one '
                                         'per body', True, 'dynamic_collision_mask', _bits_list),
    # The names and the scene file make the colliders together: parse(), _with_colliders().
    'static_colliders': Spec(STRING_ARRAY, [], 'names of the static boxes, each with a block '
                                               '<name>.pose, <name>.half_extents, <name>.enabled',
                             True),
    'static_scene_file': Spec(STRING, '', '.npz file of named static colliders, listed before '
                                          'those of static_colliders'),
    'margin': Spec(DOUBLE, 0.0, 'm; pairs whose exact distance is at most this are reported',
                   True, 'margin', _margin),
    'continuous': Spec(BOOL, False, 'check each body over its motion since the previous input, '
                                    'not only at its pose', True, 'continuous'),
    'continuous_tolerance': Spec(DOUBLE, CONTINUOUS_TOLERANCE,
                                 'm > 0; at a reported toi the boxes are within margin + this',
                                 True, 'continuous_tolerance', _tolerance),
    # Its entries must name colliders: checked with them, by parse() and run_time_change().
    'ignored_pairs': Spec(STRING_ARRAY, [], '"A B" entries, A and B each d<i> (dynamic body i) '
                                            'or a static collider name: never reported', True,
                          'ignored_pairs'),
    'tick_rate_hz': Spec(DOUBLE, 0.0, '0: check every input message; > 0: a timer checks the '
                                      'newest input at this rate',
                         field='tick_rate_hz', check=_in_range(0.0, MAX_TICK_RATE_HZ)),
    'input_timeout_s': Spec(DOUBLE, 1.0, 'no valid input for this long: ERROR diagnostic; '
                                         '0 disables',
                            field='input_timeout_s', check=_in_range(0.0, math.inf)),
    'max_bodies': Spec(INTEGER, 100000, 'inputs with more poses are rejected',
                       field='max_bodies', check=_in_range(1, MAX_COUNT)),
    # Its 0 means one body per size in dynamic.half_extents: parse() fills it in.
    'check_states.bodies': Spec(INTEGER, 0, 'bodies per state in a check_states request; 0: '
                                            'one per size in dynamic.half_extents (set it when '
                                            'one size is for all)',
                                field='state_bodies', check=_in_range(0, MAX_COUNT)),
    'robot_description': Spec(STRING, '', "URDF XML text of the robot; '': read the "
                                          'robot_description topic', field='robot_description'),
    'robot_description_semantic': Spec(STRING, '', "SRDF XML text of the robot; '': read the "
                                                   'robot_description_semantic topic',
                                       field='robot_description_semantic'),
    'robot_description_package_paths': Spec(
        STRING_ARRAY, [], 'folders searched for pkg/path when a package://pkg/path mesh is not '
                          'in the ament index', field='robot_package_paths'),
    'robot_base_pose': Spec(DOUBLE_ARRAY, [0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0],
                            "x y z qx qy qz qw of the robot's root link in frame_id",
                            field='robot_base_pose', check=_pose),
    'threads': Spec(INTEGER, 1, "threads for the box writes, the grid's pair search, the SAT and "
                                "the contacts: 1 keeps every tick on the executor's thread; 2+ "
                                "pay from ~10,000 bodies",
                    field='threads', check=_in_range(1, MAX_THREADS)),
    'diagnostic_updater.period': Spec(DOUBLE, 1.0, 's between /diagnostics messages',
                                      field='diagnostic_period_s', check=_positive),
    # Read by the node's constructor, not a field of Parameters.
    'autostart': Spec(BOOL, True, 'configure and activate at start; false: wait unconfigured for '
                                  'a lifecycle manager'),
}
# Read once, by the constructor: rclpy refuses every change (ParameterDescriptor.read_only).
READ_ONLY = frozenset({'autostart'})
START_ONLY_CONSTRAINT = 'start-only: set it while the node is unconfigured'
# <name>.<key>, each setting the Collider field of its key; pose and half_extents have no
# default: they must be given.
COLLIDER_PARAMETERS = {
    'pose': Spec(DOUBLE_ARRAY, None, 'x y z qx qy qz qw, in frame_id', True, 'pose', _pose),
    'half_extents': Spec(DOUBLE_ARRAY, None, 'm, 3 values', True, 'half_extents',
                         _collider_half_extents),
    'enabled': Spec(BOOL, True, 'a disabled collider is left out of the checks', True,
                    'enabled'),
    'margin': Spec(DOUBLE, 0.0, 'm; added to margin for pairs with this collider', True,
                   'margin', _margin),
    'collision_category': Spec(INTEGER, DEFAULT_CATEGORY, 'bits', True, 'collision_category',
                               _bits),
    'collision_mask': Spec(INTEGER, ALL_CATEGORIES, 'bits (-1: all)', True, 'collision_mask',
                           _bits),
}
# A collider name becomes the first part of parameter names, so it must be a plain identifier
# and must not collide with the node's own parameter groups.
COLLIDER_NAME = re.compile(r'[A-Za-z][A-Za-z0-9_]*\Z')
DYNAMIC_BODY = re.compile(r'd(-?[0-9]+)\Z')  # d<i> in ignored_pairs; no collider is named so
RCLPY_PARAMETER_GROUPS = frozenset({'qos_overrides', 'use_sim_time',
                                    'start_type_description_service'})
RESERVED_NAMES = frozenset(name.split('.')[0] for name in PARAMETERS) | RCLPY_PARAMETER_GROUPS
GIVEN_TYPE = re.compile(r"of type '(\w+)', expecting")  # in rclpy's InvalidParameterTypeException


class Collider(NamedTuple):
    """A static box from the parameters or the scene file.

    ``static_id`` is its id in the `collisions` cloud: its index in the list at start, the next
    unused id for a collider added later; it never changes while the collider exists and is
    never given to another one (doc/design.md, "The collisions cloud").
    """

    name: str
    pose: np.ndarray          # (7,) x y z qx qy qz qw
    half_extents: np.ndarray  # (3,)
    enabled: bool
    margin: float = 0.0
    collision_category: int = DEFAULT_CATEGORY
    collision_mask: int = ALL_CATEGORIES
    static_id: int = -1


class Parameters(NamedTuple):
    """All parameters of the node, validated."""

    frame_id: str
    broad_phase: str
    sphere_prefilter: bool
    octree_max_depth: int
    octree_leaf_cooldown_ticks: int
    dynamic_half_extents: np.ndarray  # (3,) for every body, or (N, 3) one row per body
    dynamic_collision_category: list  # one for every body, or one per body
    dynamic_collision_mask: list
    colliders: tuple                  # of Collider, in the order of static_colliders
    margin: float
    continuous: bool
    continuous_tolerance: float
    ignored_pairs: list               # the entries as given ("A B" strings)
    tick_rate_hz: float
    input_timeout_s: float
    max_bodies: int
    state_bodies: int                 # bodies per check_states state (0: not known)
    robot_description: str            # URDF text ('': from the topic)
    robot_description_semantic: str   # SRDF text ('': from the topic)
    robot_package_paths: list         # folders for package:// meshes
    robot_base_pose: np.ndarray       # (7,)
    threads: int
    diagnostic_period_s: float
    next_static_id: int = 0  # the id of the next collider added at run time

    def filters(self):
        """World.set_filters's arguments: dynamic categories and masks, ignored pair rows."""
        return (self.dynamic_collision_category, self.dynamic_collision_mask,
                ignored_pair_rows(self.ignored_pairs, [c.name for c in self.colliders],
                                  [c.static_id for c in self.colliders]))


def parse(values):
    """Validate parameter values (a mapping name -> value; missing or None: default).

    Returns :class:`Parameters`; raises ParameterError naming the first bad parameter.
    """
    def get(name, spec):
        value = values.get(name)
        return spec.default if value is None else value

    read = {name: _checked(name, spec.value_type, get(name, spec))
            for name, spec in PARAMETERS.items()}
    fields = {spec.field: spec.check(name, read[name])
              for name, spec in PARAMETERS.items() if spec.field}
    colliders = load_static_scene(read['static_scene_file']) if read['static_scene_file'] \
        else []
    names = [c.name for c in colliders] + read['static_colliders']
    _check_collider_names(names)
    for name in read['static_colliders']:
        colliders.append(_collider(name, lambda key, spec: get('%s.%s' % (name, key), spec),
                                   len(colliders)))
    ignored_pair_rows(read['ignored_pairs'], names)  # refuses a malformed entry
    if read['dynamic.half_extents_file']:
        fields['dynamic_half_extents'] = load_half_extents(read['dynamic.half_extents_file'])
    fields['state_bodies'] = _state_bodies(fields['state_bodies'],
                                           fields['dynamic_half_extents'])
    return Parameters(colliders=tuple(colliders), next_static_id=len(colliders), **fields)


def _state_bodies(value, dynamic_half_extents):
    """Return the bodies of a check_states state: ``value``, else one per dynamic size."""
    sizes = len(dynamic_half_extents) if dynamic_half_extents.ndim == 2 else 0
    if value and sizes and value != sizes:
        raise ParameterError('check_states.bodies', '%d bodies, but dynamic.half_extents sizes %d'
                             % (value, sizes))
    return value or sizes


def _collider(name, value_of, static_id):
    """Return the Collider ``name`` with id ``static_id``; ``value_of(key, spec)`` reads its block.

    Raises ParameterError naming the first invalid value (a missing pose or size included).
    """
    fields = {}
    for key, spec in COLLIDER_PARAMETERS.items():
        parameter = '%s.%s' % (name, key)
        value = value_of(key, spec)  # a missing pose or size stays None: its check says so
        fields[spec.field] = spec.check(
            parameter, None if value is None else _checked(parameter, spec.value_type, value))
    return Collider(name, static_id=static_id, **fields)


def run_time_change(parameters, name, value, block_value=None):
    """Return ``parameters`` with one run-time parameter changed; ParameterError if refused.

    Only the parameters marked run-time in the table can change; the node's wiring is fixed at
    start. A collider's block may be set before its name is in ``static_colliders`` (it is
    checked, then used when the name is added); a name added to ``static_colliders`` takes its
    block from ``block_value(parameter name)`` (None: not set). Names of rclpy's own
    parameters leave ``parameters`` as they are; other unknown names are refused.
    """
    collider, _, key = name.rpartition('.')
    if key in COLLIDER_PARAMETERS and collider and name not in PARAMETERS:
        spec = COLLIDER_PARAMETERS[key]
        value = spec.check(name, _checked(name, spec.value_type, value))
        names = [c.name for c in parameters.colliders]
        if collider not in names:  # a block for a collider yet to be added
            _check_collider_names([collider])
            return parameters
        index = names.index(collider)
        colliders = list(parameters.colliders)
        colliders[index] = colliders[index]._replace(**{spec.field: value})
        return parameters._replace(colliders=tuple(colliders))
    spec = PARAMETERS.get(name)
    if spec is None:
        if name.split('.')[0] in RCLPY_PARAMETER_GROUPS:
            return parameters  # rclpy's business
        raise ParameterError(name, 'undeclared: collision_node has no such parameter')
    if not spec.run_time:
        raise ParameterError(name, 'fixed at start, read-only while configured: set it while the '
                                   'node is unconfigured (lifecycle cleanup), or restart it')
    if not spec.field:  # static_colliders: the names make the colliders, with their blocks
        return _with_colliders(parameters, _checked(name, STRING_ARRAY, value),
                               block_value or (lambda _: None))
    changed = parameters._replace(**{
        spec.field: spec.check(name, _checked(name, spec.value_type, value))})
    if changed.ignored_pairs is not parameters.ignored_pairs:  # new entries name colliders
        ignored_pair_rows(changed.ignored_pairs, [c.name for c in parameters.colliders])
    return changed


def _with_colliders(parameters, names, block_value):
    """Return ``parameters`` with the colliders ``names``: kept ones as they are, new ones read.

    A new name takes the next unused id and its block from ``block_value``.
    """
    _check_collider_names(names)
    kept = {c.name: c for c in parameters.colliders}
    colliders = []
    next_id = parameters.next_static_id
    for name in names:
        if name in kept:
            colliders.append(kept[name])
            continue

        def value_of(key, spec, name=name):
            value = block_value('%s.%s' % (name, key))
            return spec.default if value is None else value
        colliders.append(_collider(name, value_of, next_id))
        next_id += 1
    return parameters._replace(colliders=tuple(colliders), next_static_id=next_id)


def check_run_time(parameters):
    """Raise ParameterError unless the parameters after a set of run-time changes fit together.

    ``ignored_pairs`` must name colliders that are (still) in ``static_colliders``.
    """
    try:
        ignored_pair_rows(parameters.ignored_pairs, [c.name for c in parameters.colliders])
    except ParameterError as error:
        raise ParameterError('static_colliders', '%s (remove it from ignored_pairs in the '
                                                 'same call)' % error) from None


def ignored_pair_rows(entries, collider_names, collider_ids=None):
    """Return ``ignored_pairs`` entries as World rows (id_a, type_a, id_b, type_b).

    Each entry is ``"A B"``, A and B each ``d<i>`` (dynamic body i) or a name in
    ``collider_names``, whose id is the same entry of ``collider_ids`` (default: its list
    index). Raises ParameterError naming the entry.
    """
    ids = dict(zip(collider_names, range(len(collider_names)) if collider_ids is None
                   else collider_ids))
    rows = []
    for entry in entries:
        words = entry.split()
        if len(words) != 2:
            raise ParameterError('ignored_pairs', 'entry %r must be two bodies "A B", each '
                                                  'd<i> or a static collider name' % entry)
        row = []
        for word in words:
            dynamic = DYNAMIC_BODY.match(word)
            if dynamic:
                index = int(dynamic.group(1))
                if not 0 <= index <= MAX_ID:
                    raise ParameterError('ignored_pairs', 'entry %r: dynamic index %d must be '
                                                          'in [0, %d]' % (entry, index, MAX_ID))
                row += [index, DYNAMIC]
            elif word in ids:
                row += [ids[word], STATIC]
            else:
                raise ParameterError('ignored_pairs', 'entry %r: %r is neither d<i> nor a name '
                                                      'in static_colliders' % (entry, word))
        rows.append(row)
    return np.array(rows, dtype=np.int64).reshape(-1, 4)


def declare(node):
    """Declare every parameter on ``node`` with its type; return the declaration errors.

    Called once, when the node is made: the parameters exist from then on, so that a lifecycle
    manager may set them before configure. A value of the wrong type (from a params file or an
    override) cannot be declared; its parameter is declared at its default instead and the
    error is returned, {name: ParameterError} in declaration order, for :func:`read` to report
    at configure, unless a value of the right type is set before. Only ``autostart`` is
    read-only for rclpy; the start-only parameters are refused by the node while it is
    configured (:func:`run_time_change`).
    """
    errors = {}
    for name, spec in PARAMETERS.items():
        _declare_one(node, name, spec, errors)
    names = node.get_parameter_or('static_colliders').value or []
    try:
        names = _checked('static_colliders', STRING_ARRAY, names)
        _check_collider_names(names)
    except ParameterError:
        return errors  # read() says why; blocks come with the names that are valid
    _declare_blocks(node, names, errors)
    return errors


def read(node, errors):
    """Return the node's parameters as set now, parsed; ParameterError names the first bad one.

    Called at each configure. ``errors`` are :func:`declare`'s, less those fixed since (a name
    set again with the right type): the first one that still matters is raised. A collider
    block that was never declared (a name added to ``static_colliders`` while unconfigured) is
    declared now, taking its value from the params file when it has one.
    """
    from rclpy.parameter import Parameter

    for name in PARAMETERS:  # in the order a node that declares and reads at once meets them
        if name in errors:
            raise errors[name]
    names = _checked('static_colliders', STRING_ARRAY,
                     node.get_parameter_or('static_colliders').value or [])
    _check_collider_names(names)
    _declare_blocks(node, names, errors)
    blocks = ['%s.%s' % (collider, key) for collider in names for key in COLLIDER_PARAMETERS]
    for name in blocks:
        if name in errors:
            raise errors[name]
    values = {name: _value(node, name) for name in list(PARAMETERS) + blocks}
    # rclpy keeps the values of the params files and overrides in this attribute; a name the
    # node never declares stays there unread.
    unknown = unknown_parameters(getattr(node, '_parameter_overrides', {}), names)
    if unknown:
        node.get_logger().warn(
            'ignored %d parameter(s) collision_node does not have (a typo, or a collider '
            'missing from static_colliders?): %s' % (len(unknown), reprlib.repr(unknown)))
    parsed = parse(values)
    if len(parsed.colliders) > len(names):  # the scene file's come first: list them all
        node.set_parameters([Parameter('static_colliders',
                                       value=[c.name for c in parsed.colliders])])
    return parsed


def check_unconfigured(name, value):
    """Raise ParameterError unless ``name`` may be set to ``value`` while the node is unconfigured.

    A name the node has (a collider's block for any valid name included) and a value of its
    type: the values are checked together at configure, by :func:`read`.
    """
    collider, _, key = name.rpartition('.')
    if name in PARAMETERS:
        _checked(name, PARAMETERS[name].value_type, value)
    elif key in COLLIDER_PARAMETERS and collider:
        _check_collider_names([collider])
        _checked(name, COLLIDER_PARAMETERS[key].value_type, value)
    elif name.split('.')[0] not in RCLPY_PARAMETER_GROUPS:
        raise ParameterError(name, 'undeclared: collision_node has no such parameter')


def diagnostic_period_s(value):
    """Return ``value`` if it is a valid ``diagnostic_updater.period``, else its default.

    The diagnostics run from the node's start, before configure checks the parameters.
    """
    try:
        return _positive('diagnostic_updater.period',
                         _checked('diagnostic_updater.period', DOUBLE, value))
    except ParameterError:
        return PARAMETERS['diagnostic_updater.period'].default


def _declare_blocks(node, names, errors):
    """Declare the blocks of the colliders ``names`` not declared yet (nav2's pattern)."""
    for collider in names:
        for key, spec in COLLIDER_PARAMETERS.items():
            name = '%s.%s' % (collider, key)
            if not node.has_parameter(name):
                _declare_one(node, name, spec, errors)


def _declare_one(node, name, spec, errors):
    """Declare one parameter; a value of the wrong type goes to ``errors``, the default stays."""
    from rcl_interfaces.msg import ParameterDescriptor
    from rclpy.exceptions import InvalidParameterTypeException
    from rclpy.parameter import Parameter

    types = {STRING: Parameter.Type.STRING, BOOL: Parameter.Type.BOOL,
             INTEGER: Parameter.Type.INTEGER, DOUBLE: Parameter.Type.DOUBLE,
             DOUBLE_ARRAY: Parameter.Type.DOUBLE_ARRAY,
             STRING_ARRAY: Parameter.Type.STRING_ARRAY,
             INTEGER_ARRAY: Parameter.Type.INTEGER_ARRAY}
    start_only = not spec.run_time and name not in READ_ONLY
    descriptor = ParameterDescriptor(
        description=spec.description, read_only=name in READ_ONLY,
        additional_constraints=START_ONLY_CONSTRAINT if start_only else '')
    # An empty list has no type in rclpy (a [] default reads as a byte array, an empty YAML
    # list arrives NOT_SET), so a parameter whose default is missing or empty is declared by
    # type alone and reads None until given; parse() then applies the table's default.
    default = spec.default if spec.default not in (None, []) else types[spec.value_type]
    try:
        node.declare_parameter(name, default, descriptor)
    except InvalidParameterTypeException as error:
        # rclpy's text repeats the whole value (thousands of numbers for 3 x N extents):
        # keep only the type it found.
        given = GIVEN_TYPE.search(str(error))
        found = given.group(1).lower() if given else str(error)[:200]
        hint = ' (write 1.0, not 1)' \
            if spec.value_type.startswith(DOUBLE) and found == 'integer' else ''
        errors[name] = ParameterError(name, 'must be of type %s%s, got %s'
                                      % (spec.value_type, hint, found))
        node.declare_parameter(name, default, descriptor, ignore_override=True)


def _value(node, name):
    """Return a parameter's value as plain Python; None when it is not set."""
    value = node.get_parameter_or(name).value
    return None if value is None else _plain(value)


def unknown_parameters(given, collider_names):
    """Return the names in ``given`` that the node does not read, sorted.

    A misspelt name would otherwise leave its parameter at the default without a word (e.g.
    ``dynamic.half_extent`` and every body 1 m wide). Names rclpy reads itself are known.
    """
    known = set(PARAMETERS) | {'%s.%s' % (collider, key) for collider in collider_names
                               for key in COLLIDER_PARAMETERS}
    return sorted(name for name in given if name not in known
                  and name.split('.')[0] not in RCLPY_PARAMETER_GROUPS)


def _plain(value):
    """Turn the array.array or numpy arrays of rclpy into lists."""
    return value if isinstance(value, (str, bool, int, float)) else list(value)


def _checked(name, type_name, value):
    """Check ``value`` against a table type; int is accepted where a double is expected."""
    def is_number(item):
        return isinstance(item, (int, float, np.integer, np.floating)) \
            and not isinstance(item, (bool, np.bool_))

    if type_name == STRING and isinstance(value, str):
        return value
    if type_name == BOOL and isinstance(value, (bool, np.bool_)):
        return bool(value)
    if type_name == INTEGER and is_number(value) and float(value).is_integer():
        return int(value)
    if type_name == DOUBLE and is_number(value):
        return float(value)
    if not isinstance(value, (str, bytes, dict)):
        try:
            items = list(value)
        except TypeError:
            items = None
        if type_name == STRING_ARRAY and items is not None \
                and all(isinstance(item, str) for item in items):
            return items
        if type_name == DOUBLE_ARRAY and items is not None and all(map(is_number, items)):
            return [float(item) for item in items]
        if type_name == INTEGER_ARRAY and items is not None and all(
                is_number(item) and float(item).is_integer() for item in items):
            return [int(item) for item in items]
    raise ParameterError(name, 'must be of type %s, got %s' % (type_name, reprlib.repr(value)))


def load_half_extents(path):
    """Read ``dynamic.half_extents_file``: a .npy array of shape (N, 3) or (3,), in metres.

    Returns it as float64 ((3,) for one size for all); raises ParameterError naming the
    parameter and what is wrong.
    """
    name = 'dynamic.half_extents_file'
    extents = _load(name, path)
    if extents.dtype.kind not in 'fiu' or extents.shape != (3,) and (
            extents.ndim != 2 or extents.shape[1] != 3 or not len(extents)):
        raise ParameterError(name, "'%s' must hold a float array of shape (N, 3) or (3,) "
                                   '(half extents in m), got %s of shape %s'
                             % (path, extents.dtype, extents.shape))
    return _checked_half_extents(name, extents.astype(np.float64))


SCENE_ARRAYS = {  # key in the .npz file: (dtype kinds, shape after N, required, default)
    'names': ('U', (), True, None),
    'poses': ('fiu', (POSE_SIZE,), True, None),
    'half_extents': ('fiu', (3,), True, None),
    'enabled': ('b', (), False, True),
    'margins': ('fiu', (), False, 0.0),
    'collision_categories': ('iu', (), False, DEFAULT_CATEGORY),
    'collision_masks': ('iu', (), False, ALL_CATEGORIES),
}


def load_static_scene(path):
    """Read ``static_scene_file``: named static colliders in a .npz file (numpy.savez).

    Arrays, N colliders: ``names`` (N,) str, ``poses`` (N, 7) x y z qx qy qz qw in frame_id,
    ``half_extents`` (N, 3) in m; optional ``enabled`` (N,) bool, ``margins`` (N,) m,
    ``collision_categories`` and ``collision_masks`` (N,) int64. Returns their Colliders, ids
    0..N-1; raises ParameterError naming the parameter, the array and the first bad collider.
    """
    name = 'static_scene_file'
    with _load(name, path) as archive:
        unknown = sorted(set(archive.files) - set(SCENE_ARRAYS))
        if unknown:
            raise ParameterError(name, "'%s' has arrays %s; known: %s"
                                 % (path, unknown, ', '.join(SCENE_ARRAYS)))
        arrays = {}
        for key, (kinds, shape, required, default) in SCENE_ARRAYS.items():
            if key not in archive.files:
                if required:
                    raise ParameterError(name, "'%s' has no array '%s'" % (path, key))
                continue
            array = archive[key]
            count = len(arrays['names']) if arrays else len(array)
            if array.dtype.kind not in kinds or array.shape != (count,) + shape:
                raise ParameterError(name, "'%s': %s must be %s of shape %s, got %s of shape %s"
                                     % (path, key, _KIND_NAMES[kinds[0]], (count,) + shape,
                                        array.dtype, array.shape))
            arrays[key] = array
    names = arrays['names'].tolist()

    try:
        _check_collider_names(names)
    except ParameterError as error:
        raise ParameterError(name, "'%s': names: %s" % (path, error.problem)) from None
    # Whole arrays, 10,000 rows and more, checked at once by the pipeline's own checks.
    poses = arrays['poses'].astype(np.float64)
    extents = arrays['half_extents'].astype(np.float64)
    count = len(names)
    margins = arrays.get('margins', np.zeros(count)).astype(np.float64)
    try:
        check_boxes(poses, extents)
    except InvalidBox as error:
        raise ParameterError(name, "'%s': %s (row %d): %s" % (
            path, names[error.body], error.body, error.reason)) from None
    try:
        check_margin(margins)
    except InvalidDistance as error:
        raise ParameterError(name, "'%s': %s (row %d) margin %s" % (
            path, names[error.index], error.index, error.problem)) from None
    enabled = arrays.get('enabled', np.ones(count, np.bool_))
    bits = {key: collision_bits(key, arrays.get(key, default))
            for key, default in (('collision_categories', DEFAULT_CATEGORY),
                                 ('collision_masks', ALL_CATEGORIES))}
    categories = np.broadcast_to(bits['collision_categories'], (count,))
    masks = np.broadcast_to(bits['collision_masks'], (count,))
    return [Collider(names[i], poses[i], extents[i], bool(enabled[i]), float(margins[i]),
                     int(categories[i]), int(masks[i]), i) for i in range(count)]


_KIND_NAMES = {'U': 'strings', 'f': 'numbers', 'i': 'integers', 'b': 'booleans'}


def _load(name, path):
    try:
        return np.load(path, allow_pickle=False)
    except (OSError, ValueError, EOFError) as error:  # missing, unreadable, not numpy, pickled
        raise ParameterError(name, "cannot read '%s': %s" % (path, error)) from None


def _check_collider_names(names):
    seen = set()
    for name in names:
        if not COLLIDER_NAME.match(name):
            raise ParameterError('static_colliders', 'name %r must start with a letter and hold '
                                                     'only letters, digits and _' % name)
        if DYNAMIC_BODY.match(name):
            raise ParameterError('static_colliders', 'name %r is how ignored_pairs names a '
                                                     'dynamic body; choose another' % name)
        if name in RESERVED_NAMES:
            raise ParameterError('static_colliders', "name %r is taken by the node's own "
                                                     'parameters; choose another' % name)
        if name in seen:
            raise ParameterError('static_colliders', 'name %r appears twice' % name)
        seen.add(name)
