"""Online moving object segmentation (MOS) for rotating 3D LiDAR (Chen et al., RA-L 2021)."""

__version__ = "0.1.0"
