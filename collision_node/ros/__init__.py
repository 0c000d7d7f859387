"""The ROS edge: the node, its parameters, and its messages as bytes.

PoseArray in; PointCloud2, MarkerArray and DiagnosticArray out. It imports the pipeline and
nothing else of ``collision_node``.
"""
