"""The ``pld-slam`` command line; installed as ``pld_slam_cli``. Commands only parse
arguments, call the library and print; all the work is in ``pld_slam``.

OpenBLAS runs single-threaded unless the user says otherwise (``OPENBLAS_NUM_THREADS``,
set here before numpy loads it): the pipeline's dense algebra is small (6 x 6 to a few
hundred columns) and its threads only spin. Measured on KITTI 06 with another process
on the 2-core machine: local BA median 852 ms per keyframe with OpenBLAS's threads, 163 ms
with one; the whole run 735 against 292-368 ms per frame.

OpenCV logs errors only unless the user says otherwise (``OPENCV_LOG_LEVEL``, read when
OpenCV loads): its ``WARN`` lines (e.g. ``imread_(...): can't open/read file``) repeat, in
the middle of the output, a problem the command reports itself in one line.
"""

import os

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
os.environ.setdefault("OPENCV_LOG_LEVEL", "ERROR")
