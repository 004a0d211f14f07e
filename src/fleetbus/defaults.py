"""Defaults of settings that light processes use without the settings model (pydantic): the
recording process gets its resolved settings from ``fleetbus recorder run`` and imports these only.
:mod:`fleetbus.settings` is where each is a setting, with its variable and description."""

DEFAULT_MAX_MESSAGE_BYTES = 1024 * 1024
DEFAULT_RECORDER_KEEP = "*=1GB"
#: How long the recorders' samples of the database's size are kept (one a minute per recorder).
DEFAULT_RECORDER_SAMPLES_KEEP = "90d"
DEFAULT_FIELD_INDEXES_MAX = 32
#: A notification that reaches its robots this long after the event was sent is ``late`` (the
#: default of ``FLEETBUS_LATE_AFTER_S``; a robot client rebuilding its list uses it too).
LATE_AFTER_S = 5.0
