"""The commands the development tooling adds to ``fleetbus``: ``broker`` and ``demo``."""
