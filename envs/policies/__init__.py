"""What acts once per control period: the `Policy` interface with the `Observation` a policy sees and the `Action` it
returns (`interface`); the RiemannianFlow skill (`flow_skill`, its settings `skill_settings`, the contact adaptation
`adaptation`, compiled in `closed_loop_kernel`); the scripted expert (`expert`, its plan `expert_plan`, its stiffness
`stiffness_schedule`); the replay of a recorded trajectory (`replay`); any policy in the frame of the observed hole
(`goal_frame`). The `Action` is controllers.action's (what a controller takes), re-exported here.
"""

from pihutil.lazy import lazy_exports

EXPORTS: dict[str, str] = {
    "Action": "controllers.action",
    "Observation": "envs.policies.interface",
    "Policy": "envs.policies.interface",
    "PolicyTask": "envs.policies.interface",
    "PrivilegedState": "envs.policies.interface",
    "is_policy": "envs.policies.interface",
    "observe": "envs.policies.interface",
    "policy_task": "envs.policies.interface",
    "ClosedLoopPolicy": "envs.policies.flow_skill",
    "OpenLoopPolicy": "envs.policies.flow_skill",
    "make_policy": "envs.policies.flow_skill",
    "StiffnessSetting": "envs.policies.skill_settings",
    "ContactAdaptation": "envs.policies.adaptation",
    "ScriptedExpertPolicy": "envs.policies.expert",
    "ExpertConfig": "envs.policies.expert_plan",
    "StiffnessSchedule": "envs.policies.stiffness_schedule",
    "ReplayPolicy": "envs.policies.replay",
    "GoalFramePolicy": "envs.policies.goal_frame",
}
"""The public names (name -> the module that defines it), imported on first use."""

__all__ = sorted(EXPORTS)
__getattr__, __dir__ = lazy_exports(__name__, EXPORTS)
