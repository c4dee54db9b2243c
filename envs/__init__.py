"""Simulated Franka Panda peg-in-hole testbed (MuJoCo)."""
