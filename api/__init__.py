"""The HTTP API (FastAPI): `fleetbus api` serves it, with the same accounts and roles as the broker."""
