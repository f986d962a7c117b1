"""``groundstation mocap-key``: the key the mocap bridge and the ground station share (authenticated mocap)."""

from __future__ import annotations

import click

from groundstation.mocap.auth import write_key_file


@click.command("mocap-key")
@click.argument("path", type=click.Path(dir_okay=False))
def mocap_key_command(path: str) -> int:
    """Write a new random mocap key to PATH (readable by you only; an existing file is never replaced).

    Give the same file to the bridge (mocap-bridge --key-file PATH) and to the flight (mocap.key_file): every pose
    then carries a MAC, and the ground station uses no sample without a valid one.
    """
    written = write_key_file(path)
    click.echo(f"wrote a new mocap key to {written} (mode 600): copy it to the mocap host over a trusted channel")
    return 0
