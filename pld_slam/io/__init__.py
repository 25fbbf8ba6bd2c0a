"""File formats only: trajectories in the TUM, KITTI and EuRoC formats (`trajectory`), a run's
output files (`run_output`), the check of every command's output folder (`output_folder`), the
map (`map_ply`) and dynamic-label overlays (`dynamic_overlays`).

Which files a run writes is decided above, in `pld_slam.report.run_files`.
"""
