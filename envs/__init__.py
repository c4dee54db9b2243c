"""Simulated Franka Panda peg-in-hole testbed (MuJoCo)."""

import rflow  # noqa: F401  first: pins numpy's, torch's and MKL's kernel choices as `pih` does (rflow.cpu_dispatch)
