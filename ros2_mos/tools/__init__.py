"""Tooling over the node and the pipeline: the benchmark and the process harness it and the demo use."""
