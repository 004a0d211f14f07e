"""Development tooling, apart from the runtime packages: the private RabbitMQ node, the fallback
chain that finds or starts a broker when none is configured, in-process harnesses, the demo."""
