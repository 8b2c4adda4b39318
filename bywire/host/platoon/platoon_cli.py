"""`bywire platoon string-stability CSV [--json FILE]` (seed 003, Sec. V-D).

Runs the string-stability estimator of bywire.host.platoon.string_stability on a recorded platoon
(OpenACC ZalaZone / AstaZero, CARMA) and writes the contract JSON
`{"string_stability": worst ratio, "pairs": [{"leader", "follower", "ratio"}], "band_hz"}`; each pair also
carries `peak_hz` and `coherence` (H1 is only trustworthy where the coherence is high), and the top level
`signal`, `source` and the loader's `notes` (gaps cut, rows reordered).
"""

from __future__ import annotations

import argparse
import json
import math
import sys
from pathlib import Path
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:  # the estimator (scipy.signal: a second to import) loads only when a command runs
    from bywire.host.platoon.string_stability import Result

# Below this magnitude-squared coherence the follower's motion at the peak is mostly not explained by its
# predecessor's (noise, own driver input), so the printed ratio is flagged as unreliable.
LOW_COHERENCE = 0.5


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("csv", type=Path, help="platoon recording (OpenACC ZalaZone / AstaZero or CARMA CSV)")
    p.add_argument("--json", type=Path, metavar="FILE", help="write the result as JSON")
    p.add_argument(
        "--signal", choices=("accel", "speed"), default="accel", help="signal whose ratio is taken"
    )
    p.add_argument(
        "--band",
        nargs=2,
        type=float,
        metavar=("LO", "HI"),
        help="frequency band in Hz (default: central 90 %% of the leader's acceleration power in 0.01-1 Hz)",
    )
    p.add_argument("--plot", type=Path, metavar="PNG", help="plot |H(f)| per pair and the leader's PSD")


def result_json(result: Result, source: str, notes: tuple[str, ...]) -> dict[str, Any]:
    return {
        "string_stability": result.string_stability,
        "pairs": [
            {
                "leader": p.leader,
                "follower": p.follower,
                "ratio": p.ratio,
                "peak_hz": p.peak_hz,
                "coherence": p.coherence_at_peak,
            }
            for p in result.pairs
        ],
        "band_hz": list(result.band_hz),
        "signal": result.signal,
        "source": source,
        "notes": list(notes),
    }


def _plot(result: Result, title: str, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")  # headless: write a file, never open a window
    import matplotlib.pyplot as plt

    fig, (ax_h, ax_p) = plt.subplots(2, 1, sharex=True, figsize=(8, 7))
    f = result.freq_hz
    for p in result.pairs:
        ax_h.plot(f[1:], p.gain[1:], label=f"{p.leader} -> {p.follower}: {p.ratio:.2f}")
    ax_h.axhline(1.0, color="k", lw=0.8)
    for ax in (ax_h, ax_p):
        ax.axvspan(*result.band_hz, color="0.9")
        ax.set_xscale("log")
    ax_h.set_ylabel(f"|H1| ({result.signal})")
    ax_h.legend(fontsize=7)
    ax_h.set_title(title, fontsize=9)
    ax_p.semilogy(f[1:], result.leader_psd[1:])
    unit = "(m/s²)²/Hz" if result.signal == "accel" else "(m/s)²/Hz"
    ax_p.set_ylabel(f"leader PSD {unit}")
    ax_p.set_xlabel("frequency (Hz)")
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


def main(args: argparse.Namespace) -> int:
    from bywire.host.platoon.string_stability import PlatoonCsvError, load_platoon_csv, string_stability

    try:
        platoon = load_platoon_csv(args.csv)
        band = (float(args.band[0]), float(args.band[1])) if args.band else None
        result = string_stability(platoon, signal=args.signal, band_hz=band)
    except OSError as exc:
        print(f"error: {exc.filename}: {exc.strerror}", file=sys.stderr)
        return 2
    except (PlatoonCsvError, ValueError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    print(f"{platoon.source}: {platoon.layout}, {len(platoon.vehicles)} vehicles, {platoon.time_s[-1]:.1f} s")
    for note in platoon.notes:
        print(f"  note: {note}")
    print(f"band {result.band_hz[0]:.3f}-{result.band_hz[1]:.3f} Hz, signal {result.signal}")
    print(f"{'leader':>24} {'follower':>24} {'ratio':>7} {'peak Hz':>8} {'coh':>5}")
    for p in result.pairs:
        flag = "  low coherence" if not p.coherence_at_peak >= LOW_COHERENCE else ""
        coh = p.coherence_at_peak
        print(f"{p.leader:>24} {p.follower:>24} {p.ratio:7.3f} {p.peak_hz:8.3f} {coh:5.2f}{flag}")
    verdict = "stable" if result.string_stability <= 1.0 else "UNSTABLE"
    print(f"string_stability {result.string_stability:.3f} ({verdict})")
    if not math.isfinite(result.string_stability):
        print("error: non-finite ratio", file=sys.stderr)
        return 1
    if args.json:
        args.json.write_text(json.dumps(result_json(result, platoon.source, platoon.notes), indent=2) + "\n")
    if args.plot:
        _plot(result, f"{Path(platoon.source).name} ({platoon.layout})", args.plot)
    return 0
