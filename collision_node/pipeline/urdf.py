"""URDF and SRDF documents read into plain data, checked as they are read.

Only what the collision model needs is kept: links with their ``<collision>`` elements, joints
with their origin, axis, limits and mimic, and the SRDF's collision rules. Everything is
checked here, so the model built from it can trust it: a ``ValueError`` names the joint, the
link or the element that is wrong and why. Meshes are only named here (their URI);
collision_node.pipeline.meshes reads them.

Units and conventions are the URDF's: metres, radians, ``rpy`` about fixed axes x, y then z,
i.e. R = Rz(yaw) Ry(pitch) Rx(roll).
"""
import math
import os
from typing import NamedTuple
import xml.etree.ElementTree as ElementTree

FIXED = 'fixed'
REVOLUTE = 'revolute'
CONTINUOUS = 'continuous'
PRISMATIC = 'prismatic'
MOVING_TYPES = (REVOLUTE, CONTINUOUS, PRISMATIC)
# Joint types URDF defines that a box model cannot hold: they have several degrees of freedom
# (a floating base belongs to the base pose, not to q).
REFUSED_TYPES = ('floating', 'planar')

BOX = 'box'
CYLINDER = 'cylinder'
SPHERE = 'sphere'
MESH = 'mesh'


class Origin(NamedTuple):
    """An ``<origin>``: translation (m) and roll, pitch, yaw (rad); absent: zeros."""

    xyz: tuple = (0.0, 0.0, 0.0)
    rpy: tuple = (0.0, 0.0, 0.0)


class Collision(NamedTuple):
    """One ``<collision>`` element: its shape and the shape's frame in the link's frame.

    ``size`` is the shape's dimensions: box (x, y, z) full sizes; cylinder (radius, length);
    sphere (radius,); mesh its scale (x, y, z), with the file in ``uri``.
    """

    link: str
    origin: Origin
    shape: str
    size: tuple
    uri: str = ''


class Joint(NamedTuple):
    """One ``<joint>``: ``lower``/``upper`` are -inf/inf where the joint has no limits."""

    name: str
    kind: str             # fixed, revolute, continuous or prismatic
    parent: str
    child: str
    origin: Origin
    axis: tuple           # unit vector in the joint's frame
    lower: float
    upper: float
    mimic: str            # the joint it follows, '' if none
    multiplier: float
    offset: float


class Description(NamedTuple):
    """A URDF: link names and collision elements in document order, joints likewise.

    ``directory`` is the URDF file's folder ('' when the URDF was given as text): relative
    mesh paths are read from there.
    """

    name: str
    links: tuple
    collisions: tuple
    joints: tuple
    directory: str


class CollisionRules(NamedTuple):
    """An SRDF's collision rules: pairs (link1, link2, reason), links, pairs (link1, link2)."""

    disabled_pairs: tuple
    disabled_by_default: tuple
    enabled_pairs: tuple


def read_urdf(path_or_xml):
    """Return the :class:`Description` of a URDF file path or URDF XML text."""
    root, directory = _document(path_or_xml, 'URDF')
    if root.tag != 'robot':
        raise ValueError('URDF: the root element is <%s>, not <robot>' % root.tag)
    links, collisions = [], []
    for element in root.findall('link'):
        name = _required(element, 'name', '<link>')
        if name in links:
            raise ValueError('URDF: link %r is defined twice' % name)
        links.append(name)
        for number, collision in enumerate(element.findall('collision')):
            collisions.append(_collision(name, number, collision))
    if not links:
        raise ValueError('URDF: the robot has no <link>')
    joints = []
    for element in root.findall('joint'):
        joint = _joint(element, links)
        if any(other.name == joint.name for other in joints):
            raise ValueError('URDF: joint %r is defined twice' % joint.name)
        joints.append(joint)
    return Description(root.get('name', ''), tuple(links), tuple(collisions), tuple(joints),
                       directory)


def read_srdf(path_or_xml):
    """Return the :class:`CollisionRules` of an SRDF file path or SRDF XML text."""
    root, _ = _document(path_or_xml, 'SRDF')
    disabled = []
    for element in root.findall('disable_collisions'):
        disabled.append((_required(element, 'link1', '<disable_collisions>'),
                         _required(element, 'link2', '<disable_collisions>'),
                         element.get('reason', 'srdf')))
    by_default = tuple(_required(element, 'link', '<disable_default_collisions>')
                       for element in root.findall('disable_default_collisions'))
    enabled = tuple((_required(element, 'link1', '<enable_collisions>'),
                     _required(element, 'link2', '<enable_collisions>'))
                    for element in root.findall('enable_collisions'))
    return CollisionRules(tuple(disabled), by_default, enabled)


def _document(path_or_xml, kind):
    """Parse XML text (it starts with '<') or the file at a path; return (root, folder)."""
    text = path_or_xml if isinstance(path_or_xml, str) else None
    try:
        if text is not None and text.lstrip().startswith('<'):
            return ElementTree.fromstring(text), ''
        path = os.fspath(path_or_xml)
        return ElementTree.parse(path).getroot(), os.path.dirname(os.path.abspath(path))
    except ElementTree.ParseError as error:
        raise ValueError('%s: malformed XML: %s' % (kind, error)) from None
    except OSError as error:
        raise ValueError('%s: cannot read %r: %s' % (kind, path_or_xml, error)) from None


def _required(element, attribute, where):
    value = element.get(attribute)
    if not value:
        raise ValueError('URDF/SRDF: %s has no %r attribute' % (where, attribute))
    return value


def numbers(text, count, where):
    """Return ``count`` finite floats read from whitespace-separated ``text``."""
    try:
        values = tuple(float(word) for word in text.split())
    except ValueError:
        values = ()
    if len(values) != count or not all(math.isfinite(value) for value in values):
        raise ValueError('%s: expected %d finite numbers, got %r' % (where, count, text))
    return values


def _origin(element, where):
    origin = element.find('origin')
    if origin is None:
        return Origin()
    return Origin(numbers(origin.get('xyz', '0 0 0'), 3, where + ' <origin xyz>'),
                  numbers(origin.get('rpy', '0 0 0'), 3, where + ' <origin rpy>'))


def _collision(link, number, element):
    where = 'link %r <collision> %d' % (link, number)
    geometry = element.find('geometry')
    shapes = [] if geometry is None else list(geometry)
    if len(shapes) != 1:
        raise ValueError('%s: <geometry> must hold exactly one shape' % where)
    shape = shapes[0]
    origin = _origin(element, where)
    if shape.tag == BOX:
        size = numbers(shape.get('size', ''), 3, where + ' <box size>')
    elif shape.tag == CYLINDER:
        size = (numbers(shape.get('radius', ''), 1, where + ' <cylinder radius>')[0],
                numbers(shape.get('length', ''), 1, where + ' <cylinder length>')[0])
    elif shape.tag == SPHERE:
        size = numbers(shape.get('radius', ''), 1, where + ' <sphere radius>')
    elif shape.tag == MESH:
        scale = shape.get('scale', '1 1 1')
        # One number is read as the same scale on every axis, as urdfdom does.
        count = 1 if len(scale.split()) == 1 else 3
        size = numbers(scale, count, where + ' <mesh scale>') * (3 // count)
        return Collision(link, origin, MESH, size, _required(shape, 'filename', where))
    else:
        raise ValueError('%s: unknown shape <%s>' % (where, shape.tag))
    if any(value < 0.0 for value in size):
        raise ValueError('%s: negative <%s> dimension %r' % (where, shape.tag, size))
    return Collision(link, origin, shape.tag, size)


def _joint(element, links):
    name = _required(element, 'name', '<joint>')
    where = 'joint %r' % name
    kind = element.get('type', '')
    if kind in REFUSED_TYPES:
        raise ValueError('%s: %s joints are not supported (one degree of freedom per joint: '
                         'give a floating base as the base pose)' % (where, kind))
    if kind != FIXED and kind not in MOVING_TYPES:
        raise ValueError('%s: unknown joint type %r' % (where, kind))
    ends = []
    for end in ('parent', 'child'):
        found = element.find(end)
        link = None if found is None else found.get('link')
        if link not in links:
            raise ValueError('%s: %s link %r is not a <link> of the robot' % (where, end, link))
        ends.append(link)
    axis = (1.0, 0.0, 0.0)  # URDF's default axis
    if element.find('axis') is not None:
        axis = numbers(element.find('axis').get('xyz', '1 0 0'), 3, where + ' <axis xyz>')
    norm = math.sqrt(sum(value * value for value in axis))
    if kind != FIXED and norm == 0.0:
        raise ValueError('%s: <axis xyz> is the zero vector' % where)
    lower, upper = -math.inf, math.inf
    if kind in (REVOLUTE, PRISMATIC):
        limit = element.find('limit')
        if limit is None:
            raise ValueError('%s: a %s joint needs a <limit>' % (where, kind))
        # urdfdom reads a missing bound as 0.
        lower = numbers(limit.get('lower', '0'), 1, where + ' <limit lower>')[0]
        upper = numbers(limit.get('upper', '0'), 1, where + ' <limit upper>')[0]
        if lower > upper:
            raise ValueError('%s: <limit> lower %g > upper %g' % (where, lower, upper))
    mimic, multiplier, offset = '', 1.0, 0.0
    if element.find('mimic') is not None and kind != FIXED:
        mimic_element = element.find('mimic')
        mimic = _required(mimic_element, 'joint', where + ' <mimic>')
        multiplier = numbers(mimic_element.get('multiplier', '1'), 1,
                             where + ' <mimic multiplier>')[0]
        offset = numbers(mimic_element.get('offset', '0'), 1, where + ' <mimic offset>')[0]
    return Joint(name, kind, ends[0], ends[1], _origin(element, where),
                 tuple(value / norm for value in axis) if norm else axis, lower, upper, mimic,
                 multiplier, offset)
