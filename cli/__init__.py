"""The ``pld-slam`` command line; installed as ``pld_slam_cli``. Commands only parse
arguments, call the library and print; all the work is in ``pld_slam``."""
