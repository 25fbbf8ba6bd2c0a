"""The ``pld-slam`` command line; installed as ``pld_slam_cli``. Commands only parse
arguments, call the library and print; all the work is in ``pld_slam``.

OpenBLAS runs single-threaded unless the user says otherwise: `pld_slam` sets
``OPENBLAS_NUM_THREADS`` when it is imported (its docstring says why).

OpenCV logs errors only unless the user says otherwise (``OPENCV_LOG_LEVEL``, read when
OpenCV loads): its ``WARN`` lines (e.g. ``imread_(...): can't open/read file``) repeat, in
the middle of the output, a problem the command reports itself in one line.
"""

import os

os.environ.setdefault("OPENCV_LOG_LEVEL", "ERROR")
