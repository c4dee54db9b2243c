"""RiemannianFlow: stable skills on Riemannian manifolds learned with ImitationFlow. Never imports MuJoCo."""

from numerics.cpu_dispatch import check_numpy_dispatch, pin_cpu_dispatch

pin_cpu_dispatch()
check_numpy_dispatch()
