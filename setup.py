"""ament_python package setup: the same file serves colcon on a ROS 2 install and pip off it."""

from glob import glob

from setuptools import Extension, find_packages, setup

PACKAGE = "ros2_mos"

setup(
    name=PACKAGE,
    version="0.1.0",
    packages=find_packages(exclude=["test", "test.*"]),
    # The shipped model and default config travel inside the package too, so that
    # `pip install .` and `pip install -e .` find them through importlib.resources.
    package_data={PACKAGE: ["models/*.onnx", "models/adapted/*.onnx", "models/alternatives/*.onnx", "models/*.json",
                            "data/*.yaml", "data/*.xml"]},
    data_files=[
        ("share/ament_index/resource_index/packages", [f"resource/{PACKAGE}"]),
        (f"share/{PACKAGE}", ["package.xml"]),
        (f"share/{PACKAGE}/launch", glob("launch/*.py")),
        (f"share/{PACKAGE}/config", glob("config/*.yaml") + glob(f"{PACKAGE}/data/*.xml")),
        (f"share/{PACKAGE}/models", glob(f"{PACKAGE}/models/*.onnx")),
        (f"share/{PACKAGE}/models/adapted", glob(f"{PACKAGE}/models/adapted/*.onnx")),
        (f"share/{PACKAGE}/models/alternatives", glob(f"{PACKAGE}/models/alternatives/*.onnx")),
    ],
    # The runtime (node, infer, eval, process, replay) needs no torch. rclpy and the message
    # packages come from a ROS 2 Jazzy install or the ros-jazzy-* PyPI wheels (requirements.txt).
    # kiss-icp and rosbags are pinned: ros2_mos.core.odometry follows KISS-ICP 1.3.0's register_frame, and
    # ros2_mos.io.bags writes MCAP chunk CRCs with rosbags 0.11.9's writer.
    install_requires=["setuptools", "numpy", "pyyaml", "typer", "tqdm", "onnx", "onnxruntime", "kiss-icp==1.3.0",
                      "rosbags==0.11.9"],
    extras_require={
        "sim": ["embreex", "trimesh"],
        "train": ["torch==2.13.0", "onnxscript"],
        "apps": ["trimesh", "pillow"],
    },
    # Plain C (no Python or numpy headers), loaded with ctypes by ros2_mos/core/kernels.py; the numpy code
    # runs where it is not built. -ffp-contract=off keeps its float32 arithmetic bit-identical to numpy's.
    ext_modules=[Extension(f"{PACKAGE}.core._kernels", sources=[f"{PACKAGE}/core/_kernels.c"],
                           extra_compile_args=["-O3", "-ffp-contract=off", "-fno-math-errno", "-fno-trapping-math"],
                           optional=True)],
    zip_safe=False,
    maintainer="ros2_mos developers",
    maintainer_email="dev@ros2-mos.invalid",
    description="Online moving object segmentation for rotating 3D LiDAR (ROS 2 Jazzy).",
    license="MIT",
    entry_points={
        "console_scripts": [
            "ros2-mos = ros2_mos.cli.app:main",
            "mos_node = ros2_mos.ros.node:main",
        ],
    },
)
