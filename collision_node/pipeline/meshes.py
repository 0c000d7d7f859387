"""Mesh files found from their URDF URIs, and the oriented box fitted to each.

A URI is found as ROS finds it: ``package://pkg/path`` through the ament index (each prefix of
``AMENT_PREFIX_PATH`` that registers ``pkg`` holds its files under ``share/pkg``), then in the
caller's ``package_paths`` (folders holding ``pkg/path``); ``file://`` URIs and plain paths as
files, relative ones from the URDF's folder. STL (binary and ASCII), OBJ and COLLADA are read
with trimesh (COLLADA through pycollada).

The box. Every vertex is inside it, by construction: whatever orientation is chosen, the box's
extent along each of its axes is the vertices' own range along that axis. The orientation is
the smallest-volume one among a few candidates: the mesh frame's axes (so the box is never
larger than the vertices' axis-aligned box), the vertices' principal axes, and each of these
turned about one of its axes to the smallest rectangle around the convex outline of the
vertices projected on the plane across that axis (rotating calipers). That is trimesh's
``oriented_bounds`` idea without its SciPy convex hull (SciPy is not a dependency).

trimesh is imported on first use: it costs ~0.16 s, which ``from collision_node import World``
should not pay.
"""
import os
from typing import NamedTuple

import numpy as np

PACKAGE_SCHEME = 'package://'
FILE_SCHEME = 'file://'
# The ament index: a package is installed under a prefix when this marker file exists.
AMENT_MARKERS = os.path.join('share', 'ament_index', 'resource_index', 'packages')


class MeshBox(NamedTuple):
    """A box holding a mesh's vertices, in the mesh's frame (scale applied).

    ``rotation`` columns are the box axes (a proper rotation); ``mesh_volume`` is the volume
    the mesh encloses when it is closed (watertight), NaN when it is not.
    """

    center: np.ndarray        # (3,)
    rotation: np.ndarray      # (3, 3)
    half_extents: np.ndarray  # (3,)
    mesh_volume: float


def resolve(uri, link, directory='', package_paths=()):
    """Return the path of the file ``uri`` names; ValueError naming ``link`` and ``uri``."""
    if uri.startswith(PACKAGE_SCHEME):
        package, _, inside = uri[len(PACKAGE_SCHEME):].partition('/')
        candidates = [os.path.join(prefix, 'share', package, inside)
                      for prefix in os.environ.get('AMENT_PREFIX_PATH', '').split(os.pathsep)
                      if prefix and os.path.isfile(os.path.join(prefix, AMENT_MARKERS, package))]
        candidates += [os.path.join(folder, package, inside) for folder in package_paths]
    else:
        path = uri[len(FILE_SCHEME):] if uri.startswith(FILE_SCHEME) else uri
        if not os.path.isabs(path) and not directory:
            raise ValueError('link %r: mesh %r is a relative path, and the URDF was given as '
                             'text: give the URDF as a file path or the mesh as an absolute '
                             'path' % (link, uri))
        candidates = [os.path.join(directory, path)]
    for candidate in candidates:
        if os.path.isfile(candidate):
            return candidate
    raise ValueError('link %r: mesh %r not found (looked in: %s)'
                     % (link, uri, ', '.join(candidates) or 'no package of that name in '
                        'AMENT_PREFIX_PATH or package_paths'))


def read_vertices(path, link, uri):
    """Return the (N, 3) float64 vertices of the mesh file at ``path``."""
    import trimesh
    try:
        mesh = trimesh.load(path, force='mesh')
        vertices = np.asarray(mesh.vertices, dtype=np.float64)
        volume = float(mesh.volume) if mesh.is_watertight else np.nan
    except Exception as error:  # noqa: B902 (trimesh raises many kinds for a bad file)
        raise ValueError('link %r: mesh %r (%s) cannot be read: %s'
                         % (link, uri, path, error)) from None
    if len(vertices) == 0 or not np.isfinite(vertices).all():
        raise ValueError('link %r: mesh %r (%s) has no vertices or non-finite ones'
                         % (link, uri, path))
    return vertices, abs(volume)


def fit_box(vertices, scale, volume):
    """Return the :class:`MeshBox` of ``vertices`` (N, 3) scaled by ``scale`` (3,).

    ``volume`` is the unscaled mesh's enclosed volume (NaN: not closed).
    """
    points = np.unique(vertices * np.asarray(scale, dtype=np.float64), axis=0)
    candidates = [np.eye(3), _principal_axes(points)]
    for rotation in list(candidates):
        for axis in range(3):
            candidates.append(_turned_to_smallest_outline(points, rotation, axis))
    best = min((_box_along(points, rotation) for rotation in candidates),
               key=lambda box: np.prod(box[2]))
    return MeshBox(*best, volume * abs(float(np.prod(scale))))


def _box_along(points, rotation):
    """Return (center, rotation, half extents) of the box of ``points`` with these axes."""
    local = points @ rotation
    low, high = local.min(axis=0), local.max(axis=0)
    return rotation @ (0.5 * (low + high)), rotation, 0.5 * (high - low)


def _principal_axes(points):
    """Return the eigenvectors of the points' covariance as a proper rotation."""
    _, vectors = np.linalg.eigh(np.cov(points.T) if len(points) > 1 else np.eye(3))
    return _proper(vectors)


def _proper(rotation):
    """Flip the last column if needed, so that the determinant is +1 (a rotation)."""
    if np.linalg.det(rotation) < 0.0:
        rotation = rotation.copy()
        rotation[:, 2] = -rotation[:, 2]
    return rotation


def _turned_to_smallest_outline(points, rotation, axis):
    """Return ``rotation`` turned about its column ``axis`` to the smallest 2-D rectangle."""
    u, v = rotation[:, (axis + 1) % 3], rotation[:, (axis + 2) % 3]
    hull = _hull_2d(np.stack([points @ u, points @ v], axis=1))
    if len(hull) < 3:
        return rotation
    # The smallest rectangle around a convex polygon has a side along one of its edges.
    edges = np.roll(hull, -1, axis=0) - hull
    angles = np.arctan2(edges[:, 1], edges[:, 0])
    cos, sin = np.cos(angles), np.sin(angles)
    along = np.outer(cos, hull[:, 0]) + np.outer(sin, hull[:, 1])
    across = np.outer(-sin, hull[:, 0]) + np.outer(cos, hull[:, 1])
    areas = np.ptp(along, axis=1) * np.ptp(across, axis=1)
    best = int(np.argmin(areas))
    turned = rotation.copy()
    turned[:, (axis + 1) % 3] = cos[best] * u + sin[best] * v
    turned[:, (axis + 2) % 3] = -sin[best] * u + cos[best] * v
    return turned


def _hull_2d(points):
    """Return the convex hull of 2-D ``points`` counter-clockwise (Andrew's monotone chain)."""
    points = np.unique(points, axis=0)  # sorted by x then y, as the chain needs
    if len(points) < 3:
        return points

    def half(sequence):
        chain = []
        for point in sequence:
            while len(chain) >= 2 and _cross(chain[-2], chain[-1], point) <= 0.0:
                chain.pop()
            chain.append(point)
        return chain[:-1]
    listed = [tuple(point) for point in points]
    return np.array(half(listed) + half(reversed(listed)))


def _cross(o, a, b):
    return (a[0] - o[0]) * (b[1] - o[1]) - (a[1] - o[1]) * (b[0] - o[0])
