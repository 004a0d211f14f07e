"""What a robot client knows of its notifications' subjects, to skip the news it has already.

The client hands out notifications on whichever thread listens and learns from the steps a
warden takes on another (a claim), so the map is guarded by a lock.
"""

from __future__ import annotations

import threading
from collections import OrderedDict
from dataclasses import dataclass
from datetime import datetime

from fleetbus.schemas.notifications import Notification
from fleetbus.schemas.routing import Topic

#: How many subjects (hazards, maps) a client remembers the last news of, to skip repeats of it.
SEEN_NOTIFICATIONS = 10_000


@dataclass(frozen=True)
class Known:
    """What a client knows of a notification's subject: a hazard's state and claimant, as of when
    the service made them."""

    state: str | None
    claimed_by: str | None
    at: datetime

    def says(self, other: Known) -> bool:
        return (self.state, self.claimed_by) == (other.state, other.claimed_by)


def subject_key(topic: Topic, message_id: object) -> str:
    """What a notification is about: its topic and its event's message id (a hazard, by its event)."""
    return f"{topic.value}:{message_id}"


class KnownSubjects:
    """What this client last knew of each notification's subject (a hazard, by its event): its
    state, who claimed it and as of when, from a notification it handed out, a resync or a step
    it took; the newest :data:`SEEN_NOTIFICATIONS` subjects."""

    def __init__(self, size: int = SEEN_NOTIFICATIONS) -> None:
        self._size = size
        self._known: OrderedDict[str, Known] = OrderedDict()
        self._lock = threading.Lock()

    def seen_before(self, note: Notification, resync_as_of: datetime | None = None) -> bool:
        """Whether ``note`` says nothing new: this client last knew its subject as it says (an
        announcement's copies, its own step, a resync), or, for a note from the inbox, knew it as
        of a later time (a note that waited there while a resync told the hazard's state since).
        A hazard in another state is news, an earlier one too: ``announced`` again after an
        operator released the warden's claim. ``resync_as_of``: a resync's note, with the time of
        the hazard's latest step (it is news whenever its state is). A note that is news is what
        the client knows from now on."""
        key = subject_key(note.topic, note.event.message_id)
        told = Known(note.hazard_state, note.claimed_by, resync_as_of or note.notified_at)
        with self._lock:
            known = self._known.get(key)
            if known is not None and (known.says(told) or (resync_as_of is None and told.at <= known.at)):
                return True
            self._learn(key, told)
            return False

    def know(self, key: str, known: Known) -> None:
        """``known`` is what the client knows of ``key`` from now on; its time never goes back."""
        with self._lock:
            self._learn(key, known)

    def _learn(self, key: str, known: Known) -> None:
        before = self._known.get(key)
        if before is not None and before.at > known.at:
            known = Known(known.state, known.claimed_by, before.at)
        self._known[key] = known
        self._known.move_to_end(key)
        if len(self._known) > self._size:
            self._known.popitem(last=False)
