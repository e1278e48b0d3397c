"""The Fast DDS profile for full-size clouds between processes (``data/fastdds_large_messages.xml``).

The profile's 32 MB shared-memory segment cuts the transport part of the stamp -> /mos/labels
latency several-fold (benchmarks/design_figures.md).  DDS reads the profile when a process creates its
participant, so it has to be in the environment of a process before ``rclpy.init``: ``mos_node`` sets it
for itself when the user set no profile (so that subscribers in other processes with default settings get
its full-size clouds); ``python3 -m ros2_mos.ros.dds`` prints its path for
``export FASTRTPS_DEFAULT_PROFILES_FILE=...`` in the driver's and other processes.
"""

from __future__ import annotations

import os
from collections.abc import Mapping, MutableMapping
from importlib import resources
from pathlib import Path

PROFILE_NAME = "fastdds_large_messages.xml"
#: Fast DDS 2.x (Jazzy) reads the first, Fast DDS 3.x the second.
PROFILE_VARIABLES = ("FASTRTPS_DEFAULT_PROFILES_FILE", "FASTDDS_DEFAULT_PROFILES_FILE")


def profile_path() -> Path:
    """The profile shipped inside the package."""
    return Path(str(resources.files("ros2_mos") / "data" / PROFILE_NAME))


def use_large_message_profile(environ: MutableMapping[str, str] = os.environ) -> bool:
    """Point Fast DDS at the shipped profile unless the user chose a profile or another middleware.

    Returns True when the profile was set; the user's own profile or RMW always wins.
    """
    rmw = environ.get("RMW_IMPLEMENTATION", "rmw_fastrtps_cpp")
    if rmw != "rmw_fastrtps_cpp" or any(environ.get(v) for v in PROFILE_VARIABLES):
        return False
    for variable in PROFILE_VARIABLES:
        environ[variable] = str(profile_path())
    return True


def transport_summary(environ: Mapping[str, str], set_here: bool) -> str:
    """One line for the start-up log: which middleware and DDS profile this process uses, and who chose it."""
    rmw = environ.get("RMW_IMPLEMENTATION", "rmw_fastrtps_cpp")
    if rmw != "rmw_fastrtps_cpp":
        return f"transport: {rmw} with its own settings (ros2_mos sets no profile for it)"
    chosen = next((environ[v] for v in PROFILE_VARIABLES if environ.get(v)), "")
    if set_here:
        return (f"transport: Fast DDS with ros2_mos's large-message profile (32 MB shared memory + UDP), "
                f"set because no profile was given: {chosen}")
    return f"transport: Fast DDS with the user's profile {chosen} (kept as given)"


if __name__ == "__main__":
    print(profile_path())
