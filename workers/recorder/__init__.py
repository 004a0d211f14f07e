"""The recorder: every message on the bus kept for fault analysis and evaluation (`fleetbus recorder run`)."""
