"""Simulated Franka Panda peg-in-hole testbed (MuJoCo)."""

from numerics.cpu_dispatch import check_numpy_dispatch, pin_cpu_dispatch

pin_cpu_dispatch()  # first, before numpy or torch load: numpy's, torch's and MKL's kernel choices as `pih` pins them
check_numpy_dispatch()
