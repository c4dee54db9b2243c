"""Torque-level Cartesian impedance control and mink inverse kinematics for the Panda."""
