"""Skill execution on the testbed: policies from a trained skill, episodes, batch evaluation, figures.

The simulator (envs.scene, envs.env, envs.success, ...) knows nothing of learned skills; this package
turns a `rflow.skill_io.PoseSkill` into commanded poses and scores what the simulated peg did.
"""
