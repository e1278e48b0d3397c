"""Scoring: the fixed evaluation suite and the heuristic baselines it compares with."""
