"""Skill execution on the testbed: the Policy protocol, policies (a trained skill, the scripted expert, a replay, a
user's), episodes, batch evaluation, figures.

The simulator (envs.scene, envs.env, envs.success, ...) knows nothing of learned skills; this package turns a
policy's actions (envs.execution.policy_protocol) into commanded poses and scores what the simulated peg did.
"""
