"""The robot model (pipeline/robot.py): FK against pinocchio and a naive reference, boxes, filter.

Reference robots come from example-robot-data (installed with pinocchio under cmeel.prefix);
the hard cases are a robot of the test's own, written as Python data: the URDF is generated
from it and a naive 4x4-matrix forward kinematics reads the same data.
"""
import itertools
import math
import os
import sysconfig

import numpy as np
import pinocchio
import pytest
import trimesh

from collision_node import Robot
from collision_node.pipeline.urdf import read_urdf

PREFIX = os.path.join(sysconfig.get_paths()['purelib'], 'cmeel.prefix')
ROBOTS = os.path.join(PREFIX, 'share', 'example-robot-data', 'robots')
REFERENCE_ROBOTS = {
    'panda': ('panda_description/urdf/panda.urdf', 'panda_description/srdf/panda.srdf'),
    'ur5': ('ur_description/urdf/ur5_robot.urdf', 'ur_description/srdf/ur5.srdf'),
    'z1': ('z1_description/urdf/z1.urdf', 'z1_description/srdf/z1.srdf'),
}
FK_TOLERANCE = 1e-12
# Joints without finite limits are sampled within this many radians.
UNLIMITED_RANGE = 4.0


@pytest.fixture
def ament_prefix(monkeypatch):
    """Make example-robot-data's package:// URIs resolvable through the ament index."""
    monkeypatch.setenv('AMENT_PREFIX_PATH', PREFIX)


def reference_robot(name):
    urdf, srdf = REFERENCE_ROBOTS[name]
    return Robot.from_urdf(os.path.join(ROBOTS, urdf), os.path.join(ROBOTS, srdf))


def random_q(robot, rng, count=None):
    limits = np.clip(robot.joint_limits, -UNLIMITED_RANGE, UNLIMITED_RANGE)
    size = (robot.dof,) if count is None else (count, robot.dof)
    return rng.uniform(limits[:, 0], limits[:, 1], size)


def matrix(pose):
    """Return the 4x4 transform of a pose x y z qx qy qz qw."""
    x, y, z, w = pose[3:]
    out = np.eye(4)
    out[:3, :3] = [[1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
                   [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
                   [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)]]
    out[:3, 3] = pose[:3]
    return out


def joint_values(robot, path):
    """Return {joint name: (q index, multiplier, offset)} of every moving joint."""
    model = robot.model
    values = {}
    for joint in read_urdf(path).joints:
        if joint.kind != 'fixed':
            link = robot.link_names.index(joint.child)
            values[joint.name] = (model.q_indices[link], model.multipliers[link],
                                  model.offsets[link])
    return values


# -- forward kinematics against pinocchio ------------------------------------------------------

@pytest.mark.parametrize('name', sorted(REFERENCE_ROBOTS))
def test_fk_agrees_with_pinocchio(name, ament_prefix):
    robot = reference_robot(name)
    path = os.path.join(ROBOTS, REFERENCE_ROBOTS[name][0])
    model = pinocchio.buildModelFromUrdf(path)
    geometry = pinocchio.buildGeomFromUrdf(model, path, pinocchio.GeometryType.COLLISION,
                                           package_dirs=[os.path.join(PREFIX, 'share')])
    data, geometry_data = model.createData(), pinocchio.GeometryData(geometry)
    objects = {item.name: number for number, item in enumerate(geometry.geometryObjects)}
    assert len(objects) == len(robot.box_links)
    rng = np.random.default_rng(7)
    for _ in range(20):
        q = random_q(robot, rng)
        # pinocchio reads mimic joints as independent ones: each gets the value ours computes.
        pin_q = np.zeros(model.nq)
        for joint, (index, multiplier, offset) in joint_values(robot, path).items():
            pin_joint = model.joints[model.getJointId(joint)]
            value = multiplier * q[index] + offset
            if pin_joint.nq == 2:  # continuous: cos, sin
                pin_q[pin_joint.idx_q:pin_joint.idx_q + 2] = math.cos(value), math.sin(value)
            else:
                pin_q[pin_joint.idx_q] = value
        pinocchio.forwardKinematics(model, data, pin_q)
        pinocchio.updateGeometryPlacements(model, data, geometry, geometry_data)
        links = robot.link_poses(q)
        poses = robot.box_poses(q)
        for box, link in enumerate(robot.box_links):
            number = robot.box_links[:box].count(link)
            expected = geometry_data.oMg[objects['%s_%d' % (link, number)]]
            ours = matrix(links[robot.box_link_index[box]]) @ matrix(
                robot.collision_origins[box])
            np.testing.assert_allclose(ours[:3, :3], expected.rotation, atol=FK_TOLERANCE)
            np.testing.assert_allclose(ours[:3, 3], expected.translation, atol=FK_TOLERANCE)
            # The box pose is the link frame composed with the box's own local pose.
            local = np.eye(4)
            local[:3, :3] = robot.model.box_rotations[box]
            local[:3, 3] = robot.model.box_translations[box]
            box_matrix = matrix(links[robot.box_link_index[box]]) @ local
            np.testing.assert_allclose(matrix(poses[box]), box_matrix, atol=FK_TOLERANCE)
            assert abs(np.linalg.norm(poses[box, 3:]) - 1.0) < 1e-14


# -- a robot of the test's own: every joint kind, shape and mesh format --------------------------

def write_meshes(folder):
    """Write four meshes of different shapes and formats; return {name: (file, vertices)}."""
    shapes = {
        'binary.stl': trimesh.creation.cylinder(0.04, 0.3, sections=24),
        'ascii.stl': trimesh.creation.box((0.1, 0.2, 0.05)),
        'mesh.obj': trimesh.creation.icosphere(1, 0.07),
        'mesh.dae': trimesh.creation.capsule(0.2, 0.03, count=[8, 8]),
    }
    # Turned and moved off the origin, so the fitted box has an offset and a rotation.
    turn = trimesh.transformations.euler_matrix(0.3, -0.5, 0.9)
    turn[:3, 3] = [0.02, -0.03, 0.05]
    made = {}
    for name, mesh in shapes.items():
        mesh.apply_transform(turn)
        path = os.path.join(folder, name)
        if name == 'binary.stl':
            data = trimesh.exchange.stl.export_stl(mesh)
        elif name == 'ascii.stl':
            data = trimesh.exchange.stl.export_stl_ascii(mesh).encode()
        elif name == 'mesh.obj':
            data = trimesh.exchange.obj.export_obj(mesh, include_normals=False).encode()
        else:
            data = trimesh.exchange.dae.export_collada(mesh)
        with open(path, 'wb') as file:
            file.write(data)
        made[name] = np.asarray(trimesh.load(path, force='mesh').vertices)
    return made


def own_robot_spec(folder):
    """Return (links, joints) of the test robot; mesh files under ``folder``.

    links: {name: [(xyz, rpy, shape, attributes)]}; joints: list of dicts.
    """
    package_root = os.path.join(folder, 'packages')
    os.makedirs(os.path.join(package_root, 'my_robot', 'meshes'))
    meshes = write_meshes(os.path.join(package_root, 'my_robot', 'meshes'))
    absolute = os.path.join(package_root, 'my_robot', 'meshes')
    links = {
        'base': [((0.0, 0.0, 0.1), (0.0, 0.0, 0.0), 'box', {'size': '0.4 0.3 0.2'})],
        'slider': [((0.1, 0.0, 0.0), (0.2, -0.3, 0.4), 'cylinder',
                    {'radius': '0.05', 'length': '0.3'}),
                   ((0.0, 0.1, 0.0), (0.0, 0.0, 0.0), 'sphere', {'radius': '0.04'})],
        'empty_a': [],
        'empty_b': [],
        'arm': [((0.0, 0.0, 0.15), (0.1, 0.2, 0.3), 'mesh',
                 {'filename': 'package://my_robot/meshes/binary.stl', 'scale': '1 2 0.5'})],
        'wrist': [((0.01, 0.02, 0.03), (-0.4, 0.5, -0.6), 'mesh',
                   {'filename': 'file://' + os.path.join(absolute, 'ascii.stl')})],
        'hand': [((0.0, 0.0, 0.0), (0.0, 0.0, 0.0), 'mesh',
                  {'filename': 'packages/my_robot/meshes/mesh.obj', 'scale': '1.5'}),
                 ((0.0, 0.0, 0.05), (1.0, 0.0, 0.0), 'box', {'size': '0.02 0.03 0.04'})],
        'finger': [((0.0, 0.0, 0.02), (0.0, 0.7, 0.0), 'mesh',
                    {'filename': os.path.join(absolute, 'mesh.dae')})],
        'twin': [((0.0, 0.0, 0.02), (0.0, 0.0, 0.0), 'box', {'size': '0.01 0.01 0.04'})],
        'side': [((0.0, 0.0, 0.0), (0.0, 0.0, 0.0), 'sphere', {'radius': '0.02'})],
    }
    joints = [
        {'name': 'slide', 'type': 'prismatic', 'parent': 'base', 'child': 'slider',
         'xyz': (0.1, 0.2, 0.3), 'rpy': (0.1, 0.2, 0.3), 'axis': (1.0, 2.0, -0.5),
         'limits': (-0.2, 0.4)},
        {'name': 'fixed_a', 'type': 'fixed', 'parent': 'slider', 'child': 'empty_a',
         'xyz': (0.0, 0.0, 0.2), 'rpy': (0.5, -0.5, 0.25), 'axis': (0.0, 0.0, 0.0)},
        {'name': 'turn', 'type': 'revolute', 'parent': 'empty_a', 'child': 'empty_b',
         'xyz': (0.05, -0.02, 0.1), 'rpy': (-0.3, 0.6, 1.2), 'axis': (0.3, -0.4, 1.2),
         'limits': (-2.0, 1.5)},
        {'name': 'spin', 'type': 'continuous', 'parent': 'empty_b', 'child': 'arm',
         'xyz': (0.0, 0.1, 0.0), 'rpy': (0.0, 0.0, 0.7), 'axis': (0.0, 1.0, 1.0)},
        {'name': 'elbow', 'type': 'revolute', 'parent': 'arm', 'child': 'wrist',
         'xyz': (0.0, 0.0, 0.3), 'rpy': (0.2, 0.0, 0.0), 'axis': (1.0, 0.0, 0.0),
         'limits': (-1.0, 1.0)},
        {'name': 'hand_fixed', 'type': 'fixed', 'parent': 'wrist', 'child': 'hand',
         'xyz': (0.0, 0.05, 0.0), 'rpy': (0.0, 0.0, 0.0), 'axis': (1.0, 0.0, 0.0)},
        {'name': 'grip', 'type': 'prismatic', 'parent': 'hand', 'child': 'finger',
         'xyz': (0.0, 0.02, 0.08), 'rpy': (0.0, 0.0, 0.0), 'axis': (0.0, 1.0, 0.0),
         'limits': (0.0, 0.05)},
        {'name': 'grip_twin', 'type': 'prismatic', 'parent': 'hand', 'child': 'twin',
         'xyz': (0.0, -0.02, 0.08), 'rpy': (0.0, 0.0, 0.0), 'axis': (0.0, -1.0, 0.0),
         'limits': (-1.0, 1.0), 'mimic': ('grip', 2.0, 0.01)},
        {'name': 'side_turn', 'type': 'revolute', 'parent': 'empty_b', 'child': 'side',
         'xyz': (0.1, 0.0, 0.0), 'rpy': (0.0, 0.0, 0.0), 'axis': (0.0, 0.0, 1.0),
         'limits': (-1.0, 1.0), 'mimic': ('turn', -0.5, 0.2)},
    ]
    return links, joints, package_root, meshes


def urdf_text(links, joints):
    lines = ['<robot name="own">']
    for name, collisions in links.items():
        lines.append('<link name="%s">' % name)
        for xyz, rpy, shape, attributes in collisions:
            lines.append('<collision><origin xyz="%s" rpy="%s"/><geometry><%s %s/></geometry>'
                         '</collision>' % (' '.join(map(repr, xyz)), ' '.join(map(repr, rpy)),
                                           shape, ' '.join('%s="%s"' % item
                                                           for item in attributes.items())))
        lines.append('</link>')
    for joint in joints:
        lines.append('<joint name="%s" type="%s"><parent link="%s"/><child link="%s"/>'
                     % (joint['name'], joint['type'], joint['parent'], joint['child']))
        lines.append('<origin xyz="%s" rpy="%s"/><axis xyz="%s"/>' % tuple(
            ' '.join(map(repr, joint[key])) for key in ('xyz', 'rpy', 'axis')))
        if 'limits' in joint:
            lines.append('<limit lower="%r" upper="%r" effort="1" velocity="1"/>'
                         % joint['limits'])
        if 'mimic' in joint:
            lines.append('<mimic joint="%s" multiplier="%r" offset="%r"/>' % joint['mimic'])
        lines.append('</joint>')
    lines.append('</robot>')
    return '\n'.join(lines)


def naive_transform(xyz, rpy):
    roll, pitch, yaw = rpy
    rx = np.array([[1, 0, 0], [0, math.cos(roll), -math.sin(roll)],
                   [0, math.sin(roll), math.cos(roll)]])
    ry = np.array([[math.cos(pitch), 0, math.sin(pitch)], [0, 1, 0],
                   [-math.sin(pitch), 0, math.cos(pitch)]])
    rz = np.array([[math.cos(yaw), -math.sin(yaw), 0], [math.sin(yaw), math.cos(yaw), 0],
                   [0, 0, 1]])
    out = np.eye(4)
    out[:3, :3] = rz @ ry @ rx
    out[:3, 3] = xyz
    return out


def naive_motion(kind, axis, value):
    out = np.eye(4)
    if kind != 'fixed':
        axis = np.asarray(axis) / np.linalg.norm(axis)
    if kind == 'prismatic':
        out[:3, 3] = axis * value
    elif kind in ('revolute', 'continuous'):
        skew = np.array([[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]],
                         [-axis[1], axis[0], 0]])
        out[:3, :3] = np.eye(3) + math.sin(value) * skew \
            + (1 - math.cos(value)) * skew @ skew
    return out


def naive_collision_frames(links, joints, q_by_name):
    """Return [4x4 frame of each collision element] in document order, for joint values."""
    frames = {'base': np.eye(4)}
    by_child = {joint['child']: joint for joint in joints}

    def frame(link):
        if link not in frames:
            joint = by_child[link]
            if 'mimic' in joint:
                followed, multiplier, offset = joint['mimic']
                value = multiplier * q_by_name[followed] + offset
            else:
                value = q_by_name.get(joint['name'], 0.0)
            frames[link] = frame(joint['parent']) @ naive_transform(
                joint['xyz'], joint['rpy']) @ naive_motion(joint['type'], joint['axis'], value)
        return frames[link]
    return [frame(link) @ naive_transform(xyz, rpy)
            for link, collisions in links.items() for xyz, rpy, _, _ in collisions]


@pytest.fixture
def own(tmp_path):
    links, joints, package_root, meshes = own_robot_spec(str(tmp_path))
    path = tmp_path / 'own.urdf'
    path.write_text(urdf_text(links, joints))
    robot = Robot.from_urdf(str(path), package_paths=[package_root])
    return robot, links, joints, meshes, (str(path), package_root)


def test_own_robot_reads_every_joint_and_shape(own):
    robot, links, joints = own[:3]
    assert robot.joint_names == ('slide', 'turn', 'spin', 'elbow', 'grip')
    assert robot.box_links == tuple(link for link, collisions in links.items()
                                    for _ in collisions)
    assert robot.box_shapes == ('box', 'cylinder', 'sphere', 'mesh', 'mesh', 'mesh', 'box',
                                'mesh', 'box', 'sphere')
    np.testing.assert_array_equal(robot.joint_limits, [[-0.2, 0.4], [-2.0, 1.5],
                                                       [-np.inf, np.inf], [-1.0, 1.0],
                                                       [0.0, 0.05]])
    np.testing.assert_array_equal(robot.half_extents[[0, 1, 2, 6, 8, 9]], [
        [0.2, 0.15, 0.1], [0.05, 0.05, 0.15], [0.04] * 3, [0.01, 0.015, 0.02],
        [0.005, 0.005, 0.02], [0.02] * 3])
    ratios = robot.box_volume_ratio
    assert ratios[0] == ratios[6] == 1.0
    assert ratios[1] == pytest.approx(4 / math.pi) and ratios[2] == pytest.approx(6 / math.pi)
    assert all(ratio >= 1.0 for ratio in ratios[[3, 4, 5, 7]])


def test_own_robot_fk_agrees_with_naive_matrices(own):
    robot, links, joints = own[:3]
    rng = np.random.default_rng(3)
    for q in random_q(robot, rng, 30):
        expected = naive_collision_frames(links, joints, dict(zip(robot.joint_names, q)))
        link_poses = robot.link_poses(q)
        poses = robot.box_poses(q)
        for box, frame in enumerate(expected):
            ours = matrix(link_poses[robot.box_link_index[box]]) @ matrix(
                robot.collision_origins[box])
            np.testing.assert_allclose(ours, frame, atol=FK_TOLERANCE)
            local = np.eye(4)
            local[:3, :3] = robot.model.box_rotations[box]
            local[:3, 3] = robot.model.box_translations[box]
            box_frame = np.linalg.inv(frame) @ matrix(poses[box])
            np.testing.assert_allclose(box_frame, np.linalg.inv(matrix(
                robot.collision_origins[box])) @ local, atol=FK_TOLERANCE)


def test_a_long_chain_of_turns_stays_exact_and_unit():
    """60 joints with random axes, origins and angles: the quaternion chain's drift is small.

    Each link's orientation is a product of its parent's and its joint's quaternions
    (robot.py, Composition): the boxes must still agree with naive 4x4 products, and the
    box quaternions stay unit to rounding, far inside what a step accepts.
    """
    rng = np.random.default_rng(11)
    count = 60
    names = ['base'] + ['l%d' % k for k in range(1, count + 1)]  # naive frames start at base
    links = {name: [((0.01, 0.0, 0.02), (0.3, -0.2, 0.1), 'box', {'size': '0.02 0.02 0.02'})]
             for name in names}
    joints = [{'name': 'j%d' % k, 'type': ('revolute', 'continuous', 'prismatic')[k % 3],
               'parent': names[k], 'child': names[k + 1],
               'xyz': tuple(rng.uniform(-0.2, 0.2, 3).tolist()),
               'rpy': tuple(rng.uniform(-3, 3, 3).tolist()),
               'axis': tuple(rng.normal(size=3).tolist()), 'limits': (-3.0, 3.0)}
              for k in range(count)]
    robot = Robot.from_urdf(urdf_text(links, joints))
    for q in rng.uniform(-3.0, 3.0, (10, robot.dof)):
        expected = naive_collision_frames(links, joints, dict(zip(robot.joint_names, q)))
        poses = robot.box_poses(q)
        for box, frame in enumerate(expected):
            np.testing.assert_allclose(matrix(poses[box]), frame, atol=FK_TOLERANCE)
        assert np.abs(np.linalg.norm(poses[:, 3:], axis=1) - 1.0).max() < 1e-14


def test_batches_and_the_base_pose(own):
    robot = own[0]
    rng = np.random.default_rng(4)
    states = random_q(robot, rng, 5)
    batch = robot.box_poses(states)
    assert batch.shape == (5, len(robot.box_links), 7)
    for state, poses in zip(states, batch):
        np.testing.assert_array_equal(robot.box_poses(state), poses)
    # The kernel with a base pose: every box moved by it.
    from collision_node.pipeline.robot import forward_kinematics, link_frames
    base = np.array([0.5, -1.0, 2.0, *(np.array([0.1, 0.2, 0.3, 0.9]) / np.linalg.norm(
        [0.1, 0.2, 0.3, 0.9]))])
    out = np.empty((len(robot.box_links), 7))
    forward_kinematics(robot.model, base, states[0], out, *link_frames(robot.model))
    for box in range(len(out)):
        np.testing.assert_allclose(matrix(out[box]), matrix(base) @ matrix(batch[0, box]),
                                   atol=FK_TOLERANCE)


def test_lane_frames_are_the_one_state_frames_bit_for_bit(own):
    """robot.lane_transforms (the pass's LANES states at once) against link_transforms.

    Both are the package's own kernels: the robot's pass answers as a step on box_poses only
    if the two agree to the bit, in every lane, in a block cut short by the last state, and
    in a block whose angle past trig.REDUCED_LIMIT sends its lanes through libm.
    """
    from collision_node.pipeline.robot import lane_transforms, link_frames, link_transforms
    from collision_node.pipeline.robot_pass import LANES
    robot = own[0]
    model, links = robot.model, len(robot.model.parents)
    rng = np.random.default_rng(8)
    states = random_q(robot, rng, 3 * LANES - 3)
    spin = robot.joint_names.index('spin')
    states[LANES + 2, spin] = 3e6  # a continuous joint far round
    base = np.array([0.5, -1.0, 2.0, 0.1, 0.2, 0.3, 0.9])  # not unit: normalised in both
    lanes = (np.empty(LANES), np.empty((links, 4, LANES)), np.empty((links, 9, LANES)),
             np.empty((links, 3, LANES)))
    one = link_frames(model)
    for first in range(0, len(states), LANES):
        width = min(LANES, len(states) - first)
        lane_transforms(model, base, states, first, width, *lanes)
        for w in range(width):
            link_transforms(model, base, states[first + w], *one)
            np.testing.assert_array_equal(lanes[1][:, :, w], one[2])
            np.testing.assert_array_equal(lanes[2][:, :, w], one[0].reshape(links, 9))
            np.testing.assert_array_equal(lanes[3][:, :, w], one[1])


def test_mesh_boxes_hold_every_vertex_and_beat_the_aabb(own, ament_prefix):
    robot, links, _, meshes = own[:4]
    elements = [item for collisions in links.values() for item in collisions]
    checked = 0
    for box, (xyz, rpy, shape, attributes) in enumerate(elements):
        if shape != 'mesh':
            continue
        scale = np.array([float(value) for value in attributes.get('scale', '1').split()])
        scale = np.resize(scale, 3)
        vertices = meshes[os.path.basename(attributes['filename'])] * scale
        assert_box_holds(robot, box, vertices)
        checked += 1
    assert checked == 4
    panda = reference_robot('panda')
    for box, shape in enumerate(panda.box_shapes):
        if shape == 'mesh':
            name = panda.box_links[box].replace('panda_', '').replace('leftfinger', 'finger')
            path = os.path.join(ROBOTS, 'panda_description', 'meshes', 'collision',
                                name + '.stl')
            assert_box_holds(panda, box, np.asarray(trimesh.load(path).vertices))


def assert_box_holds(robot, box, vertices):
    """Every vertex (mesh frame, scaled) inside box ``box``; its volume <= the AABB's."""
    origin = matrix(robot.collision_origins[box])
    in_link = vertices @ origin[:3, :3].T + origin[:3, 3]
    local = (in_link - robot.model.box_translations[box]) @ robot.model.box_rotations[box]
    half = robot.half_extents[box]
    scale = np.abs(vertices).max()
    assert (np.abs(local) <= half + 1e-9 * scale).all()
    aabb = vertices.max(axis=0) - vertices.min(axis=0)
    assert np.prod(2 * half) <= np.prod(aabb) * (1 + 1e-12)


# -- errors ----------------------------------------------------------------------------------

def simple_urdf(joint_type='revolute', extra_link='', joint_extra='', child='b', mesh=''):
    return ('<robot name="r"><link name="a">%s</link><link name="b"/>%s'
            '<joint name="j" type="%s"><parent link="a"/><child link="%s"/>'
            '<axis xyz="0 0 1"/><limit lower="-1" upper="1"/>%s</joint></robot>'
            % (mesh, extra_link, joint_type, child, joint_extra))


@pytest.mark.parametrize('urdf, words', [
    (simple_urdf('floating'), ["joint 'j'", 'floating']),
    (simple_urdf('planar'), ["joint 'j'", 'planar']),
    (simple_urdf('screw'), ["joint 'j'", "unknown joint type 'screw'"]),
    (simple_urdf(child='nowhere'), ["joint 'j'", "'nowhere'"]),
    ('<robot name="r"><link name="a"', ['malformed XML']),
    ('<robot name="r"></robot>', ['no <link>']),
    (simple_urdf(joint_extra='<origin xyz="0 0 x"/>'), ["joint 'j'", '<origin xyz>']),
    (simple_urdf(joint_extra='<mimic joint="ghost"/>'), ["joint 'j'", "'ghost'"]),
    (simple_urdf().replace('<axis xyz="0 0 1"/>', '<axis xyz="0 0 0"/>'),
     ["joint 'j'", 'zero vector']),
    (simple_urdf(extra_link='<link name="c"/>'), ['roots', 'a', 'c']),
    (simple_urdf(extra_link='<link name="c"/><joint name="k" type="fixed"><parent link="b"/>'
                 '<child link="c"/></joint><joint name="m" type="fixed"><parent link="c"/>'
                 '<child link="a"/></joint>'), ['cycle']),
    (simple_urdf(mesh='<collision><geometry><mesh filename="package://nowhere/x.stl"/>'
                      '</geometry></collision>'), ["link 'a'", 'package://nowhere/x.stl']),
])
def test_errors_name_what_is_wrong(urdf, words):
    with pytest.raises(ValueError) as error:
        Robot.from_urdf(urdf)
    for word in words:
        assert word in str(error.value)


def test_missing_mesh_file_names_link_and_uri(tmp_path):
    urdf = simple_urdf(mesh='<collision><geometry><mesh filename="meshes/gone.stl"/>'
                            '</geometry></collision>')
    (tmp_path / 'r.urdf').write_text(urdf)
    with pytest.raises(ValueError, match="link 'a'.*meshes/gone.stl"):
        Robot.from_urdf(str(tmp_path / 'r.urdf'))
    (tmp_path / 'meshes').mkdir()
    (tmp_path / 'meshes' / 'gone.stl').write_text('not a mesh')
    with pytest.raises(ValueError, match="link 'a'.*meshes/gone.stl"):
        Robot.from_urdf(str(tmp_path / 'r.urdf'))


def test_bad_q_is_refused_and_changes_nothing(own):
    robot = own[0]
    q = np.zeros(robot.dof)
    before = robot.box_poses(q)
    model = [array.copy() for array in robot.model]
    for bad in (np.zeros(robot.dof + 1), np.zeros((2, robot.dof - 1)), np.zeros((1, 1, 5))):
        with pytest.raises(ValueError, match='shape'):
            robot.box_poses(bad)
    for value in (np.nan, np.inf):
        q_bad = q.copy()
        q_bad[2] = value
        with pytest.raises(ValueError, match="joint 'spin'"):
            robot.box_poses(q_bad)
    for mine, kept in zip(robot.model, model):
        np.testing.assert_array_equal(mine, kept)
    np.testing.assert_array_equal(robot.box_poses(q), before)


# -- the self-collision filter ---------------------------------------------------------------

def naive_adjacent(links_with_geometry, parent_of, a, b):
    """Return True when the tree path from a to b has no link with geometry inside it."""
    def up(link):
        chain = [link]
        while chain[-1] in parent_of:
            chain.append(parent_of[chain[-1]])
        return chain
    up_a, up_b = up(a), up(b)
    common = next(link for link in up_a if link in up_b)
    inside = up_a[1:up_a.index(common)] + up_b[1:up_b.index(common)]
    if common not in (a, b):
        inside.append(common)
    return not any(link in links_with_geometry for link in inside)


def test_filter_adjacency_srdf_and_same_link_boxes(own):
    _, links, joints, _, (path, package_root) = own
    srdf = ('<robot name="own"><disable_collisions link1="base" link2="hand" reason="Never"/>'
            '<disable_collisions link1="base" link2="wrist" reason="Never"/>'
            '<disable_default_collisions link="twin"/>'
            '<enable_collisions link1="twin" link2="base"/>'
            '<enable_collisions link1="wrist" link2="base"/></robot>')
    robot = Robot.from_urdf(path, srdf, package_paths=[package_root])
    geometric = {link for link, collisions in links.items() if collisions}
    parent_of = {joint['child']: joint['parent'] for joint in joints}
    expected = {}
    for a, b in itertools.combinations(sorted(geometric), 2):
        if naive_adjacent(geometric, parent_of, a, b):
            expected[(a, b)] = 'adjacent'
    expected[('base', 'hand')] = 'Never'
    for other in geometric - {'twin', 'base'}:
        expected.setdefault(tuple(sorted(('twin', other))), 'default')
    assert robot.disabled_link_pairs == expected
    # Through the links without geometry: slider to arm and side, arm to side (siblings).
    assert {('arm', 'slider'), ('side', 'slider'), ('arm', 'side')} <= set(expected)
    links_of = robot.box_links
    naive_pairs = [(i, j) for i in range(len(links_of)) for j in range(i + 1, len(links_of))
                   if links_of[i] != links_of[j]
                   and tuple(sorted((links_of[i], links_of[j]))) not in expected]
    np.testing.assert_array_equal(robot.allowed_box_pairs,
                                  np.array(naive_pairs, np.int64).reshape(-1, 2))
    assert (2, 1) not in naive_pairs and (1, 2) not in map(tuple, robot.allowed_box_pairs)


def test_srdf_naming_an_unknown_link_is_refused():
    with pytest.raises(ValueError, match="'ghost'"):
        Robot.from_urdf(simple_urdf(), '<robot><disable_collisions link1="a" link2="ghost"/>'
                                       '</robot>')


@pytest.mark.parametrize('name', sorted(REFERENCE_ROBOTS))
def test_reference_robots_allowed_pairs(name, ament_prefix):
    robot = reference_robot(name)
    pairs = robot.allowed_box_pairs
    assert len(pairs) and (pairs[:, 0] < pairs[:, 1]).all()
    assert [tuple(pair) for pair in pairs] == sorted(tuple(pair) for pair in pairs)
    for i, j in pairs:
        key = tuple(sorted((robot.box_links[i], robot.box_links[j])))
        assert robot.box_links[i] != robot.box_links[j] and key not in robot.disabled_link_pairs


# -- the motion bound --------------------------------------------------------------------------

def corners(robot, poses):
    """Return the 8 corners of every box, (K, B, 8, 3), for poses (K, B, 7)."""
    signs = np.array(list(itertools.product((-1.0, 1.0), repeat=3)))
    out = np.empty(poses.shape[:2] + (8, 3))
    for k in range(poses.shape[0]):
        for box in range(poses.shape[1]):
            frame = matrix(poses[k, box])
            out[k, box] = (signs * robot.half_extents[box]) @ frame[:3, :3].T + frame[:3, 3]
    return out


@pytest.mark.parametrize('name', ['own', *sorted(REFERENCE_ROBOTS)])
def test_motion_radii_bound_every_corner(name, own, ament_prefix):
    robot = own[0] if name == 'own' else reference_robot(name)
    radii = robot.model.motion_radii
    assert radii.shape == (len(robot.box_links), robot.dof) and (radii >= 0).all()
    rng = np.random.default_rng(11)
    steps = np.linspace(0.0, 1.0, 101)
    for _ in range(8):
        q0, q1 = random_q(robot, rng, 2)
        states = q0 + steps[:, None] * (q1 - q0)
        points = corners(robot, robot.box_poses(states))
        moved = np.linalg.norm(points - points[0], axis=-1).max(axis=-1)  # (K, B)
        bound = (np.abs(states - q0) @ radii.T)  # (K, B)
        assert (moved <= bound * (1 + 1e-9) + 1e-12).all()
    # Joints not above a box do not move it: their radius is 0.
    if name == 'own':
        index = robot.joint_names.index('grip')
        assert radii[robot.box_links.index('side'), index] == 0.0
        assert radii[robot.box_links.index('twin'), index] == pytest.approx(2.0)


@pytest.mark.parametrize('name', ['own', *sorted(REFERENCE_ROBOTS)])
def test_the_chord_bound_holds_every_corner_on_whole_segments_and_pieces(name, own,
                                                                         ament_prefix):
    """A corner strays from the chord between its ends by at most h^2 / 8 times its bend."""
    robot = own[0] if name == 'own' else reference_robot(name)
    turns, reach = robot.chord_turns, robot.chord_reach
    assert turns.shape == (len(robot.box_links), robot.dof) and (turns >= 0).all()
    assert (reach >= 0).all() and np.array_equal(turns > 0, robot.model.motion_radii > 0)
    rng = np.random.default_rng(15)
    steps = np.linspace(0.0, 1.0, 201)
    tightest = 0.0
    limits = np.clip(robot.joint_limits, -UNLIMITED_RANGE, UNLIMITED_RANGE)
    for size in (0.05, 0.5, 3.0):  # short segments to long ones, within the limits
        for _ in range(6):
            q0 = random_q(robot, rng)
            q1 = np.clip(q0 + rng.uniform(-size, size, robot.dof), limits[:, 0], limits[:, 1])
            points = corners(robot, robot.box_poses(q0 + steps[:, None] * (q1 - q0)))
            bend = reach * (np.abs(q1 - q0) @ turns.T) ** 2  # (B,)
            for first, last in ((0, 200), (50, 150), (180, 200)):  # the segment and pieces
                s = steps[first:last + 1, None, None, None]
                h = steps[last] - steps[first]
                chord = points[first] + (s - steps[first]) / h * (points[last] - points[first])
                strayed = np.linalg.norm(points[first:last + 1] - chord, axis=-1).max(axis=(0, 2))
                bound = h * h / 8.0 * bend
                assert (strayed <= bound * (1 + 1e-9) + 1e-12).all(), (name, size, first)
                tightest = max(tightest, (strayed / np.maximum(bound, 1e-300)).max())
    assert tightest > 0.2  # a bound, not a wild one: some corner comes near it


def common_ancestor(parents, first, second):
    """Return the nearest link at or above both links (a plain walk, as a reference)."""
    above_first = [first]
    while parents[above_first[-1]] >= 0:
        above_first.append(parents[above_first[-1]])
    while second not in above_first:
        second = parents[second]
    return second


@pytest.mark.parametrize('name', ['own', *sorted(REFERENCE_ROBOTS)])
def test_pair_motion_radii_bound_every_corner_relative_to_the_common_ancestor(
        name, own, ament_prefix):
    """Two boxes of a pair move apart or together no faster than their pair's radii say."""
    robot = own[0] if name == 'own' else reference_robot(name)
    pairs = robot.allowed_box_pairs
    radii = robot.pair_motion_radii(pairs[:, 0], pairs[:, 1])
    assert radii.shape == (len(pairs), robot.dof) and (radii >= 0).all()
    assert (radii <= robot.model.motion_radii[pairs[:, 0]]
            + robot.model.motion_radii[pairs[:, 1]] + 1e-12).all()
    static = robot.pair_motion_radii(pairs[:, 0], np.full(len(pairs), -1))
    np.testing.assert_array_equal(static, robot.model.motion_radii[pairs[:, 0]])
    rng = np.random.default_rng(12)
    steps = np.linspace(0.0, 1.0, 41)
    parents, links = robot.model.parents, robot.box_link_index
    ancestors = [common_ancestor(parents, links[a], links[b]) for a, b in pairs]
    for _ in range(4):
        q0, q1 = random_q(robot, rng, 2)
        states = q0 + steps[:, None] * (q1 - q0)
        points = corners(robot, robot.box_poses(states))  # (K, B, 8, 3)
        frames = np.array([[matrix(pose) for pose in robot.link_poses(q)] for q in states])
        bound = np.abs(states - q0) @ radii.T  # (K, P)
        for p, (a, b) in enumerate(pairs):
            frame = frames[:, ancestors[p]]  # (K, 4, 4): the pair's corners in that link
            moved = 0.0
            for box in (a, b):
                local = np.einsum('kji,kcj->kci', frame[:, :3, :3],
                                  points[:, box] - frame[:, None, :3, 3])
                moved = moved + np.linalg.norm(local - local[0], axis=-1).max(axis=-1)
            assert (moved <= bound[:, p] * (1 + 1e-9) + 1e-12).all(), (name, a, b)


def test_a_box_on_a_joint_axis_moves_by_its_own_size_only():
    """A turn's reach is the distance from its axis, not from its origin (analytic).

    A box 1 m up the axis of a turning joint: the turn keeps every point of the box within
    its half diagonal of the axis, where the distance from the joint's origin says 1 m more.
    With a second turn between them that can swing the box off that axis, the ball grows by
    that turn's reach, and both bounds agree.
    """
    half = (0.1, 0.2, 0.05)
    links = {'base': [], 'arm': [], 'tip': [((0.0, 0.0, 1.0), (0.0, 0.0, 0.0), 'box',
                                            {'size': '%r %r %r' % tuple(2 * h for h in half)})]}
    joints = [{'name': 'spin', 'type': 'revolute', 'parent': 'base', 'child': 'arm',
               'xyz': (0.0, 0.0, 0.5), 'rpy': (0.0, 0.0, 0.0), 'axis': (0.0, 0.0, 1.0),
               'limits': (-3.0, 3.0)},
              {'name': 'tilt', 'type': 'revolute', 'parent': 'arm', 'child': 'tip',
               'xyz': (0.0, 0.0, 0.0), 'rpy': (0.0, 0.0, 0.0), 'axis': (1.0, 0.0, 0.0),
               'limits': (-0.5, 0.5)}]
    robot = Robot.from_urdf(urdf_text(links, joints))
    diagonal = np.linalg.norm(half)
    # The tilt's axis passes 1 m from the box: its reach is that plus the half diagonal.
    # The spin's axis runs through the box's centre at tilt 0, but the tilt can swing the
    # box 1 m off it: the ball's radius (the tilt's sweep, 1 m, plus the half diagonal).
    np.testing.assert_allclose(robot.model.motion_radii[0], [1.0 + diagonal, 1.0 + diagonal])
    assert robot.chord_reach[0] == pytest.approx(1.0 + diagonal)
    # Without the tilt, the spin alone moves the box's points by at most its half diagonal.
    alone = Robot.from_urdf(urdf_text(
        {'base': [], 'tip': links['tip']}, [dict(joints[0], child='tip')]))
    np.testing.assert_allclose(alone.model.motion_radii[0], [diagonal])


@pytest.mark.parametrize('name', ['own', *sorted(REFERENCE_ROBOTS)])
def test_center_spheres_and_gaps_hold_at_any_joint_values(name, own, ament_prefix):
    """The reach reads no limits: it holds for angles far outside them too."""
    robot = own[0] if name == 'own' else reference_robot(name)
    boxes = np.arange(len(robot.box_links))
    base = np.array([0.3, -0.2, 0.1, 0.1, 0.2, 0.3, 0.9273618])
    base[3:] /= np.linalg.norm(base[3:])
    centres, reaches = robot.center_spheres(boxes, np.full(len(boxes), -1), base)
    assert np.isfinite(reaches).any() and (reaches >= 0.0).all()
    pairs = robot.allowed_box_pairs
    gaps = robot.center_gaps(pairs[:, 0], pairs[:, 1])
    np.testing.assert_array_equal(gaps, robot.center_gaps(pairs[:, 0], pairs[:, 1]))  # kept
    rng = np.random.default_rng(13)
    limits = np.nan_to_num(robot.joint_limits, posinf=3.0, neginf=-3.0)
    states = rng.uniform(limits[:, 0] - 6.0, limits[:, 1] + 6.0, (300, robot.dof))
    frame = matrix(base)
    for poses in robot.box_poses(states):
        placed = poses[:, :3] @ frame[:3, :3].T + frame[:3, 3]
        assert (np.linalg.norm(placed - centres, axis=1) <= reaches + 1e-12).all(), name
        apart = np.linalg.norm(poses[pairs[:, 0], :3] - poses[pairs[:, 1], :3], axis=1)
        assert (apart >= gaps - 1e-12).all(), name


@pytest.mark.parametrize('name', sorted(REFERENCE_ROBOTS))
def test_the_pass_without_pairs_out_of_reach_answers_as_step_beyond_the_limits(
        name, ament_prefix):
    """Static boxes strewn near and far: the pairs left out never change an answer."""
    from collision_node import World
    robot = reference_robot(name)
    rng = np.random.default_rng(14)
    turns = rng.normal(size=(60, 4))
    poses = np.column_stack([rng.uniform(-2.0, 2.0, (60, 3)),
                             turns / np.linalg.norm(turns, axis=1, keepdims=True)])
    world = World(margin=0.01)
    world.set_static(poses, rng.uniform(0.02, 0.25, (60, 3)))
    world.set_robot(robot)
    rows = world.robot_pass()
    assert 0 < len(rows.pairs) < rows.all_pairs - rows.filtered  # some left out, not all
    limits = np.clip(robot.joint_limits, -UNLIMITED_RANGE, UNLIMITED_RANGE)
    states = rng.uniform(limits[:, 0] - 2.0, limits[:, 1] + 2.0, (300, robot.dof))
    contacts = world.check_joints(states).contacts
    assert len(contacts)
    for k, box_poses in enumerate(world.robot_poses(states)):
        step = world.step(box_poses, robot.half_extents).contacts
        mine = contacts[contacts['state'] == k]
        assert len(mine) == len(step), (name, k)
        for field in step.dtype.names:
            np.testing.assert_array_equal(mine[field], step[field], err_msg=field)


def test_a_robot_without_joints_has_no_motion_and_its_path_is_its_pose():
    from collision_node import World
    robot = Robot.from_urdf('<robot name="post"><link name="base"><collision><geometry>'
                            '<box size="0.2 0.2 1"/></geometry></collision></link></robot>')
    assert robot.dof == 0 and robot.model.motion_radii.shape == (1, 0)
    world = World()
    world.set_static([[0.0, 0.0, 0.55, 0, 0, 0, 1], [1.0, 0.0, 0.0, 0, 0, 0, 1]],
                     [0.1, 0.1, 0.1])
    world.set_robot(robot)
    rows = world.check_trajectory(np.zeros((3, 0))).contacts
    assert [(int(row['state']), int(row['id_b']), float(row['toi'])) for row in rows] \
        == [(0, 0, 0.0), (1, 0, 0.0), (2, 0, 0.0)]
