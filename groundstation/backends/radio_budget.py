"""What a Crazyradio can carry: modules per dongle times the control rate against its transaction rate.

cflib's radio driver serializes every link on one dongle through one thread, and each packet is a transaction
(the ack brings the module's reply back): Bitcraze's own figure is about 450-500 round trips a second per
Crazyradio. The Crazyflie backend sends one command per module per control period, so ``k`` modules on a dongle
at ``rate_hz`` need ``k * rate_hz`` transactions a second: one module per dongle at 250-500 Hz. Links on several
dongles (``radio://0/...``, ``radio://1/...``, or a dongle's serial) run in parallel.
"""

from __future__ import annotations

from collections import Counter
from urllib.parse import urlparse


def dongle_of(uri: str) -> str | None:
    """The dongle a ``radio://`` URI uses (index or serial), None for other links (UDP, USB, ...)."""
    if not uri.startswith("radio://"):
        return None
    return urlparse(uri).netloc or "0"


def radio_budget_issues(uris: list[str] | tuple[str, ...], rate_hz: float, capacity_hz: float) -> list[str]:
    """One line per dongle asked for more transactions a second than ``capacity_hz``."""
    per_dongle = Counter(d for d in map(dongle_of, uris) if d is not None)
    return [f"radio://{d}: {k} modules x {rate_hz:g} Hz = {k * rate_hz:g} packets/s, more than one Crazyradio "
            f"carries ({capacity_hz:g}/s): put the modules on more dongles (radio://1/..., one per module at "
            f"{rate_hz:g} Hz) or lower rate_hz"
            for d, k in sorted(per_dongle.items()) if k * rate_hz > capacity_hz]
