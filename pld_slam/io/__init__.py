"""Files in and out: trajectories in the TUM, KITTI and EuRoC formats (`trajectory`)."""
