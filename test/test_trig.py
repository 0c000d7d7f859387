"""Sine and cosine together (pipeline/trig.py) against the C library's, through math.

The forward kinematics turns every revolute joint with them, so they must be as exact as the
C library's: within 1 ulp of math.sin and math.cos over the angles a joint can take, and
exactly math's beyond the range they reduce exactly, and for NaN and Inf.
"""
import math

import numpy as np
import pytest

from collision_node.pipeline._jit import kernel
from collision_node.pipeline.trig import REDUCED_LIMIT, reduced_sincos, sincos


@kernel
def _all_sincos(angles, sines, cosines):
    for k in range(angles.shape[0]):
        sines[k], cosines[k] = sincos(angles[k])


@kernel
def _all_reduced(angles, sines, cosines):
    for k in range(angles.shape[0]):
        sines[k], cosines[k] = reduced_sincos(angles[k])


def both(function, angles):
    sines, cosines = np.empty_like(angles), np.empty_like(angles)
    function(angles, sines, cosines)
    return sines, cosines


def ulps(ours, reference):
    """Return |ours - reference| in units of the reference's last place."""
    return np.abs(ours - reference) / np.spacing(np.abs(reference))


def angles_a_joint_takes():
    rng = np.random.default_rng(0)
    return np.concatenate([
        rng.uniform(-8.0, 8.0, 200_000),                   # joint limits, half angles
        rng.uniform(-REDUCED_LIMIT, REDUCED_LIMIT, 50_000),  # continuous joints far round
        np.arange(-40, 41) * (math.pi / 4),                 # quadrant edges, sin or cos near 0
        np.nextafter(np.arange(-8, 9) * (math.pi / 2), np.inf),
        [0.0, -0.0, 5e-324, 1e-300, 1e-8, -1e-8, REDUCED_LIMIT, -REDUCED_LIMIT]])


def test_within_one_ulp_of_the_c_library():
    angles = angles_a_joint_takes()
    sines, cosines = both(_all_sincos, angles)
    expected_sines = np.array([math.sin(x) for x in angles])
    expected_cosines = np.array([math.cos(x) for x in angles])
    assert ulps(sines, expected_sines).max() <= 1.0
    assert ulps(cosines, expected_cosines).max() <= 1.0
    # Sine and cosine of one angle stay a unit pair, as a quaternion's half turn needs.
    assert np.abs(sines ** 2 + cosines ** 2 - 1.0).max() < 4e-16


def test_the_reduced_path_is_sincos_bit_for_bit_within_its_limit():
    """A loop that tested its angles against REDUCED_LIMIT calls reduced_sincos alone."""
    angles = angles_a_joint_takes()
    for ours, theirs in zip(both(_all_reduced, angles), both(_all_sincos, angles)):
        np.testing.assert_array_equal(ours, theirs)


@pytest.mark.parametrize('angle', [np.nextafter(REDUCED_LIMIT, np.inf), -1e6, 3e7, 1e300,
                                   np.inf, -np.inf, np.nan])
def test_beyond_the_limit_and_non_finite_angles_are_the_c_library_s(angle):
    sine, cosine = both(_all_sincos, np.array([angle]))
    np.testing.assert_array_equal(sine, [math.sin(angle)] if np.isfinite(angle) else [np.nan])
    np.testing.assert_array_equal(cosine, [math.cos(angle)] if np.isfinite(angle)
                                  else [np.nan])
