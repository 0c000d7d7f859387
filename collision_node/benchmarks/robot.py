"""The robot section of collision_bench: the arm of config/arm.yaml, ours against three peers.

The scene a robot runs is small: 7 box links (a base and six links, scenes.ARM_LINKS) over 3
static boxes (floor, table, shelf), adjacent links and base-floor ignored, every pair within
5 cm reported (10 cm from the shelf). Its 42 link pairs less the 7 ignored leave 35 allowed
pairs. Per state of the arm's trajectory every method answers the same question, "which
allowed pairs collide or lie within their margin", and the answers are compared state by
state with ours:

* ours, one state per call: a World set up as config/arm.yaml (brute force, margin 0.05 m,
  the shelf's own 0.05 m, the ignored pairs), ``World.step(poses, half_extents)``;
* ours, K states per call: ``World.check_states(states, half_extents)``, timed per call and
  divided by K;
* python-fcl: ``fcl.distance`` on each allowed pair in a Python loop, reported when at most
  the pair's margin (colliding pairs have a distance <= 0);
* coal: a ``coal.ComputeCollision`` per allowed pair, called in a Python loop with the pair's
  margin as ``security_margin``;
* MuJoCo: the scene as an MJCF model (each link a body with a free joint, the colliders
  static, geom margins that add up to each pair's margin, ``<exclude>`` for the ignored
  pairs: :func:`mujoco_model`); ``mj_kinematics`` + ``mj_collision``, the contacts' geom
  pairs and distances read in Python. Twice: the boxes as 8-vertex convex meshes (its
  general convex collider) and as box geoms (its box-box collider).

Each method is given its input in its own form, prepared outside the clock (our pose rows, the
fcl quaternions w first, the coal rotation matrices, MuJoCo's qpos); the clock runs from
handing it over until the answer is out of the library (for MuJoCo: copied out of its
contact buffer; one row per contact, several per pair, reduced to pairs outside the clock).
The methods take turns in rounds, each round on states a fraction of the state spacing later
than the last, so that a slow moment of the machine hits them all alike. A state where a
peer's pairs differ from ours is counted; each differing pair's exact distance
(``sat.signed_distance``) tells whether it lies on its margin's boundary (within
``BOUNDARY_M``), where an approximate distance may flip the answer, or not.

python-fcl, coal and MuJoCo are benchmark-only dependencies (the ``bench`` extra): each one
missing is reported as not installed and skipped.
"""
import importlib
import itertools
import time

import numpy as np

from collision_node.pipeline import scenes
from collision_node.pipeline.sat import signed_distance
from collision_node.pipeline.world import DYNAMIC, STATIC, World

# config/arm.yaml, as the World is given it (test_collision_bench checks them against the file).
ARM_BROAD_PHASE = 'brute_force'
ARM_MARGIN = 0.05  # m
ARM_COLLIDER_MARGINS = {'floor': 0.0, 'table': 0.0, 'shelf': 0.05}  # m, added to ARM_MARGIN
ARM_IGNORED_PAIRS = ('d0 d1', 'd1 d2', 'd2 d3', 'd3 d4', 'd4 d5', 'd5 d6', 'd0 floor')
STATIC_NAMES = tuple(scenes.ARM_STATICS)  # collider ids 0, 1, 2

# A pair whose exact distance lies this close to its margin may be answered either way by a
# method whose distance is approximate (GJK's tolerance, rounding): a boundary difference.
BOUNDARY_M = 1e-6
WARM_STATES = 10  # untimed calls of each method before its first timed round

MUJOCO_HINT = 'MuJoCo not installed (benchmark-only dependency: pip install mujoco)'
COAL_HINT = 'coal not installed (benchmark-only dependency: pip install coal)'
FCL_HINT = 'python-fcl not installed (benchmark-only dependency: pip install python-fcl)'

OURS_STEP = 'collision_node World.step'
OURS_BATCH = 'collision_node World.check_states'
FCL = 'python-fcl'
COAL = 'coal'
MUJOCO_MESH = 'MuJoCo, boxes as convex meshes'
MUJOCO_BOX = 'MuJoCo, box geoms'


# --- the scene -----------------------------------------------------------------------------


def body(name):
    """Return (type, id) of ``name``: d<i> is dynamic body i, else a collider of STATIC_NAMES."""
    if name.startswith('d') and name[1:].isdigit():
        return DYNAMIC, int(name[1:])
    return STATIC, STATIC_NAMES.index(name)


def pair_key(body_a, body_b):
    """Return a pair of (type, id) bodies as a contact names it: (id_a, type_b, id_b)."""
    (type_a, id_a), (type_b, id_b) = body_a, body_b
    if type_a == STATIC:
        (type_a, id_a), (type_b, id_b) = (type_b, id_b), (type_a, id_a)
    if type_a == STATIC:
        raise ValueError('two static bodies are never paired')
    if type_b == DYNAMIC and id_b < id_a:
        id_a, id_b = id_b, id_a
    return id_a, type_b, id_b


def ignored_keys():
    """Return the ignored pairs of config/arm.yaml as contact keys."""
    return {pair_key(*map(body, entry.split())) for entry in ARM_IGNORED_PAIRS}


def allowed_pairs():
    """Return every pair the arm's World checks, as contact keys, in a fixed order."""
    links = range(scenes.ARM_LINK_COUNT)
    every = [(a, DYNAMIC, b) for a, b in itertools.combinations(links, 2)]
    every += [(a, STATIC, s) for a in links for s in range(len(STATIC_NAMES))]
    ignored = ignored_keys()
    return [key for key in every if key not in ignored]


def pair_margin(key):
    """Return the margin (m) of a pair: the World's, plus the collider's for a static one."""
    _, type_b, id_b = key
    return ARM_MARGIN + (ARM_COLLIDER_MARGINS[STATIC_NAMES[id_b]] if type_b == STATIC else 0.0)


def arm_world():
    """Return a World set up as config/arm.yaml: broad phase, margins, colliders, ignored pairs."""
    scene = scenes.arm()
    world = World(broad_phase=ARM_BROAD_PHASE, margin=ARM_MARGIN)
    world.set_static(scene.static_poses, scene.static_half_extents,
                     margins=[ARM_COLLIDER_MARGINS[name] for name in STATIC_NAMES])
    rows = []
    for entry in ARM_IGNORED_PAIRS:
        (type_a, id_a), (type_b, id_b) = map(body, entry.split())
        rows.append((id_a, type_a, id_b, type_b))
    world.set_filters(ignored_pairs=rows)
    return world


def arm_states(count, offset=0.0):
    """Return (count, 7, 7) link poses over one period of the arm's trajectory.

    State k is at time (k + offset) · period / count.
    """
    scene = scenes.arm()
    step = scenes.ARM_PERIOD_S / count
    return np.array([scene.dynamic_poses((k + offset) * step) for k in range(count)])


def rotation(quaternion):
    """Return the rotation matrix of a quaternion (x, y, z, w), normalised as a World does.

    A pose written to 7 digits (the scenes' turned boxes) is 1e-8 off unit length: its raw
    matrix would be as far off orthonormal, and the peers would test other boxes than ours.
    """
    x, y, z, w = np.asarray(quaternion, np.float64) / np.linalg.norm(quaternion)
    return np.array([
        [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
        [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
        [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)]])


def contact_keys(contacts):
    """Return the set of pairs in a contacts array (id_a, type_b, id_b)."""
    return set(zip(contacts['id_a'].tolist(), contacts['type_b'].tolist(),
                   contacts['id_b'].tolist()))


def exact_distance(poses, key):
    """Return the signed distance of pair ``key`` at link poses (7, 7) (sat.signed_distance)."""
    scene = scenes.arm()
    id_a, type_b, id_b = key
    pose_a = poses[id_a]
    if type_b == STATIC:
        pose_b, half_b = scene.static_poses[id_b], scene.static_half_extents[id_b]
    else:
        pose_b, half_b = poses[id_b], scene.dynamic_half_extents[id_b]
    return signed_distance(pose_a[:3], rotation(pose_a[3:]), scene.dynamic_half_extents[id_a],
                           pose_b[:3], rotation(pose_b[3:]), half_b).distance


def compare(states, ours, theirs, distance=None, margin=None):
    """Compare a method's pair sets with ours, state by state.

    ``distance(state, key)`` is a pair's exact signed distance in a state and ``margin(key)``
    its margin (default: the arm's, ``states`` its link poses). Returns the counts: states
    compared and differing, pairs only ours / only theirs report, differing pairs that
    collide (exact distance <= 0), the largest distance of a differing pair from its
    margin's boundary (m; None when none differ) and whether every difference lies on the
    boundary (within BOUNDARY_M).
    """
    distance = distance or exact_distance
    margin = margin or pair_margin
    differing = only_ours = only_theirs = colliding = 0
    gaps = []
    for poses, mine, other in zip(states, ours, theirs):
        if mine == other:
            continue
        differing += 1
        only_ours += len(mine - other)
        only_theirs += len(other - mine)
        for key in mine ^ other:
            exact = distance(poses, key)
            gaps.append(abs(exact - margin(key)))
            colliding += exact <= 0.0
    worst = float(max(gaps)) if gaps else None
    return {'compared_states': len(ours), 'states_differing': differing,
            'only_ours': only_ours, 'only_peer': only_theirs, 'worst_gap_m': worst,
            'colliding_pairs_differing': int(colliding),
            'same_answers': differing == 0,
            'boundary_only': bool(differing > 0 and worst <= BOUNDARY_M)}


# --- the methods ---------------------------------------------------------------------------


class Unavailable(Exception):
    """A method that cannot run here (a library not installed, a method not in this build)."""


def _library(name, hint):
    """Import a benchmark-only library, or raise Unavailable saying how to install it."""
    try:
        return importlib.import_module(name)
    except ImportError:
        raise Unavailable(hint) from None


class Method:
    """One way to answer the arm's question; one state per call unless ``batch``.

    ``inputs(states)`` turns (S, 7, 7) poses into the method's own input (not timed);
    ``call(inputs, k)`` answers state k (timed); ``collect(raw)``, right after the clock
    stops, reads what a library keeps only until its next call; ``answer(raw)`` turns what
    it returned into a set of contact keys (not timed). A batch method's ``call(inputs)``
    answers every state and ``answers(raw, count)`` returns their sets.
    """

    batch = False
    name = ''
    setup = ''

    def inputs(self, states):
        return states

    def collect(self, raw):
        return raw

    def answer(self, raw):
        return raw


class OursStep(Method):
    name = OURS_STEP
    setup = ("a World set up as config/arm.yaml (brute_force, margin 0.05 m, the shelf's "
             '0.05 m, 7 ignored pairs), one `World.step(poses, half_extents)` per state')

    def __init__(self):
        self.world = arm_world()
        self.half_extents = scenes.arm().dynamic_half_extents

    def call(self, states, k):
        return self.world.step(states[k], self.half_extents).contacts

    def answer(self, raw):
        return contact_keys(raw)


class OursBatch(Method):
    batch = True
    name = OURS_BATCH
    setup = ('a World set up alike, `World.check_states(states, half_extents)` on K states in '
             'one call; per state = the call / K')

    def __init__(self):
        self.world = arm_world()
        self.half_extents = scenes.arm().dynamic_half_extents

    def call(self, states):
        return self.world.check_states(states, self.half_extents)

    def answers(self, raw, count):
        contacts = raw.contacts
        sets = [set() for _ in range(count)]
        for state, key in zip(contacts['state'].tolist(), zip(
                contacts['id_a'].tolist(), contacts['type_b'].tolist(),
                contacts['id_b'].tolist())):
            sets[state].add(key)
        return sets


class Fcl(Method):
    name = FCL
    setup = ("`fcl.distance` on each of the 35 allowed pairs in a Python loop, a pair "
             "reported when its distance is at most its margin; the 7 links' transforms set "
             'by `setTranslation` and `setQuatRotation` first. Its `DistanceResult` holds '
             '-inf, so python-fcl keeps no nearest points (it would build Python objects for '
             "them on every call); the distance is the call's return value")

    def __init__(self):
        self._fcl = fcl = _library('fcl', FCL_HINT)
        scene = scenes.arm()
        links = [self._object(pose, half) for pose, half in zip(
            arm_states(1)[0], scene.dynamic_half_extents)]
        statics = [self._object(pose, half) for pose, half in zip(
            scene.static_poses, scene.static_half_extents)]
        self._links = links
        self._pairs = [(links[a], (statics if type_b == STATIC else links)[b],
                        pair_margin((a, type_b, b)), (a, type_b, b))
                       for a, type_b, b in allowed_pairs()]
        self._request = fcl.DistanceRequest()
        self._sink = fcl.DistanceResult()
        self._sink.min_distance = -np.inf

    def _object(self, pose, half):
        fcl = self._fcl
        return fcl.CollisionObject(fcl.Box(*(2.0 * half)),
                                   fcl.Transform(pose[[6, 3, 4, 5]], pose[:3]))

    def inputs(self, states):
        # fcl's quaternions are (w, x, y, z); lists are the quickest form it takes.
        return np.ascontiguousarray(states[:, :, :3]), states[:, :, [6, 3, 4, 5]].tolist()

    def call(self, inputs, k):
        translations, quaternions = inputs
        for link, translation, quaternion in zip(self._links, translations[k], quaternions[k]):
            link.setTranslation(translation)
            link.setQuatRotation(quaternion)
        distance, request, sink = self._fcl.distance, self._request, self._sink
        return {key for a, b, margin, key in self._pairs
                if distance(a, b, request, sink) <= margin}


class Coal(Method):
    name = COAL
    setup = ('a `coal.ComputeCollision` per allowed pair (built once), called in a Python '
             "loop with the 7 links' `Transform3s` and a `CollisionRequest` whose "
             "`security_margin` is the pair's margin")

    def __init__(self):
        self._coal = coal = _library('coal', COAL_HINT)
        scene = scenes.arm()
        links = [coal.Box(*(2.0 * half)) for half in scene.dynamic_half_extents]
        statics = [coal.Box(*(2.0 * half)) for half in scene.static_half_extents]
        self._static_transforms = [coal.Transform3s(rotation(pose[3:]), pose[:3].copy())
                                   for pose in scene.static_poses]
        requests = {}
        for margin in sorted({pair_margin(key) for key in allowed_pairs()}):
            requests[margin] = coal.CollisionRequest()
            requests[margin].security_margin = margin
        self._pairs = [(a, type_b == STATIC, b,
                        coal.ComputeCollision(links[a], (statics if type_b == STATIC
                                                         else links)[b]),
                        requests[pair_margin((a, type_b, b))], (a, type_b, b))
                       for a, type_b, b in allowed_pairs()]
        self._result = coal.CollisionResult()
        self._links = links
        self._statics = statics  # the functors hold pointers to the geometries

    def inputs(self, states):
        rotations = np.array([[rotation(pose[3:]) for pose in poses] for poses in states])
        return rotations, np.ascontiguousarray(states[:, :, :3])

    def call(self, inputs, k):
        rotations, translations = inputs
        transform = self._coal.Transform3s
        links = [transform(r, t) for r, t in zip(rotations[k], translations[k])]
        statics, result = self._static_transforms, self._result
        found = set()
        for a, static, b, collide, request, key in self._pairs:
            result.clear()
            if collide(links[a], statics[b] if static else links[b], request, result):
                found.add(key)
        return found


def mujoco_model(mujoco, meshes):
    """Return (model, geom id -> (type, id)) of the arm in MuJoCo; meshes or box geoms.

    Links: bodies with a free joint (a mocap or jointless body is static, and MuJoCo never
    pairs two static bodies). Colliders: geoms of the world body, except those named in an
    ignored pair (the floor), which get a jointless body of their own so that ``<exclude>``
    (which names bodies) drops base-floor alone (a little quicker than a body for each
    collider). MuJoCo pairs two geoms within the sum of their
    ``margin`` attributes, so a link's geom gets half the World's margin and a collider's
    the other half plus its own: link-link 0.05 m, link-floor and link-table 0.05 m,
    link-shelf 0.10 m, as in the World.
    """
    scene = scenes.arm()
    names = list(STATIC_NAMES) + ['d%d' % i for i in range(scenes.ARM_LINK_COUNT)]
    halves = list(scene.static_half_extents) + list(scene.dynamic_half_extents)
    margins = [ARM_MARGIN / 2 + ARM_COLLIDER_MARGINS[name] for name in STATIC_NAMES]
    margins += [ARM_MARGIN / 2] * scenes.ARM_LINK_COUNT
    corners = np.array(list(itertools.product((-1.0, 1.0), repeat=3)))

    def numbers(values):
        return ' '.join('%.17g' % value for value in np.ravel(values))

    def geom(i):
        shape = ('type="mesh" mesh="box_%s"' % names[i] if meshes else
                 'type="box" size="%s"' % numbers(halves[i]))
        return '<geom name="%s" %s margin="%.17g"/>' % (names[i], shape, margins[i])

    xml = ['<mujoco model="arm">', '<option gravity="0 0 0"/>', '<asset>']
    if meshes:
        xml += ['<mesh name="box_%s" vertex="%s"/>' % (name, numbers(corners * half))
                for name, half in zip(names, halves)]
    xml += ['</asset>', '<worldbody>']
    in_ignored_pairs = {name for entry in ARM_IGNORED_PAIRS for name in entry.split()}
    for i, pose in enumerate(scene.static_poses):
        placed = 'pos="%s" quat="%s"' % (numbers(pose[:3]), numbers(pose[[6, 3, 4, 5]]))
        if names[i] in in_ignored_pairs:
            xml += ['<body name="%s" %s>' % (names[i], placed), geom(i), '</body>']
        else:
            xml.append(geom(i).replace('<geom ', '<geom %s ' % placed))
    for i in range(len(STATIC_NAMES), len(names)):
        xml += ['<body name="%s">' % names[i], '<freejoint/>', geom(i), '</body>']
    xml += ['</worldbody>', '<contact>']
    xml += ['<exclude body1="%s" body2="%s"/>' % tuple(entry.split())
            for entry in ARM_IGNORED_PAIRS]
    xml += ['</contact>', '</mujoco>']
    model = mujoco.MjModel.from_xml_string('\n'.join(xml))
    bodies = {}
    for geom_id in range(model.ngeom):
        bodies[geom_id] = body(mujoco.mj_id2name(model, mujoco.mjtObj.mjOBJ_GEOM, geom_id))
    return model, bodies


class MuJoCo(Method):

    def __init__(self, meshes):
        self._mujoco = mujoco = _library('mujoco', MUJOCO_HINT)
        self.name = MUJOCO_MESH if meshes else MUJOCO_BOX
        self.setup = (
            'MuJoCo %s: links as bodies with a free joint, colliders as world geoms (the '
            'floor in a jointless body, for its `<exclude>`), geom margins adding up to each '
            "pair's, `<exclude>` for the 7 ignored pairs; per state `qpos` written, "
            "`mj_kinematics` + `mj_collision`, the contacts' geom pairs and `dist` copied out; "
            '%s' % (mujoco.__version__, (
                "each box an 8-vertex convex mesh (MuJoCo's general convex collider)" if meshes
                else "box geoms (MuJoCo's box-box collider)")))
        self._model, self._bodies = mujoco_model(mujoco, meshes)
        self._data = mujoco.MjData(self._model)

    def inputs(self, states):
        # A free joint's qpos: x y z, then the quaternion w first.
        return np.ascontiguousarray(states[:, :, [0, 1, 2, 6, 3, 4, 5]].reshape(len(states), -1))

    def call(self, qpos, k):
        mujoco, model, data = self._mujoco, self._model, self._data
        data.qpos[:] = qpos[k]
        mujoco.mj_kinematics(model, data)
        mujoco.mj_collision(model, data)
        contact = data.contact  # data.ncon rows
        return contact.geom.copy(), contact.dist.copy()

    def answer(self, raw):
        bodies = self._bodies
        return {pair_key(bodies[a], bodies[b]) for a, b in raw[0].tolist()}


# --- the section ---------------------------------------------------------------------------


def methods():
    """Return every method: a Method, or (name, why it cannot run)."""
    made = []
    for name, make in ((OURS_STEP, OursStep), (OURS_BATCH, OursBatch), (FCL, Fcl),
                       (COAL, Coal), (MUJOCO_MESH, lambda: MuJoCo(meshes=True)),
                       (MUJOCO_BOX, lambda: MuJoCo(meshes=False))):
        try:
            made.append(make())
        except Unavailable as reason:
            made.append((name, str(reason)))
    return made


def time_round(method, states, batch, first_round, states_per_round, batch_states, seconds,
               answers, batches):
    """Time ``method`` on one round: its states one by one, or its batch in one call.

    Adds the seconds per state to ``seconds[method.name]`` and the answers to
    ``answers[method.name]``; a batch it checked goes to ``batches``. The first round warms
    the method up first, untimed.
    """
    if method.batch:
        if first_round:
            method.call(batch[:WARM_STATES])
        before = time.perf_counter()
        raw = method.call(batch)
        seconds[method.name].append((time.perf_counter() - before) / batch_states)
        answers[method.name].extend(method.answers(raw, batch_states))
        batches.append(batch)
        return
    inputs = method.inputs(states)
    if first_round:
        _time_states(method, inputs, min(WARM_STATES, states_per_round))
    taken, raws = _time_states(method, inputs, states_per_round)
    seconds[method.name].extend(taken)
    answers[method.name].extend(method.answer(raw) for raw in raws)


def _time_states(method, inputs, count):
    """Call ``method`` on states 0..count-1 of ``inputs``; return (seconds per call, raws)."""
    call, collect, clock = method.call, method.collect, time.perf_counter
    seconds, raws = np.empty(count), [None] * count
    for k in range(count):
        before = clock()
        raw = call(inputs, k)
        seconds[k] = clock() - before
        raws[k] = collect(raw)
    return seconds, raws


def robot_rows(states_per_round, batch_states, rounds, progress=print):
    """Time and compare every method on the arm; return one row per method.

    Each round, every method answers ``states_per_round`` states one call each (a batch
    method: ``batch_states`` states in one call), the methods taking turns in an order that
    rotates from round to round. A method that raises gets an ``error`` row.
    """
    made = methods()
    rows = {}
    for method in made:
        if isinstance(method, tuple):
            rows[method[0]] = {'method': method[0], 'skipped': method[1]}
            progress('robot: %s: %s' % method)
    running = [method for method in made if isinstance(method, Method)]
    seconds = {method.name: [] for method in running}
    answers = {method.name: [] for method in running}
    compared_states, batch_compared = [], []
    for round_index in range(rounds):
        offset = round_index / rounds
        states = arm_states(states_per_round, offset)
        batch = arm_states(batch_states, offset) if any(
            method.batch for method in running) else None
        compared_states.append(states)
        order = running[round_index % len(running):] + running[:round_index % len(running)]
        for method in list(order):
            try:
                time_round(method, states, batch, round_index == 0, states_per_round,
                           batch_states, seconds, answers, batch_compared)
            except Exception as error:  # one broken method must not hide the others
                rows[method.name] = {'method': method.name, 'setup': method.setup,
                                     'error': '%s: %s' % (type(error).__name__, error)}
                running.remove(method)
                progress('robot: %s: ERROR %s' % (method.name, rows[method.name]['error']))
    every_state = np.concatenate(compared_states)
    ours = answers.get(OURS_STEP)
    for method in running:
        taken = np.array(seconds[method.name]) * 1e6
        row = {'method': method.name, 'setup': method.setup, 'batch': method.batch,
               'rounds': rounds, 'per_state_us': float(np.median(taken)),
               'mean_us': float(np.mean(taken)),
               'pairs_per_state': float(np.mean([len(s) for s in answers[method.name]]))}
        if method.batch:
            row.update(states_per_call=batch_states, states=batch_states * len(taken))
            batches = np.concatenate(batch_compared)
            row.update(compare(batches, _step_answers(batches), answers[method.name]))
        else:
            row.update(states_per_call=1, states=len(taken))
            if ours is not None and method.name != OURS_STEP:
                row.update(compare(every_state, ours, answers[method.name]))
            elif method.name == OURS_STEP:
                row.update(compared_states=len(taken), states_differing=0, same_answers=True,
                           boundary_only=False, reference_answers=True)
        rows[method.name] = row
        progress('robot: %s: %.3g us per state (median of %d), %s' % (
            method.name, row['per_state_us'], len(taken), answers_text(row)))
    ordered = [rows[name] for name in (OURS_STEP, OURS_BATCH, FCL, COAL, MUJOCO_MESH,
                                       MUJOCO_BOX) if name in rows]
    _add_ratios(ordered)
    return ordered


def _step_answers(states):
    """Return our one-state-per-call answers for ``states`` (a World of its own, untimed)."""
    world = arm_world()
    half_extents = scenes.arm().dynamic_half_extents
    return [contact_keys(world.step(poses, half_extents).contacts) for poses in states]


def _add_ratios(rows):
    """Give each timed row its time over MuJoCo's; mark the MuJoCo row the ratios use.

    That is the quickest MuJoCo row whose answers agree with ours (boundary differences
    allowed), or the quickest one if none agrees (then ``mujoco_answers_differ``).
    """
    mujoco = [row for row in rows if row['method'] in (MUJOCO_MESH, MUJOCO_BOX)
              and 'per_state_us' in row]
    if not mujoco:
        return
    agreeing = [row for row in mujoco if row['same_answers'] or row['boundary_only']]
    reference = min(agreeing or mujoco, key=lambda row: row['per_state_us'])
    reference['mujoco_reference'] = True
    if not agreeing:
        reference['mujoco_answers_differ'] = True
    for row in rows:
        if 'per_state_us' in row:
            row['vs_mujoco'] = row['per_state_us'] / reference['per_state_us']


def answers_text(row):
    """Say how a row's answers compare with ours."""
    if row.get('reference_answers'):
        return 'the reference answers'
    if 'states_differing' not in row:
        return 'not compared'
    states = '{:,} states'.format(row['compared_states'])
    if row['same_answers']:
        return 'same pairs in all %s' % states
    text = '%d of %s differ (pairs only ours: %d, only theirs: %d' % (
        row['states_differing'], states, row['only_ours'], row['only_peer'])
    if row['colliding_pairs_differing']:
        text += ', of them colliding: %d' % row['colliding_pairs_differing']
    if row['boundary_only']:
        return text + '; all within %g m of the margin)' % BOUNDARY_M
    return text + '; up to %.2g m from the margin)' % row['worst_gap_m']
