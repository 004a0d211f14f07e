"""The live ROS 1 bridge: ROS topics recorded in fleetbus, mapped topics as fleetbus events, and
this robot's notifications published back as ROS topics (``fleetbus ros bridge``)."""
