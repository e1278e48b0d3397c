"""The ``ros2-mos`` command line: one typer app, each subcommand a thin call into the library.

Each module below registers its subcommands on :data:`app`; heavy imports (torch,
onnxruntime, rclpy) happen inside the commands so that ``--help`` stays instant.
"""

from ros2_mos.cli.app import app, main

# Each import registers its subcommands on `app`, and `--help` lists them in this order.
# isort: off
from ros2_mos.cli import core_commands  # noqa: F401  (infer, eval)
from ros2_mos.cli import train_commands  # noqa: F401
from ros2_mos.cli import ros_commands  # noqa: F401
from ros2_mos.cli import sim_commands  # noqa: F401
from ros2_mos.cli import offline_commands  # noqa: F401  (autolabel)
from ros2_mos.cli import apps_commands  # noqa: F401
from ros2_mos.cli import demo_command  # noqa: F401
from ros2_mos.cli import bench_command  # noqa: F401
from ros2_mos.cli import suite_command  # noqa: F401
# isort: on

__all__ = ["app", "main"]
