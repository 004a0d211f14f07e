"""``python -m fleetbus.publishers.ros``: the ROS bridge's process (see :mod:`.launch`)."""

from fleetbus.publishers.ros.launch import main

main()
