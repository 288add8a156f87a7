"""ament_python entry for colcon (`colcon build`, then `ros2 run cikan_ros sim_node`).

Metadata, packages, dependencies and the node console scripts live in pyproject.toml; this
file only adds the files ament needs: the package marker, package.xml and the default params.
"""

from setuptools import setup

setup(
    data_files=[
        ("share/ament_index/resource_index/packages", ["resource/cikan_ros"]),
        ("share/cikan_ros", ["package.xml"]),
        ("share/cikan_ros/config", ["config/cikan.yaml"]),
    ],
)
