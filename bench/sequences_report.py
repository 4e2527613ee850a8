#!/usr/bin/env python3
"""Markdown table from the sequence benchmark's CSV files (bench/sequences.sh): frames per
second, each row's frames/s over the fastest peer's (same sequence and thread count, any mode),
drift (per-frame relative pose error) and the absolute trajectory error.

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
    # The goal (issue 30): sie's frames/s at least the fastest peer's on every sequence, any mode.
    fastest = {}
    for r in rows:
        if r["library"] != "sie":
            key = (r["sequence"], r["threads"])
            fastest[key] = max(fastest.get(key, 0.0), float(r["fps"]))
    order = {"sie": 0, "small_gicp": 1, "kiss_icp": 2}
    rows.sort(key=lambda r: (r["sequence"], r["mode"].replace("kiss-icp map", "frame-to-map"),
                             int(r["threads"]), order.get(r["library"], 9)))
    print("| sequence | points/frame | frames | library, method | mode | threads | frames/s | "
          "fps / fastest peer's | RPE translation RMSE (mm) | RPE rotation RMSE (°) | max (mm) | "
          "ATE (mm) | note |")
    print("|---|---:|---:|---|---|---:|---:|---:|---:|---:|---:|---:|---|")
    for r in rows:
        reference = fastest.get((r["sequence"], r["threads"]))
        ratio = f"{float(r['fps']) / reference:.2f}" if reference else ""
        # CSVs written before the column was added have none.
        ate = f"{float(r['ate_t_rmse_mm']):.1f}" if r.get("ate_t_rmse_mm") else ""
        print(f"| {r['sequence']} | {r['points']} | {r['frames']} | {r['library']}, {r['method']} | {r['mode']} | "
              f"{r['threads']} | {float(r['fps']):.2f} | {ratio} | {float(r['rpe_t_rmse_mm']):.2f} | "
              f"{float(r['rpe_r_rmse_deg']):.3f} | {float(r['rpe_t_max_mm']):.1f} | "
              f"{ate} | {r['note']} |")


if __name__ == "__main__":
    main()
