"""Deterministic test scenes: static boxes plus dynamic boxes whose poses are a function of time.

Used by the demo's pose publisher, the benchmarks and the tests. Every scene is reproducible
from its name, body count and seed.
"""
from typing import NamedTuple, Optional

import numpy as np


class Scene(NamedTuple):
    """Static boxes and the motion of the dynamic ones (all arrays float64)."""

    name: str
    static_poses: np.ndarray           # (S, 7) x y z qx qy qz qw
    static_half_extents: np.ndarray    # (S, 3)
    dynamic_half_extents: np.ndarray   # (D, 3)
    start_positions: np.ndarray        # (D, 3)
    start_quaternions: np.ndarray      # (D, 4) qx qy qz qw
    velocities: np.ndarray             # (D, 3) m/s
    angular_velocities: np.ndarray     # (D, 3) rad/s, world frame
    bounds: Optional[np.ndarray]       # (2, 3) walls the bodies bounce off, or None: fly free

    @property
    def dynamic_count(self):
        return len(self.dynamic_half_extents)

    def dynamic_poses(self, time_s):
        """Poses (D, 7) of the dynamic boxes ``time_s`` seconds after the start."""
        positions = self.start_positions + self.velocities * time_s
        if self.bounds is not None:
            # Bounce between the walls: fold the free path back with a triangle wave.
            low, high = self.bounds
            span = high - low
            phase = np.mod(positions - low, 2.0 * span)
            positions = low + np.where(phase > span, 2.0 * span - phase, phase)
        poses = np.empty((self.dynamic_count, 7))
        poses[:, :3] = positions
        poses[:, 3:] = _rotate(self.start_quaternions, self.angular_velocities * time_s)
        return poses


def _rotate(quaternions, rotation_vectors):
    """Quaternions (N, 4) turned by the world-frame rotation vectors (N, 3)."""
    angle = np.linalg.norm(rotation_vectors, axis=1)
    axis = rotation_vectors / np.where(angle > 0.0, angle, 1.0)[:, None]
    half_sin = np.sin(0.5 * angle)[:, None]
    turn = np.concatenate([axis * half_sin, np.cos(0.5 * angle)[:, None]], axis=1)
    # Hamilton product turn ⊗ q, both as (x, y, z, w).
    tv, tw = turn[:, :3], turn[:, 3:]
    qv, qw = quaternions[:, :3], quaternions[:, 3:]
    vector = tw * qv + qw * tv + np.cross(tv, qv)
    scalar = tw * qw - np.sum(tv * qv, axis=1, keepdims=True)
    return np.concatenate([vector, scalar], axis=1)


def _random_quaternions(rng, n):
    q = rng.normal(size=(n, 4))
    return q / np.linalg.norm(q, axis=1, keepdims=True)


def _poses(positions, quaternions):
    return np.concatenate([positions, quaternions], axis=1)


# Uniform scenes: half extents in [0.1, 0.3] m; the cube's side grows as n^(1/3) so the density,
# and with it the colliding pairs per body (about 1, measured with brute force), stay the same.
UNIFORM_HALF_EXTENTS = (0.1, 0.3)
UNIFORM_SIDE_PER_CBRT_BODY = 0.62  # m
UNIFORM_SPEED = 0.5  # m/s, at most, per axis
CLUSTERED_FRACTION = 0.9
CLUSTER_SIDE_FRACTION = 0.5  # side of the corner cube holding 90 % of the bodies (about 7
#                             colliding pairs per body there)


def uniform(n, seed=0, clustered=False):
    """``n`` random boxes in a cube, half of them static, about one colliding pair per body.

    ``clustered``: 90 % of the bodies start in one corner cube (half the side), the rest
    spread over the whole cube.
    """
    rng = np.random.default_rng(seed)
    side = UNIFORM_SIDE_PER_CBRT_BODY * max(n, 1) ** (1.0 / 3.0)
    positions = rng.uniform(0.0, side, (n, 3))
    if clustered:
        in_corner = rng.random(n) < CLUSTERED_FRACTION
        positions[in_corner] *= CLUSTER_SIDE_FRACTION
    quaternions = _random_quaternions(rng, n)
    half_extents = rng.uniform(*UNIFORM_HALF_EXTENTS, (n, 3))
    n_static = n // 2
    n_dynamic = n - n_static
    return Scene(
        name='clustered' if clustered else 'uniform',
        static_poses=_poses(positions[:n_static], quaternions[:n_static]),
        static_half_extents=half_extents[:n_static],
        dynamic_half_extents=half_extents[n_static:],
        start_positions=positions[n_static:],
        start_quaternions=quaternions[n_static:],
        velocities=rng.uniform(-UNIFORM_SPEED, UNIFORM_SPEED, (n_dynamic, 3)),
        angular_velocities=rng.uniform(-1.0, 1.0, (n_dynamic, 3)),
        bounds=np.array([[0.0] * 3, [side] * 3]))


def clustered(n, seed=0):
    """``uniform`` with 90 % of the bodies in one corner."""
    return uniform(n, seed, clustered=True)


# "Discrete Collision Algorithms": cubes start close to the origin heading outward, dense at
# first, sparse later.
FLYING_OUT_HALF_EXTENT = 0.5   # m, cubes
FLYING_OUT_START_RADIUS = 0.75  # m per cube root of the body count: starts densely packed
FLYING_OUT_SPEED = (1.0, 3.0)  # m/s


def flying_out(n, seed=0):
    """Return the "Discrete Collision Algorithms" scene: ``n`` cubes flying out from the origin.

    No static bodies; every cube is dynamic.
    """
    rng = np.random.default_rng(seed)
    direction = rng.normal(size=(n, 3))
    direction /= np.linalg.norm(direction, axis=1, keepdims=True)
    radius = FLYING_OUT_START_RADIUS * max(n, 1) ** (1.0 / 3.0) * rng.random(n) ** (1.0 / 3.0)
    return Scene(
        name='flying_out',
        static_poses=np.zeros((0, 7)),
        static_half_extents=np.zeros((0, 3)),
        dynamic_half_extents=np.full((n, 3), FLYING_OUT_HALF_EXTENT),
        start_positions=direction * radius[:, None],
        start_quaternions=_random_quaternions(rng, n),
        velocities=direction * rng.uniform(*FLYING_OUT_SPEED, (n, 1)),
        angular_velocities=rng.uniform(-1.0, 1.0, (n, 3)),
        bounds=None)


def paper000(n=1000, seed=0):
    """Return the "Engine Algorithms" scene: half static, half dynamic boxes (500 + 500)."""
    return uniform(n, seed)._replace(name='paper000')


# The demo room of config/default.yaml: 6 m x 4 m x 2.5 m, statics listed there too.
ROOM_BOUNDS = ((-3.0, -2.0, 0.0), (3.0, 2.0, 2.5))
ROOM_STATICS = {  # name: (pose x y z qx qy qz qw, half extents)
    'floor': ((0.0, 0.0, -0.05, 0.0, 0.0, 0.0, 1.0), (3.0, 2.0, 0.05)),
    'wall_north': ((0.0, 2.05, 1.25, 0.0, 0.0, 0.0, 1.0), (3.0, 0.05, 1.25)),
    'wall_south': ((0.0, -2.05, 1.25, 0.0, 0.0, 0.0, 1.0), (3.0, 0.05, 1.25)),
    'table': ((0.0, 0.0, 0.4, 0.0, 0.0, 0.0, 1.0), (0.6, 0.4, 0.02)),
    'shelf_left': ((-2.5, 1.6, 1.0, 0.0, 0.0, 0.0, 1.0), (0.4, 0.2, 1.0)),
    'shelf_right': ((2.4, -1.4, 1.0, 0.0, 0.0, 0.3826834, 0.9238795), (0.4, 0.2, 1.0)),
}
ROOM_DYNAMIC_COUNT = 40
ROOM_HALF_EXTENTS = (0.1, 0.1, 0.1)  # as config/default.yaml's dynamic.half_extents


def room(n=ROOM_DYNAMIC_COUNT, seed=0):
    """Return the demo scene: ``n`` boxes drifting through the room of config/default.yaml."""
    rng = np.random.default_rng(seed)
    low, high = np.array(ROOM_BOUNDS)
    statics = list(ROOM_STATICS.values())
    return Scene(
        name='room',
        static_poses=np.array([pose for pose, _ in statics]),
        static_half_extents=np.array([extent for _, extent in statics]),
        dynamic_half_extents=np.tile(ROOM_HALF_EXTENTS, (n, 1)),
        start_positions=rng.uniform(low, high, (n, 3)),
        start_quaternions=_random_quaternions(rng, n),
        velocities=rng.uniform(-0.6, 0.6, (n, 3)),
        angular_velocities=rng.uniform(-1.0, 1.0, (n, 3)),
        bounds=np.array([low, high]))


class ArmScene(NamedTuple):
    """A serial arm of boxes over static boxes: dynamic poses from forward kinematics."""

    name: str
    static_poses: np.ndarray           # (S, 7)
    static_half_extents: np.ndarray    # (S, 3)
    dynamic_half_extents: np.ndarray   # (L, 3), one box per link

    @property
    def dynamic_count(self):
        return len(self.dynamic_half_extents)

    def dynamic_poses(self, time_s):
        """Poses (L, 7) of the links ``time_s`` seconds into the joint trajectory."""
        angles = arm_joint_angles(time_s)
        rotation, origin = np.eye(3), np.zeros(3)
        poses = np.empty((len(ARM_LINKS), 7))
        for link, (joint_origin, axis, box_center, _) in enumerate(ARM_LINKS):
            origin = origin + rotation @ np.array(joint_origin)
            rotation = rotation @ _axis_rotation(axis, angles[link])
            poses[link, :3] = origin + rotation @ np.array(box_center)
            poses[link, 3:] = _quaternion(rotation)
        return poses


# The arm of config/arm.yaml: a base and six links on revolute joints, each link's box reaching
# a few cm past its joint into its neighbour's, as real links overlap at their joints. Per link:
# joint origin in the parent link's frame, joint axis (0 x, 1 y, 2 z; None: fixed), the box
# centre in the link's frame and its half extents (m).
ARM_LINKS = (
    ((0.0, 0.0, 0.0), None, (0.0, 0.0, 0.1), (0.1, 0.1, 0.1)),         # base, on the floor
    ((0.0, 0.0, 0.2), 2, (0.0, 0.0, 0.1), (0.07, 0.07, 0.12)),        # shoulder yaw
    ((0.0, 0.0, 0.2), 1, (0.2, 0.0, 0.0), (0.25, 0.06, 0.06)),        # shoulder pitch
    ((0.4, 0.0, 0.0), 1, (0.18, 0.0, 0.0), (0.22, 0.05, 0.05)),       # elbow
    ((0.4, 0.0, 0.0), 0, (0.05, 0.0, 0.0), (0.07, 0.045, 0.045)),     # wrist roll
    ((0.1, 0.0, 0.0), 1, (0.05, 0.0, 0.0), (0.06, 0.04, 0.04)),       # wrist pitch
    ((0.1, 0.0, 0.0), 0, (0.06, 0.0, 0.0), (0.07, 0.05, 0.02)),       # flange and gripper
)
ARM_LINK_COUNT = len(ARM_LINKS)
ARM_STATICS = {  # name: (pose, half extents), as in config/arm.yaml
    'floor': ((0.0, 0.0, -0.05, 0.0, 0.0, 0.0, 1.0), (1.5, 1.5, 0.05)),
    'table': ((0.75, -0.1, 0.3, 0.0, 0.0, 0.0, 1.0), (0.3, 0.45, 0.02)),
    'shelf': ((0.1, 1.0, 0.6, 0.0, 0.0, 0.0, 1.0), (0.35, 0.12, 0.6)),
}
ARM_PERIOD_S = 8.0  # one sweep over the table, past the shelf and back


def arm_joint_angles(time_s):
    """Joint angles (rad) of the links at ``time_s``: a smooth periodic sweep (base: 0)."""
    phase = 2.0 * np.pi * time_s / ARM_PERIOD_S
    return np.array([
        0.0,
        0.25 + 0.95 * np.sin(phase),              # yaw: over the table, then to the shelf
        -0.6 + 0.25 * np.sin(2.0 * phase),        # shoulder, raised; dips twice a sweep
        0.7 + 0.3 * np.cos(phase),                # elbow
        0.8 * np.sin(3.0 * phase),                # wrist roll
        0.6 + 0.4 * np.sin(2.0 * phase + 0.5),    # wrist pitch
        0.0])


def arm(n=ARM_LINK_COUNT, seed=0):
    """Return the arm scene of config/arm.yaml (``n`` must be its link count; no randomness)."""
    if n != ARM_LINK_COUNT:
        raise ValueError('the arm has %d links, not %d' % (ARM_LINK_COUNT, n))
    statics = list(ARM_STATICS.values())
    return ArmScene('arm', np.array([pose for pose, _ in statics]),
                    np.array([extent for _, extent in statics]),
                    np.array([link[3] for link in ARM_LINKS], dtype=np.float64))


def _axis_rotation(axis, angle):
    """Return the rotation by ``angle`` about coordinate axis ``axis`` (None: identity)."""
    rotation = np.eye(3)
    if axis is not None:
        i, j = (axis + 1) % 3, (axis + 2) % 3
        c, s = np.cos(angle), np.sin(angle)
        rotation[i, i], rotation[i, j], rotation[j, i], rotation[j, j] = c, -s, s, c
    return rotation


def _quaternion(rotation):
    """Return the unit quaternion (x, y, z, w) of a rotation matrix (Shepperd's method)."""
    trace = np.trace(rotation)
    k = int(np.argmax([trace, *np.diag(rotation)]))
    if k == 0:
        w = 0.5 * np.sqrt(1.0 + trace)
        x, y, z = (rotation[2, 1] - rotation[1, 2], rotation[0, 2] - rotation[2, 0],
                   rotation[1, 0] - rotation[0, 1]) / (4.0 * w)
        return np.array([x, y, z, w])
    i = k - 1
    j, m = (i + 1) % 3, (i + 2) % 3
    q = np.empty(4)
    q[i] = 0.5 * np.sqrt(1.0 + rotation[i, i] - rotation[j, j] - rotation[m, m])
    q[j] = (rotation[j, i] + rotation[i, j]) / (4.0 * q[i])
    q[m] = (rotation[m, i] + rotation[i, m]) / (4.0 * q[i])
    q[3] = (rotation[m, j] - rotation[j, m]) / (4.0 * q[i])
    return q


SCENES = {'uniform': uniform, 'clustered': clustered, 'flying_out': flying_out,
          'paper000': paper000, 'room': room, 'arm': arm}
# Scenes whose body count is part of the scene: their default; the arm's is its only one.
SCENE_BODY_COUNTS = {'room': ROOM_DYNAMIC_COUNT, 'arm': ARM_LINK_COUNT}
FIXED_BODY_COUNTS = {'arm': ARM_LINK_COUNT}


def scene_body_count(name, bodies=None, default=1000):
    """Return the body count of scene ``name`` asked for as ``bodies``.

    None: the scene's own count (:data:`SCENE_BODY_COUNTS`), else ``default``. ValueError
    when the scene fixes its count (a robot has its links) and ``bodies`` is another one.
    """
    fixed = FIXED_BODY_COUNTS.get(name)
    if bodies is None:
        return SCENE_BODY_COUNTS.get(name, default)
    if fixed is not None and bodies != fixed:
        raise ValueError('the %s scene has %d bodies, not %d' % (name, fixed, bodies))
    return bodies


def make_scene(name, n, seed=0):
    """Return the scene called ``name`` (one of :data:`SCENES`) with ``n`` bodies."""
    if name not in SCENES:
        raise ValueError('unknown scene %r; choose one of %s' % (name, ', '.join(SCENES)))
    return SCENES[name](n, seed)
