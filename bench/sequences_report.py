#!/usr/bin/env python3
"""Markdown table from the sequence benchmark's CSV files (bench/sequences.sh): frames per
second, each library's frames/s over sie's (same sequence, mode family and thread count) and
drift (per-frame relative pose error).

    python3 bench/sequences_report.py FILE.csv [FILE.csv ...]
"""
import csv
import sys


def main():
    rows = []
    for path in sys.argv[1:]:
        with open(path, newline="") as f:
            rows.extend(r for r in csv.DictReader(f) if r.get("library"))
    if not rows:
        sys.exit("no rows")
    # sie's warm-start row is the reference (the way to run a sequence); its frame-to-map row is
    # KISS-ICP's (both register onto a map).
    sie = {(r["sequence"], r["mode"], r["threads"]): float(r["fps"])
           for r in rows if r["library"] == "sie" and "warm start" in r["method"]}
    order = {"sie": 0, "small_gicp": 1, "kiss_icp": 2}
    rows.sort(key=lambda r: (r["sequence"], r["mode"].replace("kiss-icp map", "frame-to-map"),
                             int(r["threads"]), order.get(r["library"], 9)))
    print("| sequence | points/frame | frames | library, method | mode | threads | frames/s | "
          "fps / sie warm's | RPE translation RMSE (mm) | RPE rotation RMSE (°) | max (mm) | note |")
    print("|---|---:|---:|---|---|---:|---:|---:|---:|---:|---:|---|")
    for r in rows:
        mode = "frame-to-map" if r["mode"] == "kiss-icp map" else r["mode"]
        reference = sie.get((r["sequence"], mode, r["threads"]))
        ratio = f"{float(r['fps']) / reference:.2f}" if reference else ""
        print(f"| {r['sequence']} | {r['points']} | {r['frames']} | {r['library']}, {r['method']} | {r['mode']} | "
              f"{r['threads']} | {float(r['fps']):.2f} | {ratio} | {float(r['rpe_t_rmse_mm']):.2f} | "
              f"{float(r['rpe_r_rmse_deg']):.3f} | {float(r['rpe_t_max_mm']):.1f} | {r['note']} |")


if __name__ == "__main__":
    main()
