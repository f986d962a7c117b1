"""``groundstation params``: check (and set) the firmware parameters of a flight's modules."""

from __future__ import annotations

import json
from dataclasses import asdict

import click
from rich.console import Console
from rich.table import Table

from groundstation.cli.common import stderr_console

EXIT_MISMATCH = 1


@click.command("params")
@click.argument("flight", type=click.Path(dir_okay=False))
@click.option("--apply", "apply", is_flag=True, help="Write every parameter that differs, then read it back.")
@click.option("--file", "param_file", type=click.Path(dir_okay=False), default=None,
              help="Parameter file to use instead of the config's backend.firmware_params.")
@click.option("--json", "as_json", is_flag=True, help="Print every check as JSON.")
def params_command(flight: str, apply: bool, param_file: str | None, as_json: bool) -> int:
    """Read every module's firmware parameters over its link and compare them with the required values.

    The modules and their links come from FLIGHT (backend crazyflie or mavlink); the required values from its
    backend.firmware_params file (firmware_params/crazyflie.toml, firmware_params/px4/module_params.toml) or
    --file. Exit code 0 when every module is as required, 1 when one is not (each listed), 2 on bad input.
    """
    from pathlib import Path

    from groundstation.backends.link_lock import LinkLocks
    from groundstation.firmware.modules import check_modules, required_params
    from groundstation.firmware.params import issues
    from groundstation.runtime.flight_config import load_flight_config, log_directory

    cfg, base = load_flight_config(flight)
    wanted = required_params(cfg.backend, base, Path(param_file).resolve() if param_file else None, flight)
    n = len(cfg.backend.modules)
    # The modules' link locks, as a flight takes them: parameters are never read or written while a flight (or
    # another `params`) on this host holds the modules (written into airborne modules before: hostile campaign 33).
    locks = LinkLocks(cfg.backend.modules)
    locks.acquire()
    try:
        with stderr_console().status("connecting") as status:
            checks = check_modules(cfg.backend, wanted, apply=apply, cache_dir=log_directory(cfg, base, flight),
                                   on_module=lambda done: status.update(f"modules checked: {done}/{n}"))
    finally:
        locks.release()
    if as_json:
        click.echo(json.dumps([asdict(c) | {"ok": c.ok} for c in checks]))
    else:
        table = Table(title=f"firmware parameters of {n} modules ({cfg.backend.kind})")
        for col in ("module", "link", "parameter", "required", "module has", ""):
            table.add_column(col)
        for c in checks:
            has = f"{c.actual:g}" if c.actual is not None else c.note
            done = ", ".join(w for w, flag in (("written", c.written), ("stored", c.stored)) if flag)
            table.add_row(str(c.module), c.link, c.name, f"{c.expected:g}", has,
                          ("ok" if c.ok else "WRONG") + (f" ({done})" if done else ""))
        Console(width=140).print(table)
    bad = issues(checks)
    for line in bad:
        click.echo(f"groundstation: {line}", err=True)
    if bad:
        raise SystemExit(EXIT_MISMATCH)
    return 0
