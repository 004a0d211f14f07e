"""``fleetbus map export | list``: the stored maps, written back as files map tools open."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer
import yaml
from rich.table import Table

from fleetbus.cli.context import console, fail, settings
from fleetbus.workers.maps import map_image, missing_version
from fleetbus.workers.store import run_with_repositories
from fleetbus.workers.store.maps import MapStore, MapVersion

app = typer.Typer(help="The team's map, every version.", no_args_is_help=True)


async def _read(maps: MapStore, version: int | None) -> tuple[MapVersion, bytes] | str:
    """The version and its image, or why there is none."""
    found = await maps.map_version(version)
    if found is None:
        return await missing_version(maps, version)
    return found, await map_image(maps, found)


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
    found = run_with_repositories(settings(), lambda repos: _read(repos.maps, version))
    if isinstance(found, str):
        fail(found)
    info, pgm = found
    out.mkdir(parents=True, exist_ok=True)
    (out / "map.pgm").write_bytes(pgm)
    (out / "map.yaml").write_text(map_yaml(info.metadata, "map.pgm"))
    console.print(
        f"map version {info.version} from {info.robot_id} ({len(pgm):,} bytes) -> {out}/map.pgm, map.yaml"
    )


@app.command("list")
def list_maps() -> None:
    """Every stored version, newest first (each robot's newest FLEETBUS_MAP_VERSIONS_KEEP are kept)."""

    table = Table("version", "from", "created at", "bytes", "resolution", "origin")
    for info in run_with_repositories(settings(), lambda repos: repos.maps.map_versions()):
        table.add_row(
            str(info.version),
            f"{info.robot_id} #{info.seq}",
            info.created_at.isoformat(timespec="seconds"),
            f"{info.size:,}",
            str(info.metadata["resolution"]),
            str(info.metadata["origin"]),
        )
    console.print(table)
