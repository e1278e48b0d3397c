"""Offline labelling of whole drives: past and future scans together (``ros2-mos autolabel``)."""
