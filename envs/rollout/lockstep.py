"""Episodes in lockstep: K episodes side by side in one process, one control period at a time for all of them, so
that what a period costs in Python outside the physics is paid once per period for the batch where it can be.

Each slot of the batch is an environment of its own (its own MjModel and MjData: an episode's perturbation writes
frictions, payload and joint damping into its model) with a policy of its own (a policy keeps its episode's state).
Every period:

    observations -> actions       one batched query for the slots whose policies can answer together
                                  (``act_many`` of the policy's class, e.g. envs.policies.flow_skill.ClosedLoopPolicy:
                                  the flow evaluated once over the batch), else ``act`` per slot
    actions -> prepared periods   stiffness, feed-forward lead, nullspace IK per slot (envs.sim.env.prepare_period)
    physics                       the compiled period of each slot (envs.sim.period_kernel), on ``threads`` threads
                                  (the kernel releases the GIL and touches its own episode's data only)
    scoring                       instability, observation, success per slot (envs.sim.env.finish_period)

An episode that ends leaves its slot to the next start. Each slot runs exactly the arithmetic of
`envs.rollout.episode.run_episode` (both are `EpisodeRun`), so an episode's record is the one it gets run alone,
to the last bit, whatever the batch size, the order or the threads (tests/envs/rollout/test_lockstep.py); only
``wall_s`` differs. An error in one episode ends that episode ("error: ..."), never the batch.
"""

from __future__ import annotations

from concurrent.futures import ThreadPoolExecutor
from contextlib import nullcontext
from typing import Any, Callable, Sequence

from envs.errors import EnvError
from envs.rollout.episode import EpisodeRecord, EpisodeRun, EpisodeTrace, StartPose


def act_for(runs: Sequence[EpisodeRun]) -> list[Any]:
    """The actions of the running ``runs``' policies for the coming period: one ``act_many(policies, observations)``
    call for each group of policies of one class that has it and of one ``batch_key()`` (e.g. the same skill), ``act``
    for the others. ``act_many`` must leave every policy as it was when it raises (the slots of a failed batched
    query then ``act`` one by one) and puts the exception of a policy whose own part failed in its place, so an error
    ends only the episodes it belongs to, as their own ``act`` would. None for a slot whose episode ended."""
    actions: list[Any] = [None] * len(runs)
    groups: dict[Any, list[int]] = {}
    for i, run in enumerate(runs):
        key = _batch_key(run.policy)
        if key is None:
            actions[i] = run.act()
        else:
            groups.setdefault(key, []).append(i)
    for members in groups.values():
        policy_class = type(runs[members[0]].policy)
        if len(members) == 1:
            actions[members[0]] = runs[members[0]].act()
            continue
        try:
            batch = policy_class.act_many([runs[i].policy for i in members], [runs[i].observation() for i in members])
        except Exception:  # act_many changed no state: each slot alone finds the episode the error belongs to
            for i in members:
                actions[i] = runs[i].act()
            continue
        for i, action in zip(members, batch):
            if isinstance(action, Exception):
                runs[i].fail(action, by_policy=True)
                action = None
            actions[i] = action
    return actions


def _batch_key(policy: Any) -> Any:
    """What a policy batches with: ``policy.batch_key()`` for a policy class with ``act_many``, else None."""
    if not callable(getattr(type(policy), "act_many", None)):
        return None
    return (type(policy), policy.batch_key())


def run_lockstep(envs: Sequence[Any], policies: Sequence[Any], starts: Sequence[StartPose],
                 feedforward_gain: float = 1.0, privileged: bool = False, threads: int = 1,
                 on_record: Callable[[EpisodeRecord], None] | None = None, user_policy: bool = False,
                 on_trace: Callable[[EpisodeRecord, EpisodeTrace], None] | None = None) -> list[EpisodeRecord]:
    """Run the episodes of ``starts`` in lockstep on the slots (envs[i], policies[i]) (module docstring).

    Args:
        envs: one PegInHoleEnv per slot, each with its own MjModel and MjData.
        policies: one policy per slot (any `Policy`; a class with ``act_many`` is queried once per period for all
            its slots).
        starts: the episodes, run in this order as slots become free.
        feedforward_gain, privileged: as for `run_episode`.
        threads: threads that run the slots' physics (1: in this thread).
        on_record: called with each record as its episode ends.
        user_policy: as for `run_episode` (a user's policy's errors are "policy_error").
        on_trace: called with each episode's record and trace (`EpisodeTrace`, recorded only when this is given) as
            it ends, before ``on_record``.

    Returns:
        The records in the order of ``starts``.

    Raises:
        EnvError: no slots, or unequal numbers of environments and policies.
    """
    if not envs or len(envs) != len(policies):
        raise EnvError(f"lockstep needs one policy per environment, got {len(envs)} environments and "
                       f"{len(policies)} policies")
    if len({id(e) for e in envs}) != len(envs) or len({id(e.data) for e in envs}) != len(envs):
        raise EnvError("lockstep slots must not share an environment or its MjData")
    if len({id(e.model) for e in envs}) != len(envs):
        raise EnvError("lockstep slots must not share an MjModel (an episode's perturbation writes into its model)")
    queue = list(enumerate(starts))[::-1]  # pop() from the end: episodes start in the given order
    records: list[EpisodeRecord] = [None] * len(starts)  # type: ignore[list-item]  # each set as it ends
    slots: list[tuple[int, EpisodeRun] | None] = [None] * len(envs)

    def finish(index: int, run: EpisodeRun) -> None:
        records[index], trace = run.finish()
        if on_trace is not None and trace is not None:
            on_trace(records[index], trace)
        if on_record is not None:
            on_record(records[index])

    def fill(slot: int) -> None:
        while queue:
            index, start = queue.pop()
            run = EpisodeRun(envs[slot], policies[slot], start, record_trace=on_trace is not None,
                             feedforward_gain=feedforward_gain, privileged=privileged, user_policy=user_policy)
            if run.begin():
                slots[slot] = (index, run)
                return
            finish(index, run)
        slots[slot] = None

    pool = ThreadPoolExecutor(threads) if threads > 1 else None
    with pool if pool is not None else nullcontext():
        for slot in range(len(envs)):
            fill(slot)
        while any(s is not None for s in slots):
            live = [(slot, s[1]) for slot, s in enumerate(slots) if s is not None]
            actions = act_for([run for _, run in live])
            periods = [run.command(action) for (_, run), action in zip(live, actions)]
            stepped = [(run, period) for (_, run), period in zip(live, periods) if period is not None]
            if pool is not None:
                list(pool.map(lambda rp: rp[0].physics(rp[1]), stepped))
            else:
                for run, period in stepped:
                    run.physics(period)
            for run, period in stepped:
                run.complete(period)
            for slot, run in live:
                if not run.running:
                    index = slots[slot][0]  # type: ignore[index]
                    finish(index, run)
                    fill(slot)
    return records
