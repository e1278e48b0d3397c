"""A rotating-LiDAR street simulator that writes labelled SemanticKITTI sequences (and rosbag2 bags).

Scenes are Manhattan-like street grids with buildings, vegetation, poles and
parked cars; traffic (cars, cyclists, pedestrians) moves, stops and goes; the
ego vehicle drives, turns and waits at lights.  Rays are cast with Embree
(``embreex``).  Points are labelled with SemanticKITTI ids, moving ids
(252-254) where the object's pose changed since the previous scan.

Main entry points: :func:`simulate_sequence` (write a sequence),
:class:`SequenceSimulator` (scans in memory), :data:`SIM_PRESETS`.
"""

from ros2_mos.sim.presets import SIM_PRESETS, SimPreset, sim_preset, with_effects
from ros2_mos.sim.stats import SequenceStats, format_stats
from ros2_mos.sim.world import SequenceSimulator, SimScan
from ros2_mos.sim.writer import iter_sequence_scans, sequence_dir, simulate_sequence, write_sequence_bag

__all__ = [
    "SIM_PRESETS",
    "SequenceSimulator",
    "SequenceStats",
    "SimPreset",
    "SimScan",
    "format_stats",
    "iter_sequence_scans",
    "sequence_dir",
    "sim_preset",
    "simulate_sequence",
    "with_effects",
    "write_sequence_bag",
]
