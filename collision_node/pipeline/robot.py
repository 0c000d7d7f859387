"""A robot's collision boxes, read from a URDF (and an SRDF), and their forward kinematics.

The URDF is parsed once in Python (collision_node.pipeline.urdf, .meshes) into
:class:`RobotModel`, a named tuple of flat arrays (pinocchio's ``Model`` idea: parents,
joint placements, q indices); :func:`forward_kinematics`, a kernel other kernels may call,
walks it once per state, and :func:`lane_transforms` for several states at once, the state
innermost (the robot's pass), to the same bits.

Joints. Each link but the root hangs from one joint: link frame = parent frame * origin *
motion, the motion a turn about the unit axis (revolute, continuous) or a slide along it
(prismatic) by value = multiplier * q[q_index] + offset; an ordinary joint has multiplier 1,
offset 0 and its own entry of q, a mimic joint the entry of the joint it follows (a mimic of
a mimic composed into one affine map), a fixed joint no entry (q index -1). q holds the
moving, non-mimic joints in URDF document order.

Composition. Each link's orientation is a quaternion, its parent's times the joint's: the
origin's quaternion o for a fixed or sliding joint, and for a turn by value v about axis a,
o (a sin(v/2), cos(v/2)) = cos(v/2) o + sin(v/2) (o (a, 0)), two quaternions stored per
joint (``origin_quaternions``, ``turn_quaternions``), so a turn costs a sine, a cosine and
eight flops. The link's rotation matrix is made from its quaternion (for the translations
and the box centres), and a box's quaternion is its link's times the box's own, a product
and no conversion: a box's pose is what a pass needs only for the few boxes a cull leaves
(robot_pass.py). A product of unit quaternions drifts off unit length by about an ulp per
joint: a chain of ten stays within 1e-14 of it, the quaternion a step accepts and
normalises (obb.QUATERNION_NORM_TOLERANCE).

Geometry. Every ``<collision>`` element is one box, in document order: a ``box`` exactly, a
``cylinder`` (about its z axis) the box around it (volume ratio 4/pi), a ``sphere`` its cube
(6/pi), a ``mesh`` (scaled) an oriented box holding every vertex, never larger than the
vertices' axis-aligned box (collision_node.pipeline.meshes). ``box_volume_ratio`` is box
volume / shape volume: for a mesh, over the volume the mesh encloses (NaN for an open mesh).

Reach (``center_spheres``). A box's centre stays within a fixed distance of the origin of the
topmost turning joint on its chain, whatever the angles: that origin is fixed relative to
the link above it, and walking up from the box, the distance bound grows by each joint
origin's |xyz| (a turn keeps distances from its axis's origin). No limits are read, so the
bound holds for any q a caller passes; a sliding joint on the chain moves its link's origin
and gives no bound. Seen from two boxes' nearest common ancestor (or from the root, for a
static box), a pair whose spheres stay apart by more than the culls' reach can never be
tested, and the robot's pass leaves it out of its list (robot_pass.RobotRows).

Self-collision filter (MoveIt's rules). Two boxes are not tested when they belong to one
link, when their links are adjacent, or when the SRDF disables the pair. Adjacent: the tree
path between the two links has no link with collision geometry inside it (one joint apart,
or apart only through links without geometry: MoveIt's setup assistant joins the neighbours
of each link without geometry, and this is that rule applied until nothing changes, so a
link stands next to its nearest ancestor with geometry and to the links reached through
geometry-less ones). The SRDF's ``<disable_collisions>`` pairs are added with their reason,
``<disable_default_collisions link>`` disables the link against every link with geometry
(reason 'default'), and ``<enable_collisions>`` takes a pair back from either (as MoveIt's
allowed-collision matrix, where explicit entries beat default ones), never from adjacency.

Motion bound (``motion_radii``). Base fixed, q(s) = q0 + s (q1 - q0), s in [0, 1], with
q0 and q1 within the limits: every q(s) is too (the limits are a box, which is convex). A point
p of box b moves with dp/ds = sum_j (q1_j - q0_j) dp/dq_j, so |p(1) - p(0)| <= integral of
|dp/ds| <= sum_j |q1_j - q0_j| max_s |dp/dq_j|. Joint k of the chain above b, driven by q_j
with multiplier m_k, adds to dp/dq_j: m_k a_k x (p - o_k) when it turns (a_k its unit axis,
o_k its frame's origin), m_k a_k when it slides. |a_k x (p - o_k)| is p's distance from the
axis, at most the smaller of two reaches (_axis_reaches): |p - o_k|, at most the sum of the
translations below joint k on the chain (each joint origin's |xyz| and each prismatic joint's
largest |value| within its limits, its travel, then the box centre's offset in its link and
the box's half diagonal); and the distance from the axis of a ball that holds the box
whatever the joints below do. So motion_radii[b, j] = sum over the chain joints k driven by
q_j of |m_k| (that reach if k turns, 1 if it slides); joints off the chain contribute 0. A
continuous joint driving a prismatic mimic has an infinite travel, and so infinite radii
above it. Two boxes of the robot, seen from their links' nearest common
ancestor, move only by the joints below it (the ones above move both as one, which changes no
distance between them): their pair's radii sum each box's over those joints alone
(Robot.pair_motion_radii), much less than the two boxes' motion_radii for neighbours far
from the root.

Chord bound (``chord_turns``, ``chord_reach``). On the same straight segment a point p of box
b strays from the chord between its two ends by at most |p''| / 8 (for a piece of length h of
the segment: h² |p''| / 8, the interpolation error of a C² curve). p'' = sum over chain joints
k, l of (m_k dq_k)(m_l dq_l) d²p/dθ_k dθ_l, and each such second derivative is at most the
reach of the lower of the two joints (a turning joint below: its a × (p - o) turned by the
upper one, at most p's distance from its axis; a sliding one below: its turned axis, at most
1; a sliding one above: 0). So |p''| <= chord_reach[b] (sum_j |dq_j| chord_turns[b, j])²,
with chord_turns[b, j] the sum of |m_k| over the chain joints k driven by q_j and
chord_reach[b] the largest reach of a turning joint of the chain, as the Motion bound's
(at least 1 when one slides). A robot that turns by 0.3 rad over
a segment, 1 m from the axis, strays 1.1 cm from the chord, against 30 cm of motion: two boxes
on one side of a fixed plane at both ends of a piece, farther than that, stay on it between
(robot_bodies.first_uncleared_pieces).
"""
import math
from typing import NamedTuple

import numpy as np

from collision_node.pipeline import meshes, urdf
from collision_node.pipeline._jit import inlined_kernel, kernel
from collision_node.pipeline.flat_views import view
from collision_node.pipeline.frames import (matrix, placed, quaternion_product,
                                            rotation_from_quaternion, turned)
from collision_node.pipeline.trig import REDUCED_LIMIT, reduced_sincos, sincos

# Joint type codes in RobotModel.joint_types (continuous is revolute without limits).
FIXED = 0
REVOLUTE = 1
PRISMATIC = 2
_TYPE_CODES = {urdf.FIXED: FIXED, urdf.REVOLUTE: REVOLUTE, urdf.CONTINUOUS: REVOLUTE,
               urdf.PRISMATIC: PRISMATIC}
NO_INDEX = -1  # q_indices of a fixed joint, parents of the root link
ADJACENT = 'adjacent'
DEFAULT = 'default'
IDENTITY_POSE = np.array([0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0])
# How conservative each primitive's box is: box volume / shape volume.
VOLUME_RATIOS = {urdf.BOX: 1.0, urdf.CYLINDER: 4.0 / math.pi, urdf.SPHERE: 6.0 / math.pi}


class RobotModel(NamedTuple):
    """Everything the forward kinematics reads, as flat contiguous arrays (L links, B boxes).

    Links are indexed as in ``Robot.link_names`` (URDF document order); ``order`` lists them
    parents first. Row l of the joint arrays is the joint whose child is link l (the root's
    row is unused: NO_INDEX parent, fixed).
    """

    order: np.ndarray                # (L,) int64
    parents: np.ndarray              # (L,) int64, NO_INDEX for the root
    origin_translations: np.ndarray  # (L, 3) joint origin in the parent's frame
    origin_rotations: np.ndarray     # (L, 3, 3)
    origin_quaternions: np.ndarray   # (L, 4) x y z w of origin_rotations
    turn_quaternions: np.ndarray     # (L, 4) origin_quaternions times (axis, 0)
    joint_types: np.ndarray          # (L,) int64: FIXED, REVOLUTE, PRISMATIC
    axes: np.ndarray                 # (L, 3) unit axis in the joint's frame
    q_indices: np.ndarray            # (L,) int64: the entry of q driving the joint
    multipliers: np.ndarray          # (L,) joint value = multiplier * q + offset
    offsets: np.ndarray              # (L,)
    joint_limits: np.ndarray         # (dof, 2) lower, upper (continuous: -inf, inf)
    box_links: np.ndarray            # (B,) int64
    box_translations: np.ndarray     # (B, 3) box centre in its link's frame
    box_rotations: np.ndarray        # (B, 3, 3) box axes in its link's frame
    box_quaternions: np.ndarray      # (B, 4) x y z w of box_rotations
    half_extents: np.ndarray         # (B, 3)
    motion_radii: np.ndarray         # (B, dof) module docstring, Motion bound


# RobotModel's fields in the two flat arrays of pack_model, in order.
INT_FIELDS = ('order', 'parents', 'joint_types', 'q_indices', 'box_links')
FLOAT_FIELDS = ('origin_translations', 'origin_rotations', 'origin_quaternions',
                'turn_quaternions', 'axes', 'multipliers', 'offsets', 'joint_limits',
                'box_translations', 'box_rotations', 'box_quaternions', 'half_extents',
                'motion_radii')


def pack_model(model):
    """Return ``model`` as two flat arrays (int64, float64) for kernels called from Python.

    numba unboxes every array argument on every call (about 0.14 µs each: the Panda's model
    is 15 arrays, 2 µs of a 5 µs check); two flat arrays enter at once, and
    :func:`unpack_model` makes views of them a RobotModel again at no cost (pynndescent
    hands its trees to numba as flat arrays alike). The ints start with the counts of links,
    boxes and joints.
    """
    counts = [len(model.parents), len(model.half_extents), len(model.joint_limits)]
    ints = np.concatenate([counts] + [getattr(model, name) for name in INT_FIELDS])
    floats = np.concatenate([np.ravel(getattr(model, name)) for name in FLOAT_FIELDS])
    return ints.astype(np.int64), floats


class Robot:
    """A robot's collision boxes and their poses for joint values q (module docstring)."""

    def __init__(self, joint_names, link_names, box_shapes, box_volume_ratio,
                 collision_origins, disabled_link_pairs, model, travels):
        """Hold a built model; use :meth:`from_urdf`."""
        self.joint_names = joint_names
        self.link_names = link_names
        self.box_shapes = box_shapes
        self.box_volume_ratio = box_volume_ratio
        # The <collision> element's own <origin> per box, in its link's frame, as a pose: the
        # box pose is this composed with the box's offset in the shape (a mesh's box).
        self.collision_origins = collision_origins
        self.disabled_link_pairs = disabled_link_pairs
        self.model = model
        self.box_link_index = model.box_links
        self.box_links = tuple(link_names[link] for link in model.box_links)
        self.half_extents = model.half_extents
        self.joint_limits = model.joint_limits
        self.allowed_box_pairs = _allowed_box_pairs(self.box_links, disabled_link_pairs)
        self._travels = travels  # per link: the largest |value| of its prismatic joint
        self.chord_turns, self.chord_reach = _chord_bound(model, travels)
        self._center_gaps = {}  # (box a, box b): center_gaps, once asked

    @classmethod
    def from_urdf(cls, urdf_source, srdf=None, package_paths=()):
        """Build the robot from a URDF (path or XML text) and an optional SRDF (likewise).

        ``package_paths``: folders searched for ``pkg/path`` when a ``package://pkg/path``
        mesh is not in the ament index. Raises ValueError naming what is wrong.
        """
        description = urdf.read_urdf(urdf_source)
        rules = urdf.read_srdf(srdf) if srdf is not None else urdf.CollisionRules((), (), ())
        links = description.links
        index = {name: number for number, name in enumerate(links)}
        joint_of = _joints_by_child(description.joints)
        order = _parents_first(links, description.joints, joint_of)
        drivers = _drivers(description.joints)
        joint_names = tuple(joint.name for joint in description.joints if joint.name in drivers
                            and drivers[joint.name][0] == joint.name)
        q_index = {name: number for number, name in enumerate(joint_names)}
        count = len(links)
        parents = np.full(count, NO_INDEX, np.int64)
        translations = np.zeros((count, 3))
        rotations = np.tile(np.eye(3), (count, 1, 1))
        types = np.zeros(count, np.int64)
        axes = np.zeros((count, 3))
        q_indices = np.full(count, NO_INDEX, np.int64)
        multipliers = np.ones(count)
        offsets = np.zeros(count)
        travels = np.zeros(count)  # the largest |value| of each prismatic joint
        limits = np.empty((len(joint_names), 2))
        by_name = {joint.name: joint for joint in description.joints}
        for name, number in q_index.items():
            limits[number] = by_name[name].lower, by_name[name].upper
        for link, joint in joint_of.items():
            row = index[link]
            parents[row] = index[joint.parent]
            translations[row] = joint.origin.xyz
            rotations[row] = rotation_from_rpy(*joint.origin.rpy)
            types[row] = _TYPE_CODES[joint.kind]
            axes[row] = joint.axis
            if joint.name in drivers:
                driver, multipliers[row], offsets[row] = drivers[joint.name]
                q_indices[row] = q_index[driver]
                if types[row] == PRISMATIC:
                    ends = multipliers[row] * limits[q_indices[row]] + offsets[row]
                    with np.errstate(invalid='ignore'):  # 0 * inf: a zero multiplier
                        travels[row] = np.nan_to_num(np.abs(ends), nan=abs(offsets[row])).max()
        boxes = _boxes(description, package_paths)
        box_links = np.array([index[element.link] for element in description.collisions],
                             np.int64)
        box_translations = np.array([box[0] for box in boxes]).reshape(-1, 3)
        box_rotations = np.array([box[1] for box in boxes]).reshape(-1, 3, 3)
        half_extents = np.array([box[2] for box in boxes]).reshape(-1, 3)
        origin_quaternions = _quaternions(rotations)
        turn_quaternions = np.array([quaternion_product(tuple(o), (*axis, 0.0))
                                     for o, axis in zip(origin_quaternions, axes)])
        model = RobotModel(
            np.array(order, np.int64), parents, translations, rotations, origin_quaternions,
            turn_quaternions, types, axes, q_indices, multipliers, offsets, limits, box_links,
            box_translations, box_rotations, _quaternions(box_rotations), half_extents, None)
        model = model._replace(motion_radii=_motion_radii(model, travels))
        origins = np.array([pose_from(rotation_from_rpy(*element.origin.rpy),
                                      element.origin.xyz)
                            for element in description.collisions]).reshape(-1, 7)
        geometric = {element.link for element in description.collisions}
        disabled = _disabled_link_pairs(links, joint_of, geometric, rules)
        return cls(joint_names, links, tuple(element.shape for element in description.collisions),
                   np.array([box[3] for box in boxes]), origins, disabled, model, travels)

    def pair_motion_radii(self, first, second):
        """Return radii (P, dof) bounding how fast the boxes of each pair can close in.

        Over a straight joint-space step dq, the distance between boxes ``first[p]`` and
        ``second[p]`` changes by at most sum_j |dq_j| radii[p, j] (module docstring, Motion
        bound). ``second[p]`` -1: a static box, and the radii are ``first[p]``'s. Two boxes of
        the robot: only the joints below their links' nearest common ancestor count, for
        each box; the joints above it move both boxes as one, which leaves their distance
        as it is.
        """
        model = self.model
        radii = model.motion_radii[first]
        for p in np.flatnonzero(np.asarray(second) >= 0):
            a, b = first[p], second[p]
            above = _common_ancestor(model.parents, model.box_links[a], model.box_links[b])
            radii[p] = _chain_radii(model, self._travels, a, above) \
                + _chain_radii(model, self._travels, b, above)
        return radii

    def center_spheres(self, first, above, base_pose=IDENTITY_POSE):
        """Return (centres (P, 3), reaches (P,)): where box ``first[p]``'s centre can be.

        For every joint value (limits or not), the centre lies within ``reaches[p]`` of
        ``centres[p]``, a point fixed relative to link ``above[p]`` (NO_INDEX: the root), given
        at q = 0 in the frame the root link is at ``base_pose`` in (module docstring, Reach).
        """
        model, frames = self.model, self._link_frames(np.zeros(self.dof), base_pose)
        spheres = [_center_sphere(model, self._travels, frames, box, link)
                   for box, link in zip(first, above)]
        return (np.array([sphere[0] for sphere in spheres]).reshape(-1, 3),
                np.array([sphere[1] for sphere in spheres]))

    def center_gaps(self, first, second):
        """Return (P,): a lower bound on the distance between two boxes' centres, every q.

        Boxes ``first[p]`` and ``second[p]`` of the robot, seen from their links' nearest
        common ancestor: the distance between their spheres (:meth:`center_spheres`). Kept
        per pair: a scene's every version asks again.
        """
        parents, box_links = self.model.parents, self.model.box_links
        pairs = list(zip(np.asarray(first).tolist(), np.asarray(second).tolist()))
        new = [pair for pair in dict.fromkeys(pairs) if pair not in self._center_gaps]
        if new:
            a, b = np.array(new, np.int64).reshape(-1, 2).T
            above = [_common_ancestor(parents, box_links[i], box_links[j]) for i, j in new]
            centres_a, reaches_a = self.center_spheres(a, above)
            centres_b, reaches_b = self.center_spheres(b, above)
            gaps = np.linalg.norm(centres_a - centres_b, axis=1) - reaches_a - reaches_b
            self._center_gaps.update(zip(new, gaps.tolist()))
        return np.array([self._center_gaps[pair] for pair in pairs])

    def _link_frames(self, q, base_pose):
        """Return the link frames (rotations, translations) at q, the root at ``base_pose``."""
        rotations, translations, quaternions = link_frames(self.model)
        link_transforms(self.model, np.asarray(base_pose, np.float64), q, rotations,
                        translations, quaternions)
        return rotations, translations

    @property
    def dof(self):
        """Return the length of q."""
        return len(self.joint_names)

    def box_poses(self, q):
        """Return the box poses (B, 7) for q (dof,), or (K, B, 7) for q (K, dof).

        Poses are x y z qx qy qz qw in the root link's frame. ValueError for a q of the wrong
        shape or with a NaN or Inf value.
        """
        states = self._states(q)
        out = np.empty((len(states), len(self.box_links), 7))
        box_poses_of_states(self.model, IDENTITY_POSE, states, out)
        return out[0] if np.ndim(q) == 1 else out

    def link_poses(self, q):
        """Return the link frames' poses (L, 7) for q (dof,), in ``link_names`` order."""
        state = self._states(q)
        if len(state) != 1 or np.ndim(q) != 1:
            raise ValueError('link_poses takes one state q of shape (%d,)' % self.dof)
        rotations, translations = self._link_frames(state[0], IDENTITY_POSE)
        return np.array([pose_from(rotations[link], translations[link])
                         for link in range(len(self.link_names))])

    def checked_states(self, q):
        """Return q (dof,) or (K, dof) as (K, dof) float64; ValueError naming what is wrong.

        The check every method taking q makes first: shape, then NaN or Inf (state, joint).
        """
        return self._states(q)

    def _states(self, q):
        """Return q as a (K, dof) float64 array the kernels take; ValueError naming what is wrong.

        On the path of every single-state check: the sum finds a NaN or Inf in one pass
        (an overflow to Inf only sends it to the exact search, which then finds nothing).
        """
        states = np.asarray(q, dtype=np.float64)
        if states.ndim == 1:
            states = states.reshape(1, -1)
        if states.ndim != 2 or states.shape[1] != self.dof:
            raise ValueError('q must have shape (%d,) or (K, %d) (joints %s), got %s'
                             % (self.dof, self.dof, ', '.join(self.joint_names),
                                np.shape(q)))
        if not math.isfinite(states.sum()):
            bad = np.argwhere(~np.isfinite(states))
            if len(bad):
                raise ValueError('q has a NaN or Inf value: state %d, joint %r'
                                 % (bad[0][0], self.joint_names[bad[0][1]]))
        # Writable too: numba compiles a second signature for a read-only array (a message's).
        return np.require(states, np.float64, ['C', 'A', 'W'])


def rotation_from_rpy(roll, pitch, yaw):
    """Return URDF's rotation of roll, pitch, yaw: Rz(yaw) Ry(pitch) Rx(roll)."""
    cr, sr, cp, sp, cy, sy = (math.cos(roll), math.sin(roll), math.cos(pitch),
                              math.sin(pitch), math.cos(yaw), math.sin(yaw))
    return np.array([[cy * cp, cy * sp * sr - sy * cr, cy * sp * cr + sy * sr],
                     [sy * cp, sy * sp * sr + cy * cr, sy * sp * cr - cy * sr],
                     [-sp, cp * sr, cp * cr]])


def pose_from(rotation, translation):
    """Return the pose (7,) x y z qx qy qz qw of a rotation matrix and a translation."""
    pose = np.empty(7)
    pose[:3] = translation
    pose[3:] = quaternion_from_rotation(
        rotation[0, 0], rotation[0, 1], rotation[0, 2], rotation[1, 0], rotation[1, 1],
        rotation[1, 2], rotation[2, 0], rotation[2, 1], rotation[2, 2])
    return pose


def _quaternions(rotations):
    """Return the unit quaternions (N, 4) of rotation matrices (N, 3, 3)."""
    return np.array([quaternion_from_rotation(*r.ravel()) for r in rotations]).reshape(-1, 4)


def _joints_by_child(joints):
    """Return {child link: its joint}; ValueError for a link that two joints hold."""
    joint_of = {}
    for joint in joints:
        if joint.child in joint_of:
            raise ValueError('URDF: link %r is the child of two joints, %r and %r'
                             % (joint.child, joint_of[joint.child].name, joint.name))
        joint_of[joint.child] = joint
    return joint_of


def _parents_first(links, joints, joint_of):
    """Return the link indices, each after its parent; ValueError unless links form a tree."""
    roots = [name for name in links if name not in joint_of]
    if len(roots) != 1:
        raise ValueError('URDF: the links must form one tree with one root; %s'
                         % ('roots: %s' % ', '.join(roots) if roots
                            else 'every link has a parent (a cycle)'))
    children = {name: [] for name in links}
    for joint in joints:
        children[joint.parent].append(joint.child)
    index = {name: number for number, name in enumerate(links)}
    order, stack = [], [roots[0]]
    while stack:
        name = stack.pop()
        order.append(index[name])
        stack.extend(reversed(children[name]))
    if len(order) != len(links):
        cut = sorted(set(links) - {links[number] for number in order})
        raise ValueError('URDF: links %s are not reached from the root %r (a cycle)'
                         % (', '.join(cut), roots[0]))
    return order


def _drivers(joints):
    """Return {moving joint: (the joint of q driving it, multiplier, offset)}.

    A mimic of a mimic is composed into one affine map of the joint at the end of the chain;
    a mimic of a fixed or unknown joint, or a cycle of mimics, is a ValueError.
    """
    by_name = {joint.name: joint for joint in joints}
    drivers = {}
    for joint in joints:
        if joint.kind == urdf.FIXED:
            continue
        multiplier, offset, current, seen = 1.0, 0.0, joint, [joint.name]
        while current.mimic:
            followed = by_name.get(current.mimic)
            if followed is None or followed.kind == urdf.FIXED:
                raise ValueError('joint %r: <mimic> names %r, which is %s' % (
                    current.name, current.mimic,
                    'not a joint' if followed is None else 'a fixed joint'))
            if followed.name in seen:
                raise ValueError('joint %r: mimic joints follow each other in a cycle: %s'
                                 % (joint.name, ' -> '.join(seen + [followed.name])))
            # value = m * (m' * q + o') + o
            multiplier, offset = multiplier * current.multiplier, \
                multiplier * current.offset + offset
            current = followed
            seen.append(current.name)
        drivers[joint.name] = (current.name, multiplier, offset)
    return drivers


def _boxes(description, package_paths):
    """Return (centre, rotation, half extents, volume ratio) per collision element."""
    boxes, fitted = [], {}
    for element in description.collisions:
        rotation = rotation_from_rpy(*element.origin.rpy)
        origin = np.array(element.origin.xyz)
        if element.shape == urdf.MESH:
            path = meshes.resolve(element.uri, element.link, description.directory,
                                  package_paths)
            if path not in fitted:  # one file is often named by several links
                fitted[path] = meshes.read_vertices(path, element.link, element.uri)
            vertices, volume = fitted[path]
            box = meshes.fit_box(vertices, element.size, volume)
            ratio = 8.0 * np.prod(box.half_extents) / box.mesh_volume \
                if box.mesh_volume > 0.0 else np.nan
            boxes.append((origin + rotation @ box.center, rotation @ box.rotation,
                          box.half_extents, ratio))
            continue
        if element.shape == urdf.BOX:
            half = 0.5 * np.array(element.size)
        elif element.shape == urdf.CYLINDER:
            radius, length = element.size
            half = np.array([radius, radius, 0.5 * length])
        else:
            half = np.full(3, element.size[0])
        boxes.append((origin, rotation, half, VOLUME_RATIOS[element.shape]))
    return boxes


def _motion_radii(model, travels):
    """Return motion_radii (B, dof): the module docstring's Motion bound."""
    radii = np.zeros((len(model.box_links), len(model.joint_limits)))
    for box in range(len(model.box_links)):
        radii[box] = _chain_radii(model, travels, box, NO_INDEX)
    return radii


def _common_ancestor(parents, first, second):
    """Return the nearest link that is ``first`` or above it and ``second`` or above it."""
    chain = set()
    while first != NO_INDEX:
        chain.add(first)
        first = parents[first]
    while second not in chain:
        second = parents[second]
    return second


def _chord_bound(model, travels):
    """Return (chord_turns (B, dof), chord_reach (B,)): the module docstring's Chord bound."""
    turns = np.zeros((len(model.box_links), len(model.joint_limits)))
    reach = np.zeros(len(model.box_links))
    for box in range(len(model.box_links)):
        for link, from_axis in _axis_reaches(model, travels, box, NO_INDEX):
            turns[box, model.q_indices[link]] += abs(model.multipliers[link])
            reach[box] = max(reach[box], from_axis)
    return turns, reach


def _chain_radii(model, travels, box, above):
    """Return the Motion bound's radii (dof,) of ``box`` for the joints below link ``above``.

    ``above`` NO_INDEX: every joint up to the root. An ancestor link of the box's link: only
    the joints between them, the ones that move the box relative to that link.
    """
    radii = np.zeros(len(model.joint_limits))
    for link, from_axis in _axis_reaches(model, travels, box, above):
        radii[model.q_indices[link]] += abs(model.multipliers[link]) * from_axis
    return radii


def _axis_reaches(model, travels, box, above):
    """Yield (link, reach) for each moving joint from box ``box``'s link up to link ``above``.

    A turning joint's ``reach`` bounds the distance from its axis to any point of the box,
    whatever the joints between them do: the smaller of two bounds. The walk (_walk_up) bounds
    the distance from the joint's origin. The ball: every point of the box lies in a ball,
    first its half diagonal about its centre, in its link's frame. A turn about an axis
    through the link's origin keeps the centre's part along the axis and sweeps the rest, at
    its distance d from the axis, around it: the ball's centre moves onto the axis and its
    radius grows by d, and before that the joint's reach is d plus the radius. A slide grows
    the radius by its travel (and its reach is 1: its axis, moved by a unit of q); a joint's
    origin carries the ball into the parent's frame. (The walk is the tighter one for a
    centre far off an axis and near the next: the ball's centre then jumps onto the axis.)
    """
    centre, radius = model.box_translations[box], float(np.linalg.norm(model.half_extents[box]))
    for link, walked in _walk_up(model, travels, box, above, _box_reach(model, box)):
        kind = model.joint_types[link]
        if kind == REVOLUTE:
            along = (centre @ model.axes[link]) * model.axes[link]
            off = float(np.linalg.norm(centre - along))
            yield link, min(walked, off + radius)
            centre, radius = along, radius + off
        elif kind == PRISMATIC:
            yield link, 1.0
            radius += travels[link]
        centre = model.origin_translations[link] + model.origin_rotations[link] @ centre


def _box_reach(model, box):
    """Return how far any point of box ``box`` lies from its link's origin, at most.

    The reach from each joint's origin on the chain then adds the walk up to it (_walk_up).
    """
    return np.linalg.norm(model.box_translations[box]) + np.linalg.norm(model.half_extents[box])


def _walk_up(model, travels, box, above, start):
    """Yield (link, walked) from box ``box``'s link up to link ``above`` (NO_INDEX: the root).

    ``walked`` bounds the distance from the link's origin to what ``start`` bounds it from
    the box's link's origin: each joint on the way adds its origin's |xyz| and its travel.
    """
    link, walked = model.box_links[box], start
    while link != above and model.parents[link] != NO_INDEX:
        yield link, walked
        walked += np.linalg.norm(model.origin_translations[link]) + travels[link]
        link = model.parents[link]


def _center_sphere(model, travels, frames, box, above):
    """Return (centre, reach) of :meth:`Robot.center_spheres` for one box (module docstring)."""
    rotations, translations = frames
    link = model.box_links[box]
    centre = translations[link] + rotations[link] @ model.box_translations[box]
    reach = 0.0
    for link, walked in _walk_up(model, travels, box, above,
                                 np.linalg.norm(model.box_translations[box])):
        kind = model.joint_types[link]
        if kind == PRISMATIC:  # its link's origin slides: no fixed point bounds the box
            return centre, math.inf
        if kind == REVOLUTE:  # its link's origin is fixed relative to the parent link
            centre, reach = translations[link], walked
    return centre, reach


def _disabled_link_pairs(links, joint_of, geometric, rules):
    """Return {(link a, link b) sorted: reason} of the link pairs never tested."""
    for name in [name for pair in rules.disabled_pairs for name in pair[:2]] \
            + list(rules.disabled_by_default) \
            + [name for pair in rules.enabled_pairs for name in pair]:
        if name not in links:
            raise ValueError('SRDF: link %r is not a link of the URDF' % name)
    disabled = {}
    # Each geometric link's chain up: the links without geometry above it, then the first
    # link with geometry (if any). Two chains sharing a link without geometry, or one ending
    # at the other link, make the pair adjacent (module docstring).
    met = {}
    for link in sorted(geometric):
        above = joint_of[link].parent if link in joint_of else None
        while above is not None and above not in geometric:
            for other in met.get(above, ()):
                disabled[tuple(sorted((link, other)))] = ADJACENT
            met.setdefault(above, []).append(link)
            above = joint_of[above].parent if above in joint_of else None
        if above is not None:
            disabled[tuple(sorted((link, above)))] = ADJACENT
    for first, second, reason in rules.disabled_pairs:
        disabled.setdefault(tuple(sorted((first, second))), reason)
    for link in rules.disabled_by_default:
        for other in sorted(geometric - {link}):
            disabled.setdefault(tuple(sorted((link, other))), DEFAULT)
    for pair in rules.enabled_pairs:
        pair = tuple(sorted(pair))
        if disabled.get(pair, ADJACENT) != ADJACENT:
            del disabled[pair]
    return disabled


def _allowed_box_pairs(box_links, disabled):
    """Return the (P, 2) box pairs i < j to test, in lexicographic order."""
    pairs = [(i, j) for i in range(len(box_links)) for j in range(i + 1, len(box_links))
             if box_links[i] != box_links[j]
             and tuple(sorted((box_links[i], box_links[j]))) not in disabled]
    return np.array(pairs, np.int64).reshape(-1, 2)


@kernel
def quaternion_from_rotation(r00, r01, r02, r10, r11, r12, r20, r21, r22):
    """Return the unit quaternion (x, y, z, w) of a rotation matrix (Shepperd's method).

    The largest of w, x, y, z is found from the diagonal first, so the square root is of a
    number >= 1 and the divisions are well conditioned for any rotation.
    """
    trace = r00 + r11 + r22
    if trace >= r00 and trace >= r11 and trace >= r22:
        s = 2.0 * math.sqrt(1.0 + trace)
        x, y, z, w = (r21 - r12) / s, (r02 - r20) / s, (r10 - r01) / s, 0.25 * s
    elif r00 >= r11 and r00 >= r22:
        s = 2.0 * math.sqrt(1.0 + r00 - r11 - r22)
        x, y, z, w = 0.25 * s, (r01 + r10) / s, (r02 + r20) / s, (r21 - r12) / s
    elif r11 >= r22:
        s = 2.0 * math.sqrt(1.0 + r11 - r00 - r22)
        x, y, z, w = (r01 + r10) / s, 0.25 * s, (r12 + r21) / s, (r02 - r20) / s
    else:
        s = 2.0 * math.sqrt(1.0 + r22 - r00 - r11)
        x, y, z, w = (r02 + r20) / s, (r12 + r21) / s, 0.25 * s, (r10 - r01) / s
    norm = math.sqrt(x * x + y * y + z * z + w * w)
    return x / norm, y / norm, z / norm, w / norm


@kernel
def link_transforms(model, base_pose, q, rotations, translations, quaternions):
    """Write every link frame (rotation (L, 3, 3), translation (L, 3), quaternion (L, 4)).

    For one state q (module docstring, Composition). The root link's frame is ``base_pose``
    (its quaternion normalised here). No allocation: a batch of states reuses the caller's
    arrays. :func:`lane_transforms` computes the same frames, bit for bit, for many states.

    Two loops: the joints' own quaternions first, each independent of the others, so that
    their sines and cosines overlap; then the chain, each link after its parent.
    """
    # Entry by entry, never through a view or a name bound to an array in the loops: each
    # costs a reference count, more than the arithmetic here.
    for link in range(model.parents.shape[0]):
        if model.joint_types[link] == REVOLUTE:
            s, c = sincos(0.5 * _joint_value(model, link, q[model.q_indices[link]]))
            own = _own_quaternion(model, link, s, c)
        else:
            own = _origin_quaternion(model, link)
        quaternions[link, 0], quaternions[link, 1] = own[0], own[1]
        quaternions[link, 2], quaternions[link, 3] = own[2], own[3]
    for k in range(model.order.shape[0]):
        link = model.order[k]
        parent = model.parents[link]
        if parent == NO_INDEX:
            quaternion = _unit(base_pose)
            _write_frame(link, quaternion, rotation_from_quaternion(*quaternion),
                         (base_pose[0], base_pose[1], base_pose[2]), rotations, translations,
                         quaternions)
            continue
        quaternion, rotation, translation = _chained(
            (quaternions[parent, 0], quaternions[parent, 1], quaternions[parent, 2],
             quaternions[parent, 3]), matrix(rotations, parent),
            (translations[parent, 0], translations[parent, 1], translations[parent, 2]),
            (quaternions[link, 0], quaternions[link, 1], quaternions[link, 2],
             quaternions[link, 3]), _origin_translation(model, link))
        _write_frame(link, quaternion, rotation, translation, rotations, translations,
                     quaternions)
        if model.joint_types[link] == PRISMATIC:
            value = _joint_value(model, link, q[model.q_indices[link]])
            slide = _slide(model, link, rotation, value)
            translations[link, 0] += slide[0]
            translations[link, 1] += slide[1]
            translations[link, 2] += slide[2]


@inlined_kernel
def lane_transforms(model, base_pose, states, first, lanes, halves, quaternions, rotations,
                    translations):
    """Write the link frames of states ``[first, first + lanes)`` of ``states`` (K, dof).

    :func:`link_transforms`' frames, bit for bit (the same helpers, in the same order), laid
    out with the state last: ``quaternions`` (L, 4, LANES), ``rotations`` (L, 9, LANES)
    (row-major), ``translations`` (L, 3, LANES), lane w the state first + w; ``halves``
    (LANES,) scratch. The state innermost lets LLVM run the lanes at once (a loop over a
    robot's joints cannot: each link waits for its parent), and one test of the lanes' angles
    lets their sines and cosines vectorize too (trig.py).
    """
    for link in range(model.parents.shape[0]):
        if model.joint_types[link] == REVOLUTE:
            reducible = True
            for w in range(lanes):
                entry = states[first + w, model.q_indices[link]]
                halves[w] = 0.5 * _joint_value(model, link, entry)
                reducible &= abs(halves[w]) <= REDUCED_LIMIT
            if reducible:  # a loop without a call: vectorized
                for w in range(lanes):
                    s, c = reduced_sincos(halves[w])
                    _write_quaternion(link, w, _own_quaternion(model, link, s, c), quaternions)
            else:
                for w in range(lanes):
                    s, c = sincos(halves[w])
                    _write_quaternion(link, w, _own_quaternion(model, link, s, c), quaternions)
        else:
            own = _origin_quaternion(model, link)
            for w in range(lanes):
                _write_quaternion(link, w, own, quaternions)
    for k in range(model.order.shape[0]):
        link = model.order[k]
        parent = model.parents[link]
        if parent == NO_INDEX:
            quaternion = _unit(base_pose)
            rotation = rotation_from_quaternion(*quaternion)
            for w in range(lanes):
                _write_lane(link, w, quaternion, rotation,
                            (base_pose[0], base_pose[1], base_pose[2]), quaternions, rotations,
                            translations)
            continue
        origin = _origin_translation(model, link)
        for w in range(lanes):
            quaternion, rotation, translation = _chained(
                lane_quaternion(quaternions, parent, w), lane_rotation(rotations, parent, w),
                lane_vector(translations, parent, w), lane_quaternion(quaternions, link, w),
                origin)
            _write_lane(link, w, quaternion, rotation, translation, quaternions, rotations,
                        translations)
        if model.joint_types[link] == PRISMATIC:
            for w in range(lanes):
                value = _joint_value(model, link, states[first + w, model.q_indices[link]])
                slide = _slide(model, link, lane_rotation(rotations, link, w), value)
                translations[link, 0, w] += slide[0]
                translations[link, 1, w] += slide[1]
                translations[link, 2, w] += slide[2]


@inlined_kernel
def _joint_value(model, link, entry):
    """Return the value of a moving link's joint: multiplier * ``entry`` (q's) + offset."""
    return model.multipliers[link] * entry + model.offsets[link]


@inlined_kernel
def _origin_quaternion(model, link):
    """Return the quaternion of a link's joint origin (x, y, z, w)."""
    o = model.origin_quaternions
    return o[link, 0], o[link, 1], o[link, 2], o[link, 3]


@inlined_kernel
def _origin_translation(model, link):
    """Return the translation of a link's joint origin, in its parent's frame."""
    o = model.origin_translations
    return o[link, 0], o[link, 1], o[link, 2]


@inlined_kernel
def _own_quaternion(model, link, s, c):
    """Return a turning joint's quaternion: its origin's turned by the angle of sine s, cosine c.

    ``s``, ``c``: the sine and cosine of half the joint's value (module docstring,
    Composition).
    """
    o, t = model.origin_quaternions, model.turn_quaternions
    return (c * o[link, 0] + s * t[link, 0], c * o[link, 1] + s * t[link, 1],
            c * o[link, 2] + s * t[link, 2], c * o[link, 3] + s * t[link, 3])


@inlined_kernel
def _unit(base_pose):
    """Return the base pose's quaternion normalised."""
    x, y, z, w = base_pose[3], base_pose[4], base_pose[5], base_pose[6]
    norm = math.sqrt(x * x + y * y + z * z + w * w)
    return x / norm, y / norm, z / norm, w / norm


@inlined_kernel
def _chained(parent_quaternion, parent_rotation, parent_translation, own, origin):
    """Return a link's (quaternion, rotation, translation) before any slide of its joint.

    From its parent's frame (quaternion, row-major 9-tuple rotation, translation), its
    joint's own quaternion and its origin's translation in the parent's frame.
    """
    quaternion = quaternion_product(parent_quaternion, own)
    return (quaternion, rotation_from_quaternion(*quaternion),
            placed(parent_rotation, parent_translation, origin))


@inlined_kernel
def _slide(model, link, rotation, value):
    """Return a sliding joint's move by ``value`` along its axis, in the link's frame."""
    a = model.axes
    return (value * (rotation[0] * a[link, 0] + rotation[1] * a[link, 1]
                     + rotation[2] * a[link, 2]),
            value * (rotation[3] * a[link, 0] + rotation[4] * a[link, 1]
                     + rotation[5] * a[link, 2]),
            value * (rotation[6] * a[link, 0] + rotation[7] * a[link, 1]
                     + rotation[8] * a[link, 2]))


@inlined_kernel
def _moved(rotations, translations, link, t):
    """Return the point ``t`` (3-tuple) of link ``link``'s frame in the root's frame."""
    return placed(matrix(rotations, link),
                  (translations[link, 0], translations[link, 1], translations[link, 2]), t)


@inlined_kernel
def _write_frame(link, quaternion, r, translation, rotations, translations, quaternions):
    """Write a link's frame: its quaternion, its rotation matrix (row-major) and translation."""
    rotations[link, 0, 0], rotations[link, 0, 1], rotations[link, 0, 2] = r[0], r[1], r[2]
    rotations[link, 1, 0], rotations[link, 1, 1], rotations[link, 1, 2] = r[3], r[4], r[5]
    rotations[link, 2, 0], rotations[link, 2, 1], rotations[link, 2, 2] = r[6], r[7], r[8]
    translations[link, 0], translations[link, 1], translations[link, 2] = translation
    quaternions[link, 0], quaternions[link, 1] = quaternion[0], quaternion[1]
    quaternions[link, 2], quaternions[link, 3] = quaternion[2], quaternion[3]


@inlined_kernel
def _write_lane(link, w, quaternion, rotation, translation, quaternions, rotations,
                translations):
    """Write a link's frame for lane ``w`` (lane_transforms' layout)."""
    _write_quaternion(link, w, quaternion, quaternions)
    r = rotation
    rotations[link, 0, w], rotations[link, 1, w], rotations[link, 2, w] = r[0], r[1], r[2]
    rotations[link, 3, w], rotations[link, 4, w], rotations[link, 5, w] = r[3], r[4], r[5]
    rotations[link, 6, w], rotations[link, 7, w], rotations[link, 8, w] = r[6], r[7], r[8]
    translations[link, 0, w], translations[link, 1, w] = translation[0], translation[1]
    translations[link, 2, w] = translation[2]


@inlined_kernel
def _write_quaternion(link, w, quaternion, quaternions):
    """Write a link's quaternion for lane ``w`` (lane_transforms' layout)."""
    quaternions[link, 0, w], quaternions[link, 1, w] = quaternion[0], quaternion[1]
    quaternions[link, 2, w], quaternions[link, 3, w] = quaternion[2], quaternion[3]


@inlined_kernel
def lane_quaternion(quaternions, link, w):
    """Return a link's quaternion in lane ``w`` (lane_transforms' layout)."""
    return (quaternions[link, 0, w], quaternions[link, 1, w], quaternions[link, 2, w],
            quaternions[link, 3, w])


@inlined_kernel
def lane_rotation(rotations, link, w):
    """Return a link's rotation (row-major 9-tuple) in lane ``w`` (lane_transforms' layout)."""
    return (rotations[link, 0, w], rotations[link, 1, w], rotations[link, 2, w],
            rotations[link, 3, w], rotations[link, 4, w], rotations[link, 5, w],
            rotations[link, 6, w], rotations[link, 7, w], rotations[link, 8, w])


@inlined_kernel
def lane_vector(vectors, row, w):
    """Return row ``row``'s 3-vector in lane ``w`` (lane_transforms' layout)."""
    return vectors[row, 0, w], vectors[row, 1, w], vectors[row, 2, w]


@kernel
def forward_kinematics(model, base_pose, q, out, rotations, translations, quaternions):
    """Write the (B, 7) box poses of one state ``q`` (dof,) into ``out``.

    ``base_pose`` (7,) is the root link's pose in the world; poses are x y z qx qy qz qw,
    the quaternions unit to rounding (module docstring, Composition). ``rotations`` (L, 3, 3),
    ``translations`` (L, 3) and ``quaternions`` (L, 4) are scratch for the link frames
    (:func:`link_frames` makes them). Never raises: the caller checks q (finite, length dof).
    """
    link_transforms(model, base_pose, q, rotations, translations, quaternions)
    for b in range(model.box_links.shape[0]):
        out[b, 0], out[b, 1], out[b, 2] = box_center(model, rotations, translations, b)
        out[b, 3], out[b, 4], out[b, 5], out[b, 6] = box_quaternion(model, quaternions, b)


@inlined_kernel
def box_frame(model, rotations, translations, b):
    """Return box b's centre (3-tuple) and rotation (row-major 9-tuple) from the link frames."""
    return box_center(model, rotations, translations, b), box_rotation(model, rotations, b)


@inlined_kernel
def box_center(model, rotations, translations, b):
    """Return box b's centre (3-tuple) from the link frames.

    Indexed entry by entry, never through a row view or a name bound to an array: each costs
    a reference count, more than the arithmetic here.
    """
    return _moved(rotations, translations, model.box_links[b],
                  (model.box_translations[b, 0], model.box_translations[b, 1],
                   model.box_translations[b, 2]))


@inlined_kernel
def box_quaternion(model, quaternions, b):
    """Return box b's quaternion (x, y, z, w) from the link frames' quaternions."""
    link = model.box_links[b]
    return quaternion_product((quaternions[link, 0], quaternions[link, 1],
                               quaternions[link, 2], quaternions[link, 3]),
                              (model.box_quaternions[b, 0], model.box_quaternions[b, 1],
                               model.box_quaternions[b, 2], model.box_quaternions[b, 3]))


@inlined_kernel
def box_rotation(model, rotations, b):
    """Return box b's rotation (row-major 9-tuple) from the link frames (as box_center)."""
    return turned(matrix(rotations, model.box_links[b]), matrix(model.box_rotations, b))


@kernel
def unpack_model(ints, floats):
    """Return the RobotModel of :func:`pack_model`'s arrays, its fields views of them.

    The arrays may hold more after the model (:func:`packed_sizes`).
    """
    links, boxes, dof = ints[0], ints[1], ints[2]
    i = 3
    order, parents = view(ints, i, (links,)), view(ints, i + links, (links,))
    joint_types = view(ints, i + 2 * links, (links,))
    q_indices = view(ints, i + 3 * links, (links,))
    box_links = view(ints, i + 4 * links, (boxes,))
    f = 0
    origin_translations = view(floats, f, (links, 3))
    f += 3 * links
    origin_rotations = view(floats, f, (links, 3, 3))
    f += 9 * links
    origin_quaternions = view(floats, f, (links, 4))
    f += 4 * links
    turn_quaternions = view(floats, f, (links, 4))
    f += 4 * links
    axes = view(floats, f, (links, 3))
    f += 3 * links
    multipliers, offsets = view(floats, f, (links,)), view(floats, f + links, (links,))
    f += 2 * links
    joint_limits = view(floats, f, (dof, 2))
    f += 2 * dof
    box_translations = view(floats, f, (boxes, 3))
    f += 3 * boxes
    box_rotations = view(floats, f, (boxes, 3, 3))
    f += 9 * boxes
    box_quaternions = view(floats, f, (boxes, 4))
    f += 4 * boxes
    half_extents = view(floats, f, (boxes, 3))
    f += 3 * boxes
    motion_radii = view(floats, f, (boxes, dof))
    return RobotModel(order, parents, origin_translations, origin_rotations,
                      origin_quaternions, turn_quaternions, joint_types, axes, q_indices,
                      multipliers, offsets, joint_limits, box_links, box_translations,
                      box_rotations, box_quaternions, half_extents, motion_radii)


@inlined_kernel
def packed_sizes(ints):
    """Return the lengths (ints, floats) of the model :func:`pack_model` packed at their start.

    A kernel handed arrays that begin with a packed model (and hold more after it) finds what
    follows the model here.
    """
    links, boxes, dof = ints[0], ints[1], ints[2]
    return 3 + 4 * links + boxes, 25 * links + 2 * dof + (19 + dof) * boxes


@inlined_kernel
def write_box(b, center, r, half, centers, rotations, extents):
    """Write box b's centre (3-tuple), rotation (row-major 9-tuple) and ``half`` extents.

    Entry by entry: a tuple indexed in a loop is not unrolled, and costs more than the box.
    """
    centers[b, 0], centers[b, 1], centers[b, 2] = center
    rotations[b, 0, 0], rotations[b, 0, 1], rotations[b, 0, 2] = r[0], r[1], r[2]
    rotations[b, 1, 0], rotations[b, 1, 1], rotations[b, 1, 2] = r[3], r[4], r[5]
    rotations[b, 2, 0], rotations[b, 2, 1], rotations[b, 2, 2] = r[6], r[7], r[8]
    extents[b, 0], extents[b, 1], extents[b, 2] = half[0], half[1], half[2]


@kernel
def link_frames(model):
    """Return scratch (rotations (L, 3, 3), translations (L, 3), quaternions (L, 4)).

    For :func:`link_transforms` and :func:`forward_kinematics`.
    """
    count = model.parents.shape[0]
    return np.empty((count, 3, 3)), np.empty((count, 3)), np.empty((count, 4))


@kernel
def box_poses_of_states(model, base_pose, states, out):
    """Write the box poses of each state (K, dof) into ``out`` (K, B, 7)."""
    rotations, translations, quaternions = link_frames(model)
    for k in range(states.shape[0]):
        forward_kinematics(model, base_pose, states[k], out[k], rotations, translations,
                           quaternions)
