"""An FMU that is not ours: tests/data/vendor_car, a vendor-style car in other names and units
(km/h, Pa, degrees, a pedal fraction), built from its C sources like the bundled passat, and its
plant mapping file. The tests run bywire on it only through that mapping."""

from __future__ import annotations

from pathlib import Path

from bywire.vehicle_models import ensure_fmu

VENDOR_DIR = Path(__file__).resolve().parent / "data" / "vendor_car"
VENDOR_MAPPING = VENDOR_DIR / "mapping.toml"


def vendor_fmu() -> Path:
    """The vendor car's .fmu (built once into the FMU cache, keyed by its sources' hash)."""
    return ensure_fmu(VENDOR_DIR)


def mapping_without_initial(directory: Path) -> Path:
    """A copy of the vendor car's mapping file without its [initial] table."""
    text = VENDOR_MAPPING.read_text()
    start = text.index("[initial]")
    end = text.index("\n[", start)
    path = directory / "vendor_car_no_initial.toml"
    path.write_text(text[:start] + text[end + 1 :])
    return path
