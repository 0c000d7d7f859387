"""flat_views: view against numpy's reshape of a slice, copy_into against assignment."""
import numpy as np
import pytest

from collision_node.pipeline._jit import kernel
from collision_node.pipeline.flat_views import copy_into, view


@kernel
def _views_of(flat, start):
    """Return views of ``flat`` from ``start`` in the shapes the kernels use."""
    return (view(flat, start, (4,)), view(flat, start, (2, 3)), view(flat, start, (2, 3, 3)),
            view(flat, start, (0, 3)))


@kernel
def _view_2d(flat, start, rows, columns):
    return view(flat, start, (rows, columns))


@pytest.mark.parametrize('dtype', [np.float64, np.int64])
def test_views_equal_reshaped_slices_and_share_memory(dtype):
    flat = np.arange(40).astype(dtype)
    for start in (0, 1, 7, 22):
        for got in _views_of(flat, start):
            expected = flat[start:start + got.size].reshape(got.shape)
            np.testing.assert_array_equal(got, expected)
            assert got.dtype == dtype and got.flags.c_contiguous
            assert got.size == 0 or np.shares_memory(got, flat)


def test_a_view_keeps_its_array_alive():
    made = _views_of(np.arange(40.0), 5)[2]  # nothing else holds the flat array
    np.testing.assert_array_equal(made, np.arange(5.0, 23.0).reshape(2, 3, 3))


@pytest.mark.parametrize('start, rows, columns', [(-1, 1, 1), (0, 6, 3), (14, 1, 2),
                                                  (0, -1, 3)])
def test_a_part_outside_the_array_raises(start, rows, columns):
    with pytest.raises(IndexError):
        _view_2d(np.zeros(15), start, rows, columns)


@kernel
def _copy(destination, source):
    copy_into(destination, source)


@pytest.mark.parametrize('shape', [(5,), (3, 4), (2, 2, 3), (0, 3)])
def test_copy_into_equals_numpy_assignment(shape):
    source = np.random.default_rng(1).normal(size=shape)
    destination = np.zeros(shape)
    _copy(destination, source)
    np.testing.assert_array_equal(destination, source)


def test_copy_into_a_column_and_from_a_gather():
    table = np.zeros((4, 3), np.int64)
    _copy(table[:, 1], np.arange(4))  # a strided destination
    np.testing.assert_array_equal(table, [[0, k, 0] for k in range(4)])
    values = np.arange(10.0)
    order = np.array([3, 1, 2])
    _copy(values[:3], values[order])  # read whole before the write, as numpy's
    np.testing.assert_array_equal(values[:3], [3.0, 1.0, 2.0])


def test_copy_into_arrays_of_other_shapes_raises():
    with pytest.raises(ValueError, match='differ in shape'):
        _copy(np.zeros((2, 3)), np.zeros((3, 2)))
