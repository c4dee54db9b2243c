"""Torque-level Cartesian impedance control and inverse kinematics (mink's, and its compiled twin) for the Panda.

Modules: `action` (Action: the command of one control period, as a policy gives it), `interface` (Controller: what
the episode stepping needs of a controller), `impedance` (CartesianImpedanceController, ImpedanceConfig),
`feedforward` (the velocity feed-forward lead it adds to an action's pose, compiled in `feedforward_kernel`), `ik`
(solve_ik, NullspaceReference, IKConfig), `timing` (measure_control_rate, measure_ik_rate: the speed `pih bench`
reports), `validation` (input checks), `errors` (ControllerError). Nothing else is imported here, so
`controllers.errors` stays cheap to import.
"""

from numerics.cpu_dispatch import pin_cpu_dispatch

pin_cpu_dispatch()  # first, before numpy or torch load: numpy's, torch's and MKL's kernel choices as `pih` pins them

__all__ = ["action", "errors", "feedforward", "ik", "impedance", "interface", "timing", "validation"]
