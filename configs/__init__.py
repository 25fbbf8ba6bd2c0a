"""The YAML configuration files (defaults and dataset families), installed as `pld_slam.configs`."""
