from fleetbus.cli import app

app()
