"""The robot_model section of collision_bench: the Panda from its URDF, ours against two peers.

The Panda of example-robot-data (URDF and SRDF, its meshes as boxes: 17 boxes on 13 links, 8
joints, the second finger a mimic of the first) stands on a table, a wall in front of it
and a shelf beside it (STATIC_NAMES). Its self-collision filter (same link, adjacent links,
the SRDF's pairs) leaves 44 box pairs, and 17 x 3 robot-static pairs are tested. Per random
joint state within the limits (seeded, about a third of them colliding) every method answers
"which pairs collide", from q:

* ours, one state per call: ``World.set_robot(robot)``, then ``World.check_joints(q)`` with
  q (dof,), forward kinematics included;
* ours, K states per call: ``World.check_joints(q)`` with q (K, dof), timed per call / K;
* the same on ``World(threads=os.cpu_count())``: the K states in chunks over the cores;
* MuJoCo: an MJCF model of the same tree (:func:`mujoco_model`: a body per link at its URDF
  joint origin, a hinge or slide joint on its URDF axis, the boxes as geoms at their poses in
  their links, the static boxes as world geoms, ``<exclude>`` for every filtered link pair);
  per state ``qpos`` set (the mimic finger's entry too, from the same affine map our model
  uses), ``mj_kinematics`` + ``mj_collision``. Twice, as the robot section: the boxes as
  8-vertex convex meshes, and as box geoms;
* pinocchio + coal: ``pin.buildModelFromUrdf(urdf, mimic=True)`` (its q is ours), a
  GeometryModel of ``coal.Box`` es placed at our boxes' poses in their link frames, the
  allowed pairs and every robot-static pair as collision pairs,
  ``pin.computeCollisions(model, data, geometry_model, geometry_data, q, False)`` per state.
  Its placements are checked against our forward kinematics before it is timed.

The methods take turns in rounds (robot.py), each round on new random states; every state's
set of pairs is compared with our one-state answers (robot.compare).

The trajectory check. A smooth 100-waypoint path, checked free at SAMPLES_PER_SEGMENT
states a segment: ``World.check_trajectory(waypoints)`` against ``World.check_joints
(waypoints)`` alone, in the same rounds, the two taking turns call by call
(_time_path). And its false alarms: on random short segments (every joint moved by up to
SHORT_SEGMENT_RAD, a finger by up to SHORT_SEGMENT_M), the (segment, pair) reports that a
referee sampling REFEREE_SAMPLES states of the segment (its ends included) finds never
colliding.

MuJoCo, pinocchio and coal are optional (the ``bench`` extra), and example-robot-data too
(the ``test`` extra): one missing is reported as not installed and skipped.
"""
import contextlib
import os
import sysconfig
import time

import numpy as np

from collision_node.benchmarks import robot
from collision_node.benchmarks.robot import (
    _library, answers_text, contact_keys, Method, pair_key, rotation, Unavailable)
from collision_node.pipeline import urdf
from collision_node.pipeline.robot import pose_from, Robot
from collision_node.pipeline.sat import signed_distance
from collision_node.pipeline.world import DYNAMIC, STATIC, World

# The scene: x y z qx qy qz qw and half extents (m), the Panda's root at the origin.
STATIC_NAMES = ('table', 'wall', 'shelf')
STATIC_POSES = np.array([[0.0, 0.0, -0.06, 0.0, 0.0, 0.0, 1.0],     # its top 1 cm below the base
                         [0.65, 0.0, 0.5, 0.0, 0.0, 0.0, 1.0],      # in front, within reach
                         [0.0, 0.55, 0.45, 0.0, 0.0, 0.1305262, 0.9914449]])  # turned 15 deg
STATIC_HALF_EXTENTS = np.array([[1.0, 1.0, 0.05], [0.05, 0.6, 0.5], [0.25, 0.12, 0.02]])

PANDA_URDF = ('robots', 'panda_description', 'urdf', 'panda.urdf')
PANDA_SRDF = ('robots', 'panda_description', 'srdf', 'panda.srdf')
PANDA_HINT = ('example-robot-data not installed (test and benchmark dependency: pip install '
              'example-robot-data)')
PIN_HINT = 'pinocchio not installed (benchmark-only dependency: pip install pin)'

TRAJECTORY_WAYPOINTS = 100
SAMPLES_PER_SEGMENT = 50     # the free path is checked at this many states a segment
REFEREE_SAMPLES = 200        # states per short segment for the false-alarm referee
SHORT_SEGMENT_RAD = 0.1      # a random short segment moves each joint by up to this (rad)
SHORT_SEGMENT_M = 0.005      # ... and a finger by up to this (m)
TRAJECTORY_REPEATS = 5       # timed calls of each trajectory check per round
PATH_TRIES = 200             # random smooth paths tried for a free one

OURS_JOINTS = 'collision_node World.check_joints, one state'
OURS_BATCH = 'collision_node World.check_joints, K states'
OURS_EVERY_CORE = 'collision_node World.check_joints, K states, a thread a core'
PIN_COAL = 'pinocchio + coal'
MUJOCO_MESH = robot.MUJOCO_MESH
MUJOCO_BOX = robot.MUJOCO_BOX
TRAJECTORY = 'collision_node World.check_trajectory'
WAYPOINTS = 'collision_node World.check_joints, the waypoints alone'
FALSE_ALARMS = 'check_trajectory on random short segments'


# --- the scene -----------------------------------------------------------------------------


def panda_files():
    """Return (ament prefix, URDF path, SRDF path) of example-robot-data's Panda."""
    prefix = os.path.join(sysconfig.get_paths()['purelib'], 'cmeel.prefix')
    share = os.path.join(prefix, 'share', 'example-robot-data')
    paths = os.path.join(share, *PANDA_URDF), os.path.join(share, *PANDA_SRDF)
    if not all(os.path.exists(path) for path in paths):
        raise Unavailable(PANDA_HINT)
    return (prefix,) + paths


@contextlib.contextmanager
def _ament_prefix(prefix):
    """Put ``prefix`` first on AMENT_PREFIX_PATH (its package:// URIs resolve), then restore."""
    previous = os.environ.get('AMENT_PREFIX_PATH')
    os.environ['AMENT_PREFIX_PATH'] = os.pathsep.join(filter(None, (prefix, previous)))
    try:
        yield
    finally:
        if previous is None:
            del os.environ['AMENT_PREFIX_PATH']
        else:
            os.environ['AMENT_PREFIX_PATH'] = previous


def load_panda():
    """Return the Panda as a Robot (its meshes as boxes, its SRDF's filter)."""
    prefix, urdf_path, srdf_path = panda_files()
    with _ament_prefix(prefix):
        return Robot.from_urdf(urdf_path, srdf_path)


def panda_world(panda, threads=1):
    """Return a default World (but ``threads``) with the static boxes and the Panda at 0."""
    world = World(threads=threads)
    world.set_static(STATIC_POSES, STATIC_HALF_EXTENTS)
    world.set_robot(panda)
    return world


def random_states(panda, count, rng):
    """Return (count, dof) joint states drawn uniformly within the limits."""
    limits = panda.joint_limits
    return rng.uniform(limits[:, 0], limits[:, 1], (count, panda.dof))


def joint_values(panda, urdf_path):
    """Return {URDF joint name: (q index, multiplier, offset)} of every moving joint.

    A joint's value is multiplier * q[q index] + offset (a mimic joint follows its driver).
    """
    model = panda.model
    found = {}
    for joint in urdf.read_urdf(urdf_path).joints:
        row = panda.link_names.index(joint.child)
        if model.q_indices[row] >= 0:
            found[joint.name] = (int(model.q_indices[row]), float(model.multipliers[row]),
                                 float(model.offsets[row]))
    return found


def _distance(panda):
    """Return distance(q, key): the exact signed distance of a pair at joint state q."""
    def distance(q, key):
        poses = panda.box_poses(q)
        id_a, type_b, id_b = key
        pose_b, half_b = ((STATIC_POSES[id_b], STATIC_HALF_EXTENTS[id_b]) if type_b == STATIC
                          else (poses[id_b], panda.half_extents[id_b]))
        pose_a = poses[id_a]
        return signed_distance(pose_a[:3], rotation(pose_a[3:]), panda.half_extents[id_a],
                               pose_b[:3], rotation(pose_b[3:]), half_b).distance
    return distance


# --- the methods ---------------------------------------------------------------------------


class OursJoints(Method):
    name = OURS_JOINTS
    setup = ('a default World, the static boxes by `set_static`, the Panda by '
             '`set_robot(robot)`; one `World.check_joints(q)` per state, q of shape (dof,): '
             'forward kinematics included')

    def __init__(self, panda):
        self.world = panda_world(panda)

    def call(self, states, k):
        return self.world.check_joints(states[k]).contacts

    def answer(self, raw):
        return contact_keys(raw)


class OursBatch(robot.OursBatch):
    name = OURS_BATCH
    setup = 'a World set up alike, `World.check_joints(q)` with q (K, dof); per state = call / K'

    def __init__(self, panda):
        self.world = panda_world(panda)

    def call(self, states):
        return self.world.check_joints(states)


class OursEveryCore(OursBatch):
    name = OURS_EVERY_CORE
    setup = ('the same on a World(threads=os.cpu_count()): the states in chunks over the '
             'calling thread and pooled helpers')

    def __init__(self, panda):
        self.world = panda_world(panda, threads=os.cpu_count())


def mujoco_model(mujoco, panda, urdf_path, meshes):
    """Return (model, geom id -> (type, id), qpos map) of the Panda's scene in MuJoCo.

    One body per link, at its URDF joint origin in its parent's body; a moving joint is a
    hinge or slide on its URDF axis (in the joint's frame, which is the child body's frame);
    a fixed joint is none, so the body is welded to its parent. Each box is a geom at its pose
    in its link (a box geom, or an 8-vertex mesh of its corners), each static box a world
    geom. Link pairs our filter drops are ``<exclude>`` d (MuJoCo never pairs geoms of one
    body, and never two static ones: the root link is welded to the world, so its pairs with
    the static boxes are not tested; they are free in every state here, and the answers are
    compared). The qpos map (M, c): qpos = M q + c, with the mimic finger's entry.
    """
    model = panda.model
    values = joint_values(panda, urdf_path)
    names = {joint.child: joint.name for joint in urdf.read_urdf(urdf_path).joints}
    corners = np.array([[x, y, z] for x in (-1.0, 1.0) for y in (-1.0, 1.0)
                        for z in (-1.0, 1.0)])

    def numbers(values):
        return ' '.join('%.17g' % value for value in np.ravel(values))

    def placed(rotation_matrix, translation):
        pose = pose_from(np.asarray(rotation_matrix, np.float64),
                         np.asarray(translation, np.float64))
        return 'pos="%s" quat="%s"' % (numbers(pose[:3]), numbers(pose[[6, 3, 4, 5]]))

    def shape(name, half):
        if meshes:
            return 'type="mesh" mesh="%s"' % name
        return 'type="box" size="%s"' % numbers(half)

    box_names = ['box%d' % b for b in range(len(panda.half_extents))]
    static_names = ['static%d' % s for s in range(len(STATIC_NAMES))]
    xml = ['<mujoco model="panda boxes">', '<option gravity="0 0 0"/>', '<asset>']
    if meshes:
        xml += ['<mesh name="%s" vertex="%s"/>' % (name, numbers(corners * half))
                for name, half in zip(box_names + static_names,
                                      list(panda.half_extents) + list(STATIC_HALF_EXTENTS))]
    xml += ['</asset>', '<worldbody>']
    for s, (pose, half) in enumerate(zip(STATIC_POSES, STATIC_HALF_EXTENTS)):
        xml.append('<geom name="%s" %s %s/>' % (static_names[s], shape(static_names[s], half),
                                                placed(rotation(pose[3:]), pose[:3])))
    children = {link: [] for link in range(len(panda.link_names))}
    for link in model.order:
        if model.parents[link] >= 0:
            children[model.parents[link]].append(link)

    def body(link):
        lines = ['<body name="%s" %s>' % (panda.link_names[link], placed(
            model.origin_rotations[link], model.origin_translations[link]))]
        if model.parents[link] >= 0 and model.joint_types[link] != 0:
            kind = 'slide' if model.joint_types[link] == 2 else 'hinge'
            lines.append('<joint name="%s" type="%s" axis="%s"/>' % (
                names[panda.link_names[link]], kind, numbers(model.axes[link])))
        for b in np.flatnonzero(model.box_links == link):
            lines.append('<geom name="%s" %s %s/>' % (
                box_names[b], shape(box_names[b], model.half_extents[b]),
                placed(model.box_rotations[b], model.box_translations[b])))
        for child in children[link]:
            lines += body(child)
        return lines + ['</body>']

    root = int(model.order[0])
    root_body = body(root)
    # The root: its frame is the world's (the base at the origin, no joint).
    root_body[0] = '<body name="%s">' % panda.link_names[root]
    xml += root_body + ['</worldbody>', '<contact>']
    xml += ['<exclude body1="%s" body2="%s"/>' % pair for pair in sorted(
        panda.disabled_link_pairs)]
    xml += ['</contact>', '</mujoco>']
    built = mujoco.MjModel.from_xml_string('\n'.join(xml))
    geoms = {}
    for geom in range(built.ngeom):
        name = mujoco.mj_id2name(built, mujoco.mjtObj.mjOBJ_GEOM, geom)
        geoms[geom] = (STATIC, int(name[6:])) if name.startswith('static') else (
            DYNAMIC, int(name[3:]))
    qpos_map, qpos_offset = np.zeros((built.nq, panda.dof)), np.zeros(built.nq)
    for joint in range(built.njnt):
        index, multiplier, offset = values[mujoco.mj_id2name(built, mujoco.mjtObj.mjOBJ_JOINT,
                                                             joint)]
        address = built.jnt_qposadr[joint]
        qpos_map[address, index], qpos_offset[address] = multiplier, offset
    return built, geoms, (qpos_map, qpos_offset)


class MuJoCo(robot.MuJoCo):

    def __init__(self, panda, urdf_path, meshes):
        self._mujoco = mujoco = _library('mujoco', robot.MUJOCO_HINT)
        self.name = MUJOCO_MESH if meshes else MUJOCO_BOX
        self.setup = (
            'MuJoCo %s: a body per link at its URDF joint origin, a hinge or slide on its URDF '
            "axis, the boxes as geoms at their poses in their links, the static boxes as world "
            'geoms, `<exclude>` for the %d filtered link pairs (the root link welded to the '
            'world: MuJoCo pairs no two static bodies, so its %d pairs with the static boxes, '
            'free in every state here, are not tested); per state `qpos` written (the '
            "mimic finger's entry set equal to the first finger's, as the URDF's mimic says), "
            "`mj_kinematics` + `mj_collision`, the contacts' geom pairs copied out; %s" % (
                mujoco.__version__, len(panda.disabled_link_pairs), len(STATIC_NAMES) * np.sum(
                    panda.model.box_links == panda.model.order[0]), (
                    "each box an 8-vertex convex mesh (MuJoCo's general convex collider)"
                    if meshes else "box geoms (MuJoCo's box-box collider)")))
        self._model, self._bodies, self._qpos = mujoco_model(mujoco, panda, urdf_path, meshes)
        self._data = mujoco.MjData(self._model)

    def inputs(self, states):
        qpos_map, qpos_offset = self._qpos
        return np.ascontiguousarray(states @ qpos_map.T + qpos_offset)


class PinCoal(Method):
    name = PIN_COAL

    def __init__(self, panda, urdf_path):
        self._pin = pin = _library('pinocchio', PIN_HINT)
        coal = _library('coal', robot.COAL_HINT)
        self.setup = (
            'pinocchio %s, coal %s: `pin.buildModelFromUrdf(urdf, mimic=True)` (the same q), '
            "a GeometryModel of `coal.Box` geometries at our boxes' poses in their link frames "
            'and the static boxes on the universe joint, %d collision pairs (the allowed ones and '
            'every robot-static pair); per state `pin.computeCollisions(model, data, '
            'geometry_model, geometry_data, q, False)`, which places the boxes by forward '
            "kinematics and tests every pair; the pairs' `isCollision()` read after the clock "
            'stops' % (
                pin.__version__, coal.__version__ if hasattr(coal, '__version__') else '',
                len(panda.allowed_box_pairs) + len(panda.half_extents) * len(STATIC_NAMES)))
        self.model = model = pin.buildModelFromUrdf(urdf_path, True)
        if model.nq != panda.dof:
            raise ValueError('pinocchio model has nq %d, ours dof %d' % (model.nq, panda.dof))
        # q in pinocchio's joint order: its idx_q of each of our joints.
        self._order = np.empty(panda.dof, np.int64)
        for index, name in enumerate(panda.joint_names):
            self._order[model.idx_qs[model.getJointId(name)]] = index
        geometry = pin.GeometryModel()
        keys = []
        for b, link in enumerate(panda.box_links):
            frame = model.frames[model.getFrameId(link)]
            local = pin.SE3(panda.model.box_rotations[b], panda.model.box_translations[b])
            geometry.addGeometryObject(pin.GeometryObject(
                'box%d' % b, frame.parentJoint, model.getFrameId(link), frame.placement * local,
                coal.Box(*(2.0 * panda.half_extents[b]))))
        boxes = len(panda.half_extents)
        for s, (pose, half) in enumerate(zip(STATIC_POSES, STATIC_HALF_EXTENTS)):
            geometry.addGeometryObject(pin.GeometryObject(
                'static%d' % s, 0, 0, pin.SE3(rotation(pose[3:]), pose[:3].copy()),
                coal.Box(*(2.0 * half))))
        pairs = [tuple(pair) for pair in panda.allowed_box_pairs.tolist()]
        pairs += [(b, boxes + s) for b in range(boxes) for s in range(len(STATIC_NAMES))]
        for a, b in pairs:
            geometry.addCollisionPair(pin.CollisionPair(a, b))
            keys.append(pair_key((DYNAMIC, a), (STATIC, b - boxes) if b >= boxes
                                 else (DYNAMIC, b)))
        self._keys = keys
        self.geometry = geometry
        self._data = model.createData()
        self._geometry_data = pin.GeometryData(geometry)
        self._results = self._geometry_data.collisionResults

    def inputs(self, states):
        return np.ascontiguousarray(states[:, self._order])

    def call(self, q, k):
        return self._pin.computeCollisions(self.model, self._data, self.geometry,
                                           self._geometry_data, q[k], False)

    def collect(self, raw):
        """Read which pairs collided (outside the clock: a Python loop over the results)."""
        return [key for key, result in zip(self._keys, self._results) if result.isCollision()]

    def answer(self, raw):
        return set(raw)

    def placement_error(self, panda, states):
        """Return the largest |pinocchio's box pose - ours| (m, and rotation matrix entries)."""
        pin = self._pin
        worst = 0.0
        for q_ours, q in zip(states, self.inputs(states)):
            pin.forwardKinematics(self.model, self._data, q)
            pin.updateGeometryPlacements(self.model, self._data, self.geometry,
                                         self._geometry_data)
            for b, pose in enumerate(panda.box_poses(q_ours)):
                placement = self._geometry_data.oMg[b]
                worst = max(worst, np.abs(placement.translation - pose[:3]).max(),
                            np.abs(placement.rotation - rotation(pose[3:])).max())
        return float(worst)


# --- the trajectory ------------------------------------------------------------------------


def free_path(panda, world, rng, waypoints=TRAJECTORY_WAYPOINTS):
    """Return a smooth (waypoints, dof) path free at SAMPLES_PER_SEGMENT states a segment.

    Each joint swings about a random centre by a random amplitude (within its limits), as
    a sum of two sines of random phase; the first random path whose dense samples are all
    free is returned. Returns (path, tries).
    """
    limits = panda.joint_limits
    middle, half = limits.mean(axis=1), 0.5 * (limits[:, 1] - limits[:, 0])
    dense = np.linspace(0.0, 1.0, (waypoints - 1) * SAMPLES_PER_SEGMENT + 1)
    for tries in range(1, PATH_TRIES + 1):
        centre = middle + rng.uniform(-0.5, 0.5, panda.dof) * half
        room = half - np.abs(centre - middle)
        amplitude = rng.uniform(0.3, 0.9, panda.dof) * room
        phases = rng.uniform(0.0, 2.0 * np.pi, (2, panda.dof))

        def path(s, centre=centre, amplitude=amplitude, phases=phases):
            s = s[:, None]
            swing = 0.6 * np.sin(2.0 * np.pi * s + phases[0]) \
                + 0.4 * np.sin(4.0 * np.pi * s + phases[1])
            return centre + amplitude * swing
        if len(world.check_joints(path(dense)).contacts) == 0:
            return path(np.linspace(0.0, 1.0, waypoints)), tries
    raise RuntimeError('no free path in %d tries' % PATH_TRIES)


def short_segments(panda, count, rng):
    """Return (count, 2, dof) random short segments within the limits."""
    limits = panda.joint_limits
    start = random_states(panda, count, rng)
    reach = np.where(limits[:, 1] - limits[:, 0] < 1.0, SHORT_SEGMENT_M, SHORT_SEGMENT_RAD)
    end = np.clip(start + rng.uniform(-1.0, 1.0, start.shape) * reach, limits[:, 0],
                  limits[:, 1])
    return np.stack([start, end], axis=1)


def false_alarms(world, segments):
    """Count check_trajectory's (segment, pair) reports a dense sampled referee finds free.

    A segment's reports are every pair its two-waypoint check_trajectory reports (at either
    end or between); the referee checks REFEREE_SAMPLES states from one end to the other.
    Returns the counts: reports, of them false alarms, and pairs the referee finds that were
    not reported (misses; there should be none).
    """
    s = np.linspace(0.0, 1.0, REFEREE_SAMPLES)[:, None]
    reports = alarms = misses = colliding = 0
    for start, end in segments:
        reported = contact_keys(world.check_trajectory(np.stack([start, end])).contacts)
        found = contact_keys(world.check_joints(start + s * (end - start)).contacts)
        reports += len(reported)
        alarms += len(reported - found)
        misses += len(found - reported)
        colliding += bool(found)
    return {'method': FALSE_ALARMS, 'kind': 'false_alarms', 'segments': len(segments),
            'colliding_segments': colliding, 'reports': reports, 'false_alarms': alarms,
            'misses': misses, 'false_alarm_rate': alarms / reports if reports else 0.0,
            'referee_samples': REFEREE_SAMPLES}


# --- the section ---------------------------------------------------------------------------


def _time_path(checks, path, seconds, round_index):
    """Time TRAJECTORY_REPEATS calls of each check on ``path``, the two taking turns.

    Call by call, and the one that goes first alternates from round to round: the first call
    after the other methods finds the caches cold, and the two share their kernels, so the
    one that always went first would pay for both. Adds seconds per call to ``seconds``;
    returns the pairs the checks report.
    """
    names = list(checks)
    if round_index % 2:
        names.reverse()
    if round_index == 0:
        for name in names:
            checks[name](path)
    reports = set()
    for _ in range(TRAJECTORY_REPEATS):
        for name in names:
            before = time.perf_counter()
            result = checks[name](path)
            seconds[name].append(time.perf_counter() - before)
            reports |= contact_keys(result.contacts)
    return reports


def methods(panda, urdf_path):
    """Return every state method: a Method, or (name, why it cannot run)."""
    made = []
    for name, make in ((OURS_JOINTS, lambda: OursJoints(panda)),
                       (OURS_BATCH, lambda: OursBatch(panda)),
                       (OURS_EVERY_CORE, lambda: OursEveryCore(panda)),
                       (MUJOCO_MESH, lambda: MuJoCo(panda, urdf_path, meshes=True)),
                       (MUJOCO_BOX, lambda: MuJoCo(panda, urdf_path, meshes=False)),
                       (PIN_COAL, lambda: PinCoal(panda, urdf_path))):
        try:
            made.append(make())
        except Unavailable as reason:
            made.append((name, str(reason)))
    return made


def robot_model_rows(states_per_round, batch_states, rounds, segments, seed=0, progress=print):
    """Time and compare every method on the Panda; return the rows (see the module docstring).

    Each round: ``states_per_round`` new random states one call each, ``batch_states`` in
    one call, and TRAJECTORY_REPEATS calls of each trajectory check (_time_path); the
    methods take turns in an order that rotates from round to round. Then ``segments``
    random short segments for the false alarms. Without example-robot-data, one row saying so.
    """
    try:
        _, urdf_path, _ = panda_files()
    except Unavailable as reason:
        progress('robot_model: %s' % reason)
        return [{'method': OURS_JOINTS, 'skipped': str(reason)}]
    panda = load_panda()
    rng = np.random.default_rng(seed)
    made = methods(panda, urdf_path)
    rows = {}
    for method in made:
        if isinstance(method, tuple):
            rows[method[0]] = {'method': method[0], 'skipped': method[1]}
            progress('robot_model: %s: %s' % method)
    running = [method for method in made if isinstance(method, Method)]
    for method in running:
        if isinstance(method, PinCoal):
            error = method.placement_error(panda, random_states(panda, 20, rng))
            rows[PIN_COAL] = {'placement_error': error}
            progress('robot_model: pinocchio places the boxes within %.2g of ours' % error)
    referee = panda_world(panda)
    path, tries = free_path(panda, referee, rng)
    trajectory = {TRAJECTORY: referee.check_trajectory, WAYPOINTS: referee.check_joints}
    seconds = {name: [] for name in [method.name for method in running] + list(trajectory)}
    answers = {method.name: [] for method in running}
    every_state, every_batch, path_reports = [], [], set()
    turns = running + [trajectory]
    for round_index in range(rounds):
        states = random_states(panda, states_per_round, rng)
        batch = random_states(panda, batch_states, rng)
        every_state.append(states)
        every_batch.append(batch)  # the same batch for every batch method
        turn = round_index % len(turns)
        for method in turns[turn:] + turns[:turn]:
            if method is trajectory:
                path_reports |= _time_path(trajectory, path, seconds, round_index)
                continue
            try:
                robot.time_round(method, states, batch, round_index == 0, states_per_round,
                                 batch_states, seconds, answers, [])
            except Exception as error:  # one broken method must not hide the others
                rows[method.name] = {'method': method.name, 'setup': method.setup,
                                     'error': '%s: %s' % (type(error).__name__, error)}
                turns.remove(method)
                running.remove(method)
                progress('robot_model: %s: ERROR %s' % (method.name, rows[method.name]['error']))
    every_state = np.concatenate(every_state)
    ours = answers.get(OURS_JOINTS)
    distance = _distance(panda)
    for method in running:
        taken = np.array(seconds[method.name]) * 1e6
        row = dict(rows.get(method.name, {}), method=method.name, setup=method.setup,
                   kind='state', batch=method.batch, rounds=rounds,
                   per_state_us=float(np.median(taken)), mean_us=float(np.mean(taken)),
                   pairs_per_state=float(np.mean([len(s) for s in answers[method.name]])),
                   colliding_states=float(np.mean([bool(s) for s in answers[method.name]])))
        if method.batch:
            batches = np.concatenate(every_batch)
            row.update(states_per_call=batch_states, states=len(batches))
            row.update(robot.compare(batches, _one_by_one(panda, batches),
                                     answers[method.name], distance, _margin))
        else:
            row.update(states_per_call=1, states=len(taken))
            if method.name == OURS_JOINTS:
                row.update(compared_states=len(taken), states_differing=0, same_answers=True,
                           boundary_only=False, reference_answers=True,
                           boxes=len(panda.half_extents), dof=panda.dof,
                           allowed_pairs=len(panda.allowed_box_pairs))
            elif ours is not None:
                row.update(robot.compare(every_state, ours, answers[method.name], distance,
                                         _margin))
        rows[method.name] = row
        progress('robot_model: %s: %.3g us per state (median of %d), %s' % (
            method.name, row['per_state_us'], len(taken), answers_text(row)))
    for name in trajectory:
        taken = np.array(seconds[name]) * 1e3
        rows[name] = {'method': name, 'kind': 'trajectory', 'waypoints': len(path),
                      'calls': len(taken), 'per_call_ms': float(np.median(taken)),
                      'mean_ms': float(np.mean(taken)), 'path_tries': tries,
                      'samples_per_segment': SAMPLES_PER_SEGMENT,
                      'reported_pairs': len(path_reports)}
    rows[TRAJECTORY]['vs_waypoints'] = (rows[TRAJECTORY]['per_call_ms']
                                        / rows[WAYPOINTS]['per_call_ms'])
    rows[WAYPOINTS]['vs_waypoints'] = 1.0
    for name in trajectory:
        progress('robot_model: %s: %.3g ms per call (median of %d), %.3gx the waypoints alone'
                 % (name, rows[name]['per_call_ms'], rows[name]['calls'],
                    rows[name]['vs_waypoints']))
    rows[FALSE_ALARMS] = false_alarms(referee, short_segments(panda, segments, rng))
    progress('robot_model: %s' % false_alarm_text(rows[FALSE_ALARMS]))
    ordered = [rows[name] for name in (OURS_JOINTS, OURS_BATCH, OURS_EVERY_CORE, MUJOCO_MESH,
                                       MUJOCO_BOX, PIN_COAL, TRAJECTORY, WAYPOINTS,
                                       FALSE_ALARMS)
               if name in rows]
    robot._add_ratios([row for row in ordered if row.get('kind') != 'trajectory'])
    return ordered


def _margin(key):
    """Return a pair's margin: 0 m, the default World's (colliding pairs only)."""
    return 0.0


def _one_by_one(panda, states):
    """Return our one-state-per-call answers for ``states`` (a World of its own, untimed)."""
    world = panda_world(panda)
    return [contact_keys(world.check_joints(q).contacts) for q in states]


def false_alarm_text(row):
    """Say what the false-alarm row found."""
    return ('{:,} random short segments ({:,} with a sampled collision): {:,} (segment, pair) '
            "reports, {:,} of them never colliding at the referee's {} samples ({:.3g} %); "
            '{:,} pairs the referee found unreported'.format(
                row['segments'], row['colliding_segments'], row['reports'],
                row['false_alarms'], row['referee_samples'], 100.0 * row['false_alarm_rate'],
                row['misses']))
