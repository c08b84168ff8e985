"""The scheduling policy: a pure function of the pending tasks and the workers' loads and caches.

No sockets, no clocks, no randomness: :func:`assign` maps (pending tasks in queue order,
worker views) to a list of (task id, worker id) assignments, so the policy is tested alone
(ipyparallel's schedulers are built the same way) and the broker only applies what it returns.

Policy (docs/architecture.md; the network side in docs/scale-out.md, "The network contract"):

1. Tasks are taken strictly in queue order (the broker puts re-queued tasks at the front, see
   :func:`requeue_front`); when no worker has a free credit slot, assignment stops — later tasks
   never overtake earlier ones.
2. Credit-based flow control: a worker with ``credit`` slots (granted in its HELLO, default
   :data:`common.protocol.CREDIT_PER_THREAD` per render thread) never gets more than ``credit``
   tasks in flight.
3. Affinity: among workers with a free slot, those already holding the task's VPL/photon set
   (key ``(scene_version, seed, k)``) come first — the set is not recomputed. A worker that is
   given a task of a set it lacks will compute that set, so within one call it counts as a
   holder for the later tasks of that set.
4. Then least loaded: the smallest ``inflight / credit`` (load fraction), ties broken by more
   free slots, then by worker id (deterministic).
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Hashable, Iterable, Sequence


@dataclass(frozen=True)
class PendingTask:
    task: Hashable  # the broker's task id
    set_key: Hashable  # the VPL/photon set the task needs, e.g. (scene_version, seed, k)


@dataclass(frozen=True)
class WorkerView:
    id: Hashable
    credit: int  # task slots granted by the worker
    inflight: int = 0  # tasks assigned and not yet answered
    cached: frozenset = field(default_factory=frozenset)  # set keys the worker holds

    @property
    def free(self) -> int:
        return max(0, self.credit - self.inflight)

    @property
    def load(self) -> float:
        return self.inflight / self.credit if self.credit > 0 else float("inf")


def assign(pending: Sequence[PendingTask], workers: Iterable[WorkerView],
           limit: int | None = None) -> list[tuple[Hashable, Hashable]]:
    """Assignments (task id, worker id) for a prefix of ``pending``; see the module docstring.

    ``limit`` caps the number of assignments (None: as many as credit allows).
    """
    state = {w.id: [w.credit, w.inflight, set(w.cached)] for w in workers}
    order = sorted(state, key=_id_order)
    out: list[tuple[Hashable, Hashable]] = []
    for t in pending:
        if limit is not None and len(out) >= limit:
            break
        free = [wid for wid in order if state[wid][1] < state[wid][0]]
        if not free:
            break
        holders = [wid for wid in free if t.set_key in state[wid][2]]
        pool = holders or free
        best = min(pool, key=lambda wid: (state[wid][1] / state[wid][0],
                                          -(state[wid][0] - state[wid][1]), _id_order(wid)))
        out.append((t.task, best))
        state[best][1] += 1
        state[best][2].add(t.set_key)
    return out


def _id_order(wid):
    return (type(wid).__name__, wid)


def requeue_front(pending: Sequence, lost: Sequence) -> list:
    """The queue with the ``lost`` tasks (of an expired or disconnected worker) at the front,
    in their original order, and no task twice."""
    lost_list = list(dict.fromkeys(lost))
    seen = set(lost_list)
    return lost_list + [t for t in pending if t not in seen]


def credit_for(threads: int, per_thread: int | None = None) -> int:
    """Default credit a worker grants: ~3 tasks in flight per render thread."""
    from common.protocol import CREDIT_PER_THREAD

    return max(1, int(threads) * (CREDIT_PER_THREAD if per_thread is None else per_thread))
