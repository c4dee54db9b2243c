"""The one exception type of the simulation package."""


class EnvError(RuntimeError):
    """A scene, episode, demonstration or rendering request that cannot be carried out.

    The message names the offending input and what is wrong with it, in one line.
    """


class ActionError(EnvError):
    """An action the controller cannot command (a malformed pose or stiffness, a feed-forward it refuses): the
    policy's doing, not the simulator's (envs.rollout.episode tells a user's policy's errors apart by it)."""


class PolicyFailure(Exception):
    """A user's policy failed in an episode of a run that stops at its first error (`pih evaluate --policy` without
    --keep-going, and the other commands that run a --policy): it raised in ``reset`` or ``act``, or returned an
    action that is not an `Action` or one the controller cannot command.

    Attributes:
        index: the episode.
        reason: the episode's reason, "policy_error: Type: message at file:line" (the traceback's last line).
        traceback: the policy's traceback as Python prints it (from the policy's own frames on).
    """

    def __init__(self, index: int, reason: str, traceback: str):
        super().__init__(f"the policy failed in episode {index}: {reason.removeprefix('policy_error: ')}")
        self.index, self.reason, self.traceback = index, reason, traceback
