"""The one rule for removing an account while it is in use: a robot mounted, or an operator
holding a mount or checked in to a mission, is not removed (central's ``fleetbus users remove``
and a site removing its copy as central asks refuse alike)."""

from __future__ import annotations

from fleetbus.workers.store.channels import ChannelStore


async def in_use(channels: ChannelStore, name: str) -> str | None:
    """Why ``name`` cannot be removed now, in a sentence; None when nothing holds it."""
    mounts = await channels.mounts(operator=name) + await channels.mounts(robot=name)
    if not mounts and not await channels.check_ins(operator=name):
        return None
    held = ", ".join(f"{m.robot} mounted by {m.operator} for {m.mission_id}" for m in mounts)
    return f"{name} is in use ({held or 'checked in'}); unmount and check out first"
