"""Torque-level Cartesian impedance control and inverse kinematics (mink's, and its compiled twin) for the Panda.

Modules: `protocol` (Controller: what the episode stepping needs of a controller), `impedance`
(CartesianImpedanceController, ImpedanceConfig), `ik` (solve_ik, NullspaceReference, IKConfig), `benchmark`
(measure_control_rate, measure_ik_rate for `pih bench`), `validation` (input checks), `errors` (ControllerError).
Nothing else is imported here, so `controllers.errors` stays cheap to import.
"""

import rflow  # noqa: F401  first: pins numpy's kernel choices as `pih` does (rflow.cpu_dispatch)
