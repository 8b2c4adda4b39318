"""The published platoon CSV layouts we read, and how a file's header tells which one it is.

Every spelling here comes from a published dataset or a public cut of one; the `source` of each layout
says which. Canonical fields: time in s, speed in m/s, acceleration in m/s² (SI inside; every published
file below already stores these units, so the factors `time_to_s`, `speed_to_mps`, `accel_to_mps2` are 1
and stay as the one place a unit conversion would go).

OpenACC (Makridis et al., "OpenACC. An open database of car-following experiments", Transp. Res. C 125,
2021; JRC data catalogue JRCDBT0001, campaign notes `<campaign>_notes.txt`):

- `openacc_jrc`: the JRC release of every campaign (Casale, Cherasco, Vicolungo, AstaZero, ZalaZone,
  JRC low speed). Metadata lines `Date,DD,MM,YYYY`, `Vehicle_order,veh1,veh2,...`, `Number_of_vehicles,N`,
  `ACC,0|1|2|`, `Distance_setting,...` (five in every campaign; read as the lines before the one that
  starts with `Time`), then the table header `Time, Speed1, ...`. `Time`: common time frame (s);
  `Speed<i>`: raw Doppler GNSS speed of vehicle i (m/s), vehicle i being the i-th of `Vehicle_order`,
  leader first; an index may be missing (a car without data). The other columns per campaign note:
  `Lat<i>`, `Lon<i>` (rad in the notes; ZalaZone stores degrees), `Alt<i>`, `E<i>`, `N<i>`, `U<i>` (m,
  local ENU), `VE<i>`, `VN<i>`, `VU<i>` (Vicolungo, m/s), `Driver<i>` (`ACC`/`Human`), `IVS<i>`
  (bumper-to-bumper spacing behind vehicle i, m); their order differs by campaign (AstaZero: Lat, Lon,
  Alt, E, N, U, then every Driver, then every IVS; ZalaZone: E, N, Lon, Lat, Alt, no Driver, data rows
  ending in a comma; Casale's leader without Alt/U). We read `Time` and `Speed<i>` only.
- `openacc_cut`: cuts of the release without the metadata lines, header `Time,Speed1,...` or
  `Time,Speed_1,...`: the AstaZero cuts `data/OpenACC_trajectory_1.csv` (`Speed_1`) and
  `OpenACC_trajectory_2.csv` (`Speed1`) of CATS-Lab/AV-Conrol-PERL_Platooning, taken from
  `ASta_platoon1.csv`.

CARMA (FHWA Saxton Laboratory, Cooperative Automated Research Mobility Applications, data.transportation.gov;
US federal work):

- `carma2_usdot`: "Cooperative Automated Research Mobility Applications (CARMA) 2" (dataset dusd-cr84,
  closed-track CACC platoon tests of July 2018, Tiernan et al. 2019, doi:10.21949/1503647), as published:
  `LocationDateTime, RunNo, Elapsed_Time` (s since the run's start), then per vehicle `<field>_<COLOUR>`
  for the five Cadillac SRX BLACK, GREEN, GREY, SILVER, WHITE: `vehspdavgdrvn_srx_<C>` (average speed of
  the driven wheels, m/s) and `p29_actual_vehicle_acceleration_<C>` (m/s²). Its data dictionary is
  `Data_Elements.xlsx`, sheet 2. One file holds many runs; the platoon order is not in the file:
  runs 5, 6, 9, 10 and 13 drove BLACK, GREEN, GREY, SILVER, WHITE (the five-car platoon runs, as read by
  public analyses of the set).
- `carma2_licit`: the same runs restructured by licit-lab/vrt_analysis (`data/raw/carma/data<run>.csv`,
  Lanaud et al., Findings 2021): `Date, Heure, Time`, then per vehicle leader, follower1..follower4
  `<v>_avg_speed_driven_wheels` (m/s), `<v>_acceleration` (m/s²), `<v>_GPS_speed`, `<v>_radar1`, ...
- `carma1_usdot`: "Test Data of Proof-of-Concept Vehicle Platooning Based on Cooperative Adaptive Cruise
  Control (CACC)" (CARMA 1, dataset wpek-zziu, 2016, 20 Hz): `Run, bin_utc_time_formatted,
  elapsed_time (s)`, then per vehicle `<field>-<suffix>`, suffixes bl, grn, wt, ag (silver), gry:
  `speed_CACC-<s>` (m/s, the unit in which public analyses of the set integrate it; the dataset's own
  dictionary was not at hand), `distToPVeh_CACC-<s>`, ... One file holds many runs; the order changes
  from run to run and is not in the file; the field notes give it for runs 29, 30 and 68-72.
- `carma1_licit`: CARMA 1 as restructured by licit-lab/vrt_analysis (`collector/poc.py`):
  `elapsed_time (s)` and `speed_CACC_leader`, `speed_CACC_follower1..4`.
"""

from __future__ import annotations

import re
from collections.abc import Mapping
from dataclasses import dataclass, field

# The OpenACC metadata keys, one line each before the table header (JRC campaign notes, "Csv Metadata").
OPENACC_METADATA_KEYS = ("Date", "Vehicle_order", "Number_of_vehicles", "ACC", "Distance_setting")

_CARMA_LICIT_VEHICLES = ("leader", "follower1", "follower2", "follower3", "follower4")


@dataclass(frozen=True)
class Layout:
    """One published header spelling, mapped onto our canonical fields.

    `speed_pattern` is a regular expression over a whole header cell whose one group is the vehicle's key;
    `accel_template` names the same vehicle's acceleration column (`{}` is the key). Vehicles are ordered
    leader first by `vehicle_order` (fixed keys), by `order_by_run` (keys per run) or, when both are
    empty, by the integer value of the key (OpenACC's vehicle index)."""

    name: str
    title: str
    signature: str  # how the header reads, for the error that names the expected layouts
    source: str
    time_column: str
    speed_pattern: str
    accel_template: str | None = None
    metadata_lines: bool = False
    run_column: str | None = None
    vehicle_order: tuple[str, ...] = ()
    order_by_run: Mapping[str, tuple[str, ...]] = field(default_factory=dict)
    time_to_s: float = 1.0
    speed_to_mps: float = 1.0
    accel_to_mps2: float = 1.0

    def speed_columns(self, header: list[str]) -> dict[str, str]:
        """Vehicle key -> speed column, in header order."""
        out: dict[str, str] = {}
        for cell in header:
            m = re.fullmatch(self.speed_pattern, cell)
            if m:
                out.setdefault(m.group(1), cell)
        return out

    def matches(self, header: list[str]) -> bool:
        return self.time_column in header and bool(self.speed_columns(header))


_CARMA2_ORDER = ("BLACK", "GREEN", "GREY", "SILVER", "WHITE")

LAYOUTS: tuple[Layout, ...] = (
    Layout(
        name="openacc_jrc",
        title="OpenACC, JRC release",
        signature="metadata lines 'Date,...' to 'Distance_setting,...', then 'Time,Speed1,...'",
        source="JRC OpenACC campaigns Casale, Cherasco, Vicolungo, AstaZero, ZalaZone, JRC low speed",
        time_column="Time",
        speed_pattern=r"Speed(\d+)",
        metadata_lines=True,
    ),
    Layout(
        name="openacc_cut",
        title="OpenACC cut without metadata",
        signature="'Time,Speed1,...' or 'Time,Speed_1,...'",
        source="CATS-Lab/AV-Conrol-PERL_Platooning data/OpenACC_trajectory_1.csv, _2.csv (AstaZero)",
        time_column="Time",
        speed_pattern=r"Speed_?(\d+)",
    ),
    Layout(
        name="carma2_licit",
        title="CARMA 2 (licit-lab cut)",
        signature="'Date,Heure,Time,...,leader_avg_speed_driven_wheels,...'",
        source="licit-lab/vrt_analysis data/raw/carma/data<run>.csv (FHWA CARMA 2, July 2018)",
        time_column="Time",
        speed_pattern=r"(leader|follower[1-4])_avg_speed_driven_wheels",
        accel_template="{}_acceleration",
        vehicle_order=_CARMA_LICIT_VEHICLES,
    ),
    Layout(
        name="carma2_usdot",
        title="CARMA 2 (USDOT)",
        signature="'LocationDateTime,RunNo,Elapsed_Time,...,vehspdavgdrvn_srx_BLACK,...'",
        source="data.transportation.gov dusd-cr84, data dictionary Data_Elements.xlsx sheet 2",
        time_column="Elapsed_Time",
        speed_pattern=r"vehspdavgdrvn_srx_(BLACK|GREEN|GREY|SILVER|WHITE)",
        accel_template="p29_actual_vehicle_acceleration_{}",
        run_column="RunNo",
        order_by_run={run: _CARMA2_ORDER for run in ("5", "6", "9", "10", "13")},
    ),
    Layout(
        name="carma1_usdot",
        title="CARMA 1 proof of concept (USDOT)",
        signature="'Run,bin_utc_time_formatted,elapsed_time (s),...,speed_CACC-bl,...'",
        source="data.transportation.gov wpek-zziu (FHWA CACC proof of concept, 2016)",
        time_column="elapsed_time (s)",
        speed_pattern=r"speed_CACC-(bl|grn|wt|ag|gry)",
        run_column="Run",
        order_by_run={
            "29": ("bl", "grn", "wt", "ag", "gry"),
            "30": ("bl", "wt", "gry", "grn", "ag"),
            "68": ("bl", "grn", "wt", "ag", "gry"),
            "69": ("bl", "wt", "ag", "gry", "grn"),
            "70": ("bl", "ag", "gry", "grn", "wt"),
            "71": ("bl", "gry", "grn", "wt", "ag"),
            "72": ("bl", "grn", "wt", "ag", "gry"),
        },
    ),
    Layout(
        name="carma1_licit",
        title="CARMA 1 proof of concept (licit-lab cut)",
        signature="'elapsed_time (s),...,speed_CACC_leader,speed_CACC_follower1,...'",
        source="licit-lab/vrt_analysis collector/poc.py (FHWA CACC proof of concept, 2016)",
        time_column="elapsed_time (s)",
        speed_pattern=r"speed_CACC_(leader|follower[1-4])",
        vehicle_order=_CARMA_LICIT_VEHICLES,
    ),
)

LAYOUTS_BY_NAME = {layout.name: layout for layout in LAYOUTS}


def expected_layouts() -> str:
    """The known layouts, as the unknown-layout error names them."""
    return "; ".join(f"{layout.title} {layout.signature}" for layout in LAYOUTS)


def header_layout(header: list[str]) -> Layout | None:
    """The first layout without metadata lines whose time and speed columns the header holds."""
    for layout in LAYOUTS:
        if not layout.metadata_lines and layout.matches(header):
            return layout
    return None


def normalise_run(cell: str) -> str:
    """A run number as the order tables spell it: '5', '5.0' and ' 5 ' are run 5."""
    text = cell.strip()
    try:
        value = float(text)
    except ValueError:
        return text
    return str(int(value)) if value.is_integer() else text


__all__ = [
    "LAYOUTS",
    "LAYOUTS_BY_NAME",
    "OPENACC_METADATA_KEYS",
    "Layout",
    "expected_layouts",
    "header_layout",
    "normalise_run",
]
