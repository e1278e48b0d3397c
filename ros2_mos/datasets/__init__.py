"""Readers and writers of the formats users have: SemanticKITTI folders and rosbag2 bags."""
