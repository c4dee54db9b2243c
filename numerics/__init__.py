"""Numerics at the bottom of the project, on numpy, numba and the standard library only: unit quaternions
(`quaternion`), the rigid pose as a value (`pose`), BLAS-free small linear algebra (`small_linalg`), the numpy/torch dispatch of array maps that never
imports torch (`arrays`), the pin of numpy's, torch's and MKL's CPU-dependent code paths (`cpu_dispatch`) and the
package's exception (`errors`). `controllers`, `envs` and `rflow` take these from here.

The pin is set here, before anything of this package imports numpy (`cpu_dispatch` imports the standard library only),
and checked once: a numpy loaded earlier with the loops the pin turns off is warned about. The packages above call
`pin_cpu_dispatch` first thing too, so none of them depends on another's import for it.
"""

from numerics.cpu_dispatch import check_numpy_dispatch, pin_cpu_dispatch

pin_cpu_dispatch()
check_numpy_dispatch()

__all__ = ["arrays", "cpu_dispatch", "errors", "pose", "quaternion", "small_linalg"]
