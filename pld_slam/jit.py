"""Numba kernels, compiled once per machine rather than once per process.

Every kernel of the package is declared with `kernel` (``numba.njit(nogil=True)``, cached
on disk). Compiling the kernels costs each process 1.5-2.5 s (the GGS query 1 s, the
stereo rows 0.35 s, the Jacobian fill 0.3 s), paid again by every ``pld-slam run``, every
ablation cell and every regression cell; loaded from the cache they cost 0.1-0.2 s.

Where the cache goes. Numba's default is a ``__pycache__`` folder next to the source,
inside the installed package: that folder may be read-only, and a reinstall leaves it
behind as a folder without ``__init__.py`` that shadows the new install (seen: a fresh
``pip install .`` then ``pip install -e .`` could no longer import ``pld_slam``). So
`pld_slam` sets ``NUMBA_CACHE_DIR`` to a user cache folder (``$XDG_CACHE_HOME/pld-slam/numba``,
else ``~/.cache/pld-slam/numba``) when the user has not set it, before numba is imported.
Where numba was imported earlier without it (a user's own program), there is no cache
folder to use and kernels are compiled per process, never cached next to the source.
Numba keys a cache entry by the source file's path and modification time, so an edited
or reinstalled package never loads a stale kernel. `pld_slam.kernels` compiles them all
before a run's first frame.
"""

import numba

_KERNELS: dict[str, numba.core.registry.CPUDispatcher] = {}
"""Every kernel declared so far, by qualified name (module and function)."""


def kernel(function):
    """``function`` compiled by ``numba.njit(nogil=True)``, cached on disk when a cache folder is set."""
    dispatcher = numba.njit(nogil=True, cache=bool(numba.config.CACHE_DIR))(function)
    _KERNELS[f"{function.__module__}.{function.__qualname__}"] = dispatcher
    return dispatcher


def compiled_kernels() -> dict[str, numba.core.registry.CPUDispatcher]:
    """The kernels of every module imported so far, by qualified name (`pld_slam.kernels` imports them all)."""
    return dict(_KERNELS)
