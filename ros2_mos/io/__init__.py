"""Readers and writers of the formats users have: PointCloud2 buffers, SemanticKITTI folders, rosbag2 bags."""
