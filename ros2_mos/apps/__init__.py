"""The paper's applications (Sec. IV-E): MOS-masked LiDAR odometry and clean maps.

``kitti_metrics``  KITTI odometry benchmark errors (relative, 100..800 m) and ATE
``odometry``       KISS-ICP over a sequence with no mask, the MOS mask, or the ground-truth mask
``mapping``        :class:`~ros2_mos.apps.mapping.VoxelMap`, raw vs MOS-cleaned maps, ghost share,
                   PLY/PCD writers and a bird's-eye-view PNG like the paper's Fig. 8
"""
