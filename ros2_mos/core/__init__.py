"""The pipeline's stages and the pipeline: projection, residuals, odometry, the network, labels back to points.

No ROS, no file formats: everything above (I/O, scoring, the node, the tools) builds on this layer.
"""
