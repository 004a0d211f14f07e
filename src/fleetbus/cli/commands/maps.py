"""``fleetbus map export | list``: the stored maps, written back as files map tools open."""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING, Annotated

import typer
import yaml
from rich.table import Table

from fleetbus.cli.context import console
from fleetbus.cli.services import with_services

if TYPE_CHECKING:
    from fleetbus.api.services.standalone import Services
    from fleetbus.workers.store.maps import MapVersion

app = typer.Typer(help="The team's map, every version.", no_args_is_help=True)


def map_yaml(metadata: dict, image_name: str) -> str:
    """The ``map_server`` YAML for an image (the fields Table 2 of the reference checks)."""
    fields = {
        key: metadata[key] for key in ("resolution", "origin", "negate", "occupied_thresh", "free_thresh")
    }
    return yaml.safe_dump({"image": image_name, **fields}, sort_keys=False)


@app.command("export")
def export(
    out: Annotated[Path, typer.Option(help="folder for map.pgm and map.yaml")] = Path("."),
    version: Annotated[int | None, typer.Option(help="a version; default the latest")] = None,
) -> None:
    """Write a stored map (the latest by default) to map.pgm and map.yaml."""

    async def read(services: Services) -> tuple[MapVersion, bytes]:
        found = await services.maps.version(version)
        return found, await services.maps.image(found)

    info, pgm = with_services(read)
    out.mkdir(parents=True, exist_ok=True)
    (out / "map.pgm").write_bytes(pgm)
    (out / "map.yaml").write_text(map_yaml(info.metadata, "map.pgm"))
    console.print(
        f"map version {info.version} from {info.robot_id} ({len(pgm):,} bytes) -> {out}/map.pgm, map.yaml"
    )


@app.command("list")
def list_maps() -> None:
    """Every stored version, newest first (each robot's newest FLEETBUS_MAP_VERSIONS_KEEP are kept)."""

    async def read(services: Services) -> list[MapVersion]:
        return await services.maps.versions()

    table = Table("version", "from", "created at", "bytes", "resolution", "origin")
    for info in with_services(read):
        table.add_row(
            str(info.version),
            f"{info.robot_id} #{info.seq}",
            info.created_at.isoformat(timespec="seconds"),
            f"{info.size:,}",
            str(info.metadata["resolution"]),
            str(info.metadata["origin"]),
        )
    console.print(table)
