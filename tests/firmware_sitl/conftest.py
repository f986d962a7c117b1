"""The real crazyflie-firmware in the loop: built from a checkout named by ``CRAZYFLIE_FIRMWARE``.

    CRAZYFLIE_FIRMWARE=/path/to/crazyflie-firmware .venv/bin/python -m pytest tests/firmware_sitl

Without it the firmware half of every scenario is skipped with that reason (CI has no checkout: the firmware is
GPL-3 and fetched by developers, never committed) and the Python half (``sim/crazyflie_firmware.py``) still runs.
"""

from __future__ import annotations

import os
import subprocess
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
SITL = ROOT / "firmware/crazyflie_sitl"
_built: dict[str, Path] = {}


def sitl_binary(platform: str) -> Path:
    """``cf_sitl`` for ``platform``, built once per session from the checkout; skips without one."""
    base = os.environ.get("CRAZYFLIE_FIRMWARE")
    if not base:
        pytest.skip("the real firmware runs only with CRAZYFLIE_FIRMWARE=<crazyflie-firmware 2026.08 checkout with "
                    "submodules> (not in CI: the firmware is fetched by developers, never committed)")
    if platform not in _built:
        build = subprocess.run(["make", "-s", "-j2", f"CRAZYFLIE_BASE={base}", f"PLATFORM={platform}"], cwd=SITL,
                               capture_output=True, text=True, timeout=600)
        assert build.returncode == 0, build.stderr[-3000:]
        _built[platform] = SITL / "build" / platform / "cf_sitl"
    return _built[platform]
