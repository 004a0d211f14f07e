"""Which ingest shard each robot's messages go to: bindings on ``fleetbus.ingest.shards``.

A robot is bound to exactly one shard, with one key per type it sends there (``<robot>.status``,
``<robot>.map`` ...: every type but the express lane's hazards and localisations), when its account
is provisioned, on the shard that has the fewest robots (ties: the lowest number). The assignment
is the broker's own bindings, so the management UI shows it and nothing else can disagree with it.

Why by name, and why bindings rather than a hash:

- The routing key's first word is the only robot identity on a message that a robot cannot
  choose: topic permissions make the broker refuse any key on ``<robot>.events`` that does not
  start with the robot's name. (A beacon's key on the robot's headers exchange is not checked by
  the broker; one sent under another robot's name lands in that robot's shard and is dead-lettered
  there as ``identity-mismatch``, so it cannot reorder or change anything but its own copy.)
- Least-loaded placement spreads a small team evenly; hashing names does not: 4 robots hashed
  onto 4 shards use all four only 4!/4^4 = 9 % of the time.
- A message that matches no robot binding (an account made before shards, a malformed key) goes
  to shard 0 by the exchange's alternate exchange: never to no shard at all.

Robots are never moved behind anyone's back: moving a robot while its messages are queued in its
old shard could store them out of order. ``fleetbus shards rebalance`` moves robots on request.
"""

from __future__ import annotations

from collections.abc import Collection, Mapping
from dataclasses import dataclass, field

from fleetbus.broker.management import ManagementAPI
from fleetbus.schemas.routing import (
    SHARD_EXCHANGE,
    SHARD_TYPES,
    ingest_shard_queue,
    shard_binding_keys,
    shard_of_queue,
)


@dataclass(frozen=True)
class ShardMap:
    """The robots bound to each shard, as the broker routes them now."""

    shards: int
    """How many shards are configured (``FLEETBUS_INGEST_SHARDS``)."""
    bindings: Mapping[str, tuple[int, ...]] = field(default_factory=dict)
    """Each bound robot's shards: one, unless a move was interrupted."""
    unassigned: tuple[str, ...] = ()
    """The registry's robots with no shard binding: their messages go to shard 0 by the alternate exchange."""

    def shard_of(self, robot: str) -> int | None:
        """The shard ``robot``'s messages go to (shard 0 for an unassigned robot); None: several."""
        bound = self.bindings.get(robot, ())
        if not bound:
            return 0
        return bound[0] if len(bound) == 1 else None

    def robots_on(self, shard: int) -> list[str]:
        return sorted(robot for robot, bound in self.bindings.items() if shard in bound)

    def load(self) -> list[int]:
        """Robots bound to each configured shard."""
        return [len(self.robots_on(shard)) for shard in range(self.shards)]

    def least_loaded(self) -> int:
        load = self.load()
        return load.index(min(load))

    def stray(self) -> list[str]:
        """Robots bound to a shard beyond the configured ones, or to more than one."""
        return sorted(
            robot
            for robot, bound in self.bindings.items()
            if len(bound) > 1 or any(shard >= self.shards for shard in bound)
        )


SHARD_KEY_ENDS = frozenset(t.value for t in SHARD_TYPES)


def _robot_of(binding_key: str) -> str | None:
    """The robot a shard binding key is for: ``<robot>.<shard type>``."""
    robot, _, rest = binding_key.partition(".")
    return robot if robot and rest in SHARD_KEY_ENDS else None


def read_shard_map(api: ManagementAPI, vhost: str, shards: int, robots: Collection[str] = ()) -> ShardMap:
    """The broker's shard bindings; ``robots`` (the account registry's) not bound to any shard are
    the unassigned ones."""
    bound: dict[str, set[int]] = {}
    for binding in api.exchange_bindings(vhost, SHARD_EXCHANGE):
        shard = shard_of_queue(binding.get("destination", ""))
        robot = _robot_of(binding.get("routing_key", ""))
        if binding.get("destination_type") == "queue" and shard is not None and robot is not None:
            bound.setdefault(robot, set()).add(shard)
    return ShardMap(
        shards,
        {robot: tuple(sorted(found)) for robot, found in sorted(bound.items())},
        tuple(sorted(set(robots) - bound.keys())),
    )


def _bind(api: ManagementAPI, vhost: str, robot: str, shard: int) -> None:
    for key in shard_binding_keys(robot):
        api.bind(vhost, SHARD_EXCHANGE, ingest_shard_queue(shard), key)


def _unbind(api: ManagementAPI, vhost: str, robot: str, shard: int) -> None:
    api.unbind_keys(vhost, SHARD_EXCHANGE, ingest_shard_queue(shard), list(shard_binding_keys(robot)))


def assign_shard(api: ManagementAPI, vhost: str, robot: str, shards: int) -> int:
    """The robot's shard: the one it is bound to, else the least loaded, bound now."""
    current = read_shard_map(api, vhost, shards)
    bound = current.bindings.get(robot)
    if bound:
        return bound[0]
    shard = current.least_loaded()
    _bind(api, vhost, robot, shard)
    return shard


def unassign_shard(api: ManagementAPI, vhost: str, robot: str) -> None:
    """Remove every shard binding of ``robot`` (its account is being deleted)."""
    for shard in read_shard_map(api, vhost, 1).bindings.get(robot, ()):
        _unbind(api, vhost, robot, shard)


@dataclass(frozen=True, order=True)
class Move:
    robot: str
    bound: tuple[int, ...]
    """The shards it is bound to now; none: it goes to shard 0 by the alternate exchange."""
    target: int

    def __str__(self) -> str:
        now = ", ".join(map(str, self.bound)) if self.bound else "0 (unassigned)"
        return f"{self.robot}: shard {now} -> {self.target}"


def rebalance_plan(current: ShardMap) -> list[Move]:
    """Moves that leave every robot on one configured shard, the loads differing by at most one.

    Unassigned and stray robots are placed first (on the least loaded shards), then robots move
    from the fullest shard to the emptiest until the loads are even; robots in place stay put.
    """
    placed = {
        robot: bound[0]
        for robot, bound in current.bindings.items()
        if len(bound) == 1 and bound[0] < current.shards
    }

    def load() -> list[int]:
        counts = [0] * current.shards
        for shard in placed.values():
            counts[shard] += 1
        return counts

    for robot in sorted({*current.unassigned, *current.stray()}):
        counts = load()
        placed[robot] = counts.index(min(counts))
    while True:
        counts = load()
        fullest, emptiest = counts.index(max(counts)), counts.index(min(counts))
        if counts[fullest] - counts[emptiest] <= 1:
            break
        placed[max(r for r, shard in placed.items() if shard == fullest)] = emptiest
    return [
        Move(robot, current.bindings.get(robot, ()), target)
        for robot, target in sorted(placed.items())
        if current.bindings.get(robot, ()) != (target,)
    ]


def apply_move(api: ManagementAPI, vhost: str, move: Move) -> None:
    """Bind the robot to its new shard first, then unbind the others: never routed to no shard."""
    _bind(api, vhost, move.robot, move.target)
    for shard in move.bound:
        if shard != move.target:
            _unbind(api, vhost, move.robot, shard)
