from glob import glob

from setuptools import find_packages, setup

package_name = 'collision_node'

setup(
    name=package_name,
    version='0.1.0',
    packages=find_packages(exclude=['test']),
    data_files=[
        ('share/ament_index/resource_index/packages', ['resource/' + package_name]),
        ('share/' + package_name, ['package.xml', 'LICENSE']),
        ('share/' + package_name + '/config', glob('config/*.yaml') + glob('config/*.xml')),
    ],
    install_requires=['setuptools', 'numpy', 'numba', 'trimesh', 'pycollada'],
    extras_require={
        # pin and example-robot-data: the robot model's FK reference and its robots; ray: the
        # cluster's tests.
        'test': ['pytest', 'hypothesis', 'python-fcl', 'coal', 'pin', 'example-robot-data',
                 'ray'],
        # robot sections: coal, mujoco; robot_model: pin, example-robot-data (its Panda).
        'bench': ['python-fcl', 'coal', 'mujoco', 'matplotlib', 'pin', 'example-robot-data'],
        'ray': ['ray'],  # collision_node.cluster and collision_label (doc/cluster.md)
    },
    zip_safe=False,
    maintainer='collision_node maintainers',
    maintainer_email='collision-node@example.com',
    description='Real-time OBB collision detection node for ROS 2',
    license='Apache-2.0',
    entry_points={
        'console_scripts': [
            'collision_node = collision_node.tools.programs:collision_node',
            'pose_publisher = collision_node.tools.programs:pose_publisher',
            'collision_monitor = collision_node.tools.programs:collision_monitor',
            'collision_demo = collision_node.tools.programs:collision_demo',
            'collision_bench = collision_node.benchmarks.collision_bench:main',
            'collision_latency = collision_node.benchmarks.collision_latency:main',
            'collision_soak = collision_node.benchmarks.collision_soak:main',
            'collision_label = collision_node.tools.label:main',
        ],
    },
)
