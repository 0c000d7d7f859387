"""flat_views.view: a part of a flat array in any shape, against numpy's reshape of a slice."""
import numpy as np
import pytest

from collision_node.pipeline._jit import kernel
from collision_node.pipeline.flat_views import view


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
