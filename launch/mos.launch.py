"""Launch mos_node with the package's parameters: `ros2 launch ros2_mos mos.launch.py`.

Needs a ROS 2 install (launch and launch_ros are not in the PyPI wheels; off a
ROS install run the `mos_node` console script with `--ros-args --params-file`).

Arguments: params_file (default: the installed config/mos.yaml), model (empty:
the params file's / the shipped model), input_topic (remaps /points), reliable
(true for reliable input QoS), log_level.
"""

import os

from ament_index_python.packages import get_package_share_directory
from launch import LaunchDescription
from launch.actions import DeclareLaunchArgument
from launch.conditions import IfCondition, UnlessCondition
from launch.substitutions import LaunchConfiguration, PythonExpression
from launch_ros.actions import Node


def generate_launch_description() -> LaunchDescription:
    default_params = os.path.join(get_package_share_directory("ros2_mos"), "config", "mos.yaml")
    params_file = LaunchConfiguration("params_file")
    model = LaunchConfiguration("model")
    input_topic = LaunchConfiguration("input_topic")
    reliable = LaunchConfiguration("reliable")
    log_level = LaunchConfiguration("log_level")

    def node(with_model: bool) -> Node:
        overrides = {
            "qos.reliability": PythonExpression(["'reliable' if '", reliable, "' == 'true' else 'best_effort'"])
        }
        if with_model:
            overrides["model"] = model
        has_model = PythonExpression(["'", model, "' != ''"])
        return Node(
            package="ros2_mos",
            executable="mos_node",
            name="mos_node",
            output="screen",
            emulate_tty=True,
            parameters=[params_file, overrides],
            remappings=[("/points", input_topic)],
            arguments=["--ros-args", "--log-level", log_level],
            condition=IfCondition(has_model) if with_model else UnlessCondition(has_model),
        )

    return LaunchDescription([
        DeclareLaunchArgument("params_file", default_value=default_params, description="ROS params file"),
        DeclareLaunchArgument("model", default_value="", description="ONNX model; empty: from the params file"),
        DeclareLaunchArgument("input_topic", default_value="/points", description="PointCloud2 input topic"),
        DeclareLaunchArgument("reliable", default_value="false", description="reliable input QoS"),
        DeclareLaunchArgument("log_level", default_value="info", description="node log level"),
        node(with_model=True),
        node(with_model=False),
    ])
