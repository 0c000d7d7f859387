"""Parameter files for the node's scenes, for the benchmarks and tests that start a node.

:func:`scene_parameters` turns a scene's boxes into the node's parameters,
:func:`write_params_file` writes them as a ``--params-file``, and :func:`write_scene_files`
writes large scenes as the node's ``static_scene_file`` and ``dynamic.half_extents_file``.
"""
import json
import os

import numpy as np

from collision_node.ros.params import POSE_SIZE


def scene_parameters(static_poses, static_half_extents, dynamic_half_extents, **values):
    """Return the node's parameters for a scene (name -> value), e.g. for a params file.

    The static boxes become colliders ``s0``, ``s1``, ... in their order; ``values`` sets the
    other parameters by name (``**{'diagnostic_updater.period': 0.5}`` for dotted names).
    """
    names = ['s%d' % i for i in range(len(static_poses))]
    values = dict(values, static_colliders=names, **{
        'dynamic.half_extents': np.asarray(dynamic_half_extents, np.float64).ravel().tolist()})
    for name, pose, extents in zip(names, np.asarray(static_poses, np.float64).tolist(),
                                   np.asarray(static_half_extents, np.float64).tolist()):
        values[name + '.pose'], values[name + '.half_extents'] = pose, extents
    return values


def write_scene_files(directory, static_poses, static_half_extents, dynamic_half_extents,
                      names=None):
    """Write a scene as ``static_scene_file`` and ``dynamic.half_extents_file``; return them.

    The files go to ``directory`` (scene.npz, dynamic_half_extents.npy); the static boxes are
    named ``s0``, ``s1``, ... unless ``names`` are given. Returns the two parameters (name ->
    path), for :func:`write_params_file` with the scene's other parameters.
    """
    scene = os.path.join(directory, 'scene.npz')
    sizes = os.path.join(directory, 'dynamic_half_extents.npy')
    count = len(static_poses)
    np.savez(scene, names=np.array(names if names is not None
                                   else ['s%d' % i for i in range(count)], dtype=str),
             poses=np.asarray(static_poses, np.float64).reshape(count, POSE_SIZE),
             half_extents=np.asarray(static_half_extents, np.float64).reshape(count, 3))
    np.save(sizes, np.asarray(dynamic_half_extents, np.float64))
    return {'static_scene_file': scene, 'dynamic.half_extents_file': sizes}


def write_params_file(path, values, node_name='collision_node'):
    """Write ``values`` (name -> value) as a --params-file (JSON is YAML).

    Empty lists are left out: they have no type in a ROS parameter file.
    """
    with open(path, 'w') as out:
        json.dump({node_name: {'ros__parameters': {
            name: value for name, value in values.items() if value != []}}}, out)
