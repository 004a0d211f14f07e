"""``python -m fleetbus.workers.recorder``: the recording process (see :mod:`.launch`)."""

from fleetbus.workers.recorder.launch import main

main()
