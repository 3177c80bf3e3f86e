"""Release delay from the data (``calibrate-occupation --release-offset auto``): a sweep on the real profiles.

Fleets of VIRM-6 (162 m) and FLIRT-4 (81 m) runs (``simulate-occupation``'s simulator, realistic driver,
``--runs`` per composition) on the three real TTOBench profiles with sections of U(600, 1500) m
(release_case.py), releases late by delay + U(0, jitter) per joint and run. Per fleet: the estimated delay
against the true mean (delay + jitter / 2), whether it was called separable, and the compositions assigned
(eq. 1-2, delta 1 s) with no offset, with the estimate, and with the true mean as a known offset.
Then two cases that must come out *not separable*: every run at one speed (kinematic runs at 30 m/s, no
stops between) with the four IC compositions, and on Stadelhofen (no three sections in one leg).

    .venv/bin/python bench/occupation/bench_release.py [--seeds 5] [--runs 6]

Prints Markdown tables; writes bench/out/bench_release.json and docs/images/release_delay.png.
"""

from __future__ import annotations

import argparse
import itertools
import json
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))
import release_case as rc  # noqa: E402

from train_calib.occupation.compositions import load_train_types  # noqa: E402
from train_calib.occupation.fleet import FleetConfig, simulate_fleet  # noqa: E402
from train_calib.occupation.generate import occupation_events  # noqa: E402
from train_calib.occupation.length import estimate_length  # noqa: E402
from train_calib.occupation.pipeline import default_stops  # noqa: E402
from train_calib.occupation.release_delay import estimate_release_delay  # noqa: E402
from train_calib.paths import config_file  # noqa: E402
from train_calib.track import Section, load_track  # noqa: E402

OUT = HERE.parent / "out"
FIGURE = HERE.parents[1] / "docs" / "images" / "release_delay.png"
SCENARIOS = {  # name: (fixed delay, jitter) in s
    "prompt 0-0.4 s": (0.0, 0.4),
    "issue 0.3-1.5 s": (0.3, 1.2),
    "fixed 0.5 s": (0.5, 0.0),
    "fixed 1.0 s": (1.0, 0.0),
    "1.0-2.0 s": (1.0, 1.0),
}


def _assigned(fleet, track, lengths, offset: float) -> int:
    est = [estimate_length(r.events, track.sections, lengths, 1.0, release_offset_s=offset) for r in fleet]
    return sum(e.composition == r.composition for e, r in zip(est, fleet))


def sweep(seeds: int, runs: int, workers: int) -> list[dict]:
    types = load_train_types(rc.TYPES)
    lengths = types.lengths()
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        for profile in ("vasteras", "yizhuang", "stadelhofen"):
            track = load_track(rc.write_case_track(profile, Path(tmp) / f"{profile}.yaml", seed=1))
            stops = default_stops(track)
            for name, (delay, jitter) in SCENARIOS.items():
                for seed in range(seeds):
                    cfg = FleetConfig(runs_per_composition=runs, release_delay_s=delay, release_jitter_s=jitter)
                    fleet = simulate_fleet(track, types, cfg, seed=100 + seed, workers=workers)
                    t0 = time.perf_counter()
                    est = estimate_release_delay({r.run_id: r.events for r in fleet}, track.sections, stops, lengths)
                    elapsed = time.perf_counter() - t0
                    true = delay + jitter / 2
                    rows.append(
                        {
                            "profile": profile,
                            "scenario": name,
                            "seed": seed,
                            "true_s": true,
                            "delay_s": est.delay_s,
                            "std_s": est.std_s,
                            "separable": est.separable,
                            "applied_s": est.applied_s,
                            "n_joints": est.n_joints,
                            "runs": len(fleet),
                            "correct_no_offset": _assigned(fleet, track, lengths, 0.0),
                            "correct_auto": _assigned(fleet, track, lengths, est.applied_s),
                            "correct_known": _assigned(fleet, track, lengths, true),
                            "sections_differ": est.sections_differ,
                            "elapsed_s": elapsed,
                            "reason": est.reason,
                        }
                    )
                print(f"{profile} {name}: done", file=sys.stderr, flush=True)
    return rows


def one_speed_case(compositions: tuple[str, ...]) -> dict:
    """Runs of ``compositions`` at 30 m/s throughout (no stop), the four IC lengths as the catalogue: a run's d
    and d + (L_c - L_c') / v fit equally; only a mix of compositions that fits one delay tells them apart."""
    edges = np.cumsum(np.concatenate(([0.0], np.random.default_rng(3).uniform(600, 1500, 14))))
    sections = [Section(f"S{k:02d}", float(a), float(b)) for k, (a, b) in enumerate(itertools.pairwise(edges))]
    lengths = load_train_types(config_file("train_types/ic_compositions.yaml")).lengths()
    rng = np.random.default_rng(4)
    runs = {}
    for k in range(12):
        length = lengths[compositions[k % len(compositions)]]
        t = np.linspace(0.0, edges[-1] / 30.0 + 60.0, 4000)
        s = -400.0 + 30.0 * t
        runs[f"r{k}"] = occupation_events(
            t, s, length, sections, run_id=f"r{k}", t0_s=rng.uniform(0, 1e5), release_delay_s=0.3,
            release_jitter_s=1.2, rng=rng,
        )  # fmt: skip
    est = estimate_release_delay(runs, sections, [-1e9, 1e9], lengths)
    return {"separable": est.separable, "delay_s": est.delay_s, "alias_delay_s": est.alias_delay_s,
            "reason": est.reason}  # fmt: skip


def table(rows: list[dict]) -> str:
    out = [
        "| profile | releases late by | true mean | |error| median / max | separable | within 0.2 s "
        "| assigned right: no offset / auto / known |",
        "|---|---|---|---|---|---|---|",
    ]
    keys = sorted({(r["profile"], r["scenario"]) for r in rows}, key=lambda k: (k[0], list(SCENARIOS).index(k[1])))
    for profile, scen in keys:
        rs = [r for r in rows if r["profile"] == profile and r["scenario"] == scen]
        err = np.array([abs(r["delay_s"] - r["true_s"]) for r in rs if r["separable"]])
        n = sum(r["runs"] for r in rs)
        sep = sum(r["separable"] for r in rs)
        within = int(np.sum(err <= 0.2))
        e_txt = f"{np.median(err):.2f} / {np.max(err):.2f} s" if err.size else "-"
        out.append(
            f"| {profile} | {scen} | {rs[0]['true_s']:.1f} s | {e_txt} | {sep}/{len(rs)} | {within}/{sep} | "
            f"{sum(r['correct_no_offset'] for r in rs)} / {sum(r['correct_auto'] for r in rs)} / "
            f"{sum(r['correct_known'] for r in rs)} of {n} |"
        )
    return "\n".join(out)


def figure(rows: list[dict], path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(6.4, 4.4))
    colours = {"vasteras": "tab:blue", "yizhuang": "tab:orange", "stadelhofen": "tab:grey"}
    jitter = np.random.default_rng(0)
    for profile, colour in colours.items():
        rs = [r for r in rows if r["profile"] == profile and r["separable"]]
        if not rs:
            continue
        x = np.array([r["true_s"] for r in rs]) + jitter.uniform(-0.03, 0.03, len(rs))
        ax.errorbar(x, [r["delay_s"] for r in rs], yerr=[r["std_s"] for r in rs], fmt="o", ms=3, color=colour,
                    label=f"{profile} ({len(rs)} fleets)", alpha=0.8)  # fmt: skip
    lim = np.array([-0.2, 1.8])
    ax.plot(lim, lim, "k-", lw=0.8)
    ax.fill_between(lim, lim - 0.2, lim + 0.2, color="k", alpha=0.08, label="+-0.2 s")
    ax.set_xlabel("true mean release delay, s")
    ax.set_ylabel("estimated (--release-offset auto), s, 1 sigma")
    ax.set_title("Release delay from the data: VIRM-6 + FLIRT fleets, sections 600-1500 m", fontsize=9)
    ax.legend(fontsize=8)
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110)
    plt.close(fig)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, default=5, help="fleets per profile and scenario (default 5)")
    parser.add_argument("--runs", type=int, default=6, help="runs per composition (default 6)")
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--no-figure", action="store_true")
    args = parser.parse_args()
    rows = sweep(args.seeds, args.runs, args.workers)
    one = {
        "all four IC compositions": one_speed_case(("VIRM4", "VIRM6", "VIRM10", "ICRm")),
        "VIRM6 only": one_speed_case(("VIRM6",)),
    }
    print(table(rows))
    print()
    for name, case in one.items():
        print(f"one speed (30 m/s, 0.3-1.5 s late), {name}: separable {case['separable']}: {case['reason']}")
    stad = [r for r in rows if r["profile"] == "stadelhofen"]
    print(f"stadelhofen: separable in {sum(r['separable'] for r in stad)}/{len(stad)}: {stad[0]['reason']}")
    fired = sum(r["sections_differ"] for r in rows)
    print(f"sections_differ (one delay per fleet: should not fire): {fired}/{len(rows)}")
    print(f"estimation time: median {1000 * np.median([r['elapsed_s'] for r in rows]):.0f} ms per fleet")
    OUT.mkdir(exist_ok=True)
    (OUT / "bench_release.json").write_text(json.dumps({"rows": rows, "one_speed": one}, indent=1, default=float))
    if not args.no_figure:
        figure(rows, FIGURE)
        print(f"written {FIGURE}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
