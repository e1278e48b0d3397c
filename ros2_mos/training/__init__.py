"""Training, export and benchmarking of the MOS networks (the only place torch is imported).

The core runtime (``ros2_mos.core.inference``) runs the exported ONNX models without
torch; everything here needs numpy + torch only, so it also runs on a GPU machine
without kiss-icp or rclpy.
"""
