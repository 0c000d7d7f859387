"""The frame helpers of pipeline/frames.py against naive numpy references."""
import numpy as np

from collision_node.pipeline.frames import (quaternion_product, rotation_from_quaternion,
                                            squared_distance_outside, transposed_times)


def unit_quaternions(rng, count):
    turns = rng.normal(size=(count, 4))
    return turns / np.linalg.norm(turns, axis=1, keepdims=True)


def naive_rotation(quaternion):
    """R = I + 2 w [v]x + 2 [v]x^2 for a unit quaternion (v, w)."""
    x, y, z, w = quaternion
    skew = np.array([[0.0, -z, y], [z, 0.0, -x], [-y, x, 0.0]])
    return np.eye(3) + 2.0 * w * skew + 2.0 * skew @ skew


def test_rotation_from_quaternion_is_the_naive_rotation():
    for quaternion in unit_quaternions(np.random.default_rng(1), 200):
        rotation = np.array(rotation_from_quaternion(*quaternion)).reshape(3, 3)
        np.testing.assert_allclose(rotation, naive_rotation(quaternion), atol=1e-15)
        np.testing.assert_allclose(rotation @ rotation.T, np.eye(3), atol=1e-15)


def test_quaternion_product_composes_the_rotations():
    rng = np.random.default_rng(2)
    for p, q in zip(unit_quaternions(rng, 200), unit_quaternions(rng, 200)):
        product = quaternion_product(tuple(p), tuple(q))
        np.testing.assert_allclose(naive_rotation(product),
                                   naive_rotation(p) @ naive_rotation(q), atol=1e-14)
        assert abs(np.linalg.norm(product) - 1.0) < 1e-15


def test_squared_distance_outside_is_the_distance_to_the_closest_point():
    rng = np.random.default_rng(3)
    for quaternion in unit_quaternions(rng, 200):
        rotation = naive_rotation(quaternion)
        half = rng.uniform(0.01, 1.0, 3)
        point = rng.uniform(-2.0, 2.0, 3)  # from the box's centre, in the world's axes
        local = rotation.T @ point
        closest = np.clip(local, -half, half)
        expected = np.sum((local - closest) ** 2)
        r = tuple(rotation.ravel())
        got = squared_distance_outside(tuple(point), r, tuple(half))
        assert abs(got - expected) <= 1e-12 * (1.0 + expected)
        assert squared_distance_outside(tuple(-point), r, tuple(half)) == got  # symmetric
        inside = tuple(rotation @ (half * rng.uniform(-1.0, 1.0, 3)))
        assert squared_distance_outside(inside, r, tuple(half)) == 0.0


def test_transposed_times_is_the_transpose_times_the_vector():
    rng = np.random.default_rng(4)
    for quaternion in unit_quaternions(rng, 200):
        rotation, v = naive_rotation(quaternion), rng.normal(size=3)
        np.testing.assert_allclose(transposed_times(tuple(rotation.ravel()), tuple(v)),
                                   rotation.T @ v, atol=1e-15)
