"""RiemannianFlow: stable skills on Riemannian manifolds learned with ImitationFlow. Never imports MuJoCo."""

from numerics.cpu_dispatch import pin_cpu_dispatch

pin_cpu_dispatch()  # first, before torch or numpy load: the kernel choices `pih` pins
