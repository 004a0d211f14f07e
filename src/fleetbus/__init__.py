"""fleetbus: the event backbone and database server for a team of robots, on RabbitMQ.

The runtime packages live under this namespace (installed from the repository's top-level
folders): `fleetbus.schemas`, `fleetbus.publishers` (the robot client), `fleetbus.broker`,
`fleetbus.workers`, `fleetbus.api`; `fleetbus.settings` is every setting; `fleetbus.cli` is the
command line and `fleetbus_dev` the development tooling."""
