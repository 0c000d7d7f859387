"""Views of part of a flat array as an array of any shape, for kernels that unpack workspaces.

A kernel handed one flat array that holds many (robot.pack_model's model, robot_pass's
workspace) makes a view of each part on every call. numba's ``a[i:j].reshape(shape)`` asks a
C helper whether the reshape can be done without a copy each time: about 30 ns a view, and a
call that unpacks 28 parts for one joint state spent a tenth of its time there. A part of a
C-contiguous flat array is C-contiguous in any shape, so :func:`view` writes the shape and
strides itself, after checking that the part lies within the array.
"""
from numba.core import cgutils, types
from numba.core.imputils import impl_ret_borrowed
from numba.extending import intrinsic
from numba.np.arrayobj import make_array, populate_array

from collision_node.pipeline._jit import inlined_kernel


@inlined_kernel
def view(flat, start, shape):
    """Return ``flat[start:start + prod(shape)]`` as a C-contiguous array of ``shape``.

    ``flat``: a C-contiguous 1-D array; ``shape``: a tuple of ints. Raises IndexError when
    the part does not lie within ``flat``.
    """
    size = 1
    for length in shape:
        if length < 0:
            raise IndexError('view: a negative length')
        size *= length
    if start < 0 or start + size > flat.shape[0]:
        raise IndexError('view: the part does not lie within the array')
    return _unchecked_view(flat, start, shape)


@intrinsic
def _unchecked_view(typingctx, flat, start, shape):
    """:func:`view` without its bounds check: the array struct filled in place."""
    if not (isinstance(flat, types.Array) and flat.ndim == 1 and flat.layout == 'C'
            and isinstance(start, types.Integer) and isinstance(shape, types.UniTuple)
            and isinstance(shape.dtype, types.Integer)):
        return None
    result_type = types.Array(flat.dtype, shape.count, 'C')

    def codegen(context, builder, signature, arguments):
        flat_value, start_value, shape_value = arguments
        source = make_array(signature.args[0])(context, builder, flat_value)
        result = make_array(result_type)(context, builder)
        intp = context.get_value_type(types.intp)
        lengths = [builder.sext(length, intp) if length.type.width < intp.width else length
                   for length in cgutils.unpack_tuple(builder, shape_value, shape.count)]
        strides, stride = [], source.itemsize
        for length in reversed(lengths):
            strides.insert(0, stride)
            stride = builder.mul(stride, length)
        populate_array(result, data=builder.gep(source.data, [start_value]), shape=lengths,
                       strides=strides, itemsize=source.itemsize, meminfo=source.meminfo,
                       parent=None)
        # The view shares the flat array's memory: one more reference to it.
        return impl_ret_borrowed(context, builder, result_type, result._getvalue())

    return result_type(flat, start, shape), codegen
