"""Where the shared real data lives (`../shared/data` beside the repository), read in place.

The data is never copied into the repository (KITTI is non-commercial, the rest carries its own
licences): tests that need it skip with a message where it is absent. `BYWIRE_SHARED_DATA` points
elsewhere (a CI checkout that is not beside `shared/`).
"""

from __future__ import annotations

import os
from pathlib import Path


def shared_data_dir() -> Path:
    override = os.environ.get("BYWIRE_SHARED_DATA")
    if override:
        return Path(override)
    beside = Path(__file__).resolve().parents[2] / "shared" / "data"
    return beside if beside.exists() else Path("/work/shared/data")
