"""``python -m ros2_mos.cli`` = ``ros2-mos`` (where the console script is not installed)."""

from ros2_mos.cli.app import main

main()
