"""``python -m pld_slam_cli``: the ``pld-slam`` command (how ablation cells start their runs)."""

from pld_slam_cli.main import main

main()
