"""Views of part of a flat array as an array of any shape, for kernels that unpack workspaces.

A kernel handed one flat array that holds many (robot.pack_model's model, robot_pass's
workspace) makes a view of each part on every call. numba's ``a[i:j].reshape(shape)`` asks a
C helper whether the reshape can be done without a copy each time: about 30 ns a view, and a
call that unpacks 28 parts for one joint state spent a tenth of its time there. A part of a
C-contiguous flat array is C-contiguous in any shape, so :func:`view` writes the shape and
strides itself, after checking that the part lies within the array.

It is one intrinsic, bounds check included, not a jitted function around one: numba types a
jitted helper inlined into its callers again at every call site, and the robot's kernels make
over 70 views (half the robot's compile time went there).

:func:`copy_into` fills such a part from an array of its shape. numba's own slice assignment
(``part[:] = array``) compiles a formatted message for shapes that differ, its f-strings and
``str`` of ints, about 4 s in every process that compiles one; kernels copy with this instead.
"""
from numba.core import cgutils, types
from numba.core.imputils import impl_ret_borrowed
from numba.extending import intrinsic
from numba.np.arrayobj import make_array, populate_array

from collision_node.pipeline._jit import kernel

OUTSIDE = 'view: the part does not lie within the array'


@intrinsic
def view(typingctx, flat, start, shape):
    """Return ``flat[start:start + prod(shape)]`` as a C-contiguous array of ``shape``.

    ``flat``: a C-contiguous 1-D array; ``start``: an int; ``shape``: a tuple of ints.
    Raises IndexError (OUTSIDE) when a length is negative or the part does not lie within
    ``flat``.
    """
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

        def widened(value):
            return builder.sext(value, intp) if value.type.width < intp.width else value

        start_value = widened(start_value)
        lengths = [widened(length)
                   for length in cgutils.unpack_tuple(builder, shape_value, shape.count)]
        zero = intp(0)
        outside = builder.icmp_signed('<', start_value, zero)
        size = intp(1)
        for length in lengths:
            outside = builder.or_(outside, builder.icmp_signed('<', length, zero))
            size = builder.mul(size, length)
        end = builder.add(start_value, size)
        (flat_length,) = cgutils.unpack_tuple(builder, source.shape, 1)
        outside = builder.or_(outside, builder.icmp_signed('>', end, flat_length))
        with cgutils.if_unlikely(builder, outside):
            context.call_conv.return_user_exc(builder, IndexError, (OUTSIDE,))
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


@kernel
def copy_into(destination, source):
    """``destination[...] = source`` for two arrays of one shape (ValueError otherwise)."""
    if destination.shape != source.shape:
        raise ValueError('copy_into: the arrays differ in shape')
    for i, value in enumerate(source.flat):
        destination.flat[i] = value
