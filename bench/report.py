#!/usr/bin/env python3
"""Markdown tables from the benchmark's CSV files (bench/run.sh): time, accuracy and the ratio
of each library's time to sie's at the same size and thread count, then sie's stage times.

    python3 bench/report.py FILE.csv [FILE.csv ...]

sie rows come from bench_icp (stage times and the floor, one NN pass + one 6x6 solve, in `note`;
a second row per size runs the paper's single start, a third registers onto a target prepared
beforehand); compare_pcl also writes sie rows, which
are dropped here in favour of bench_icp's so every sie number comes from one program.
"""
import csv
import sys
from collections import defaultdict


def read_rows(paths):
    rows = []
    for path in paths:
        with open(path, newline="") as f:
            for row in csv.DictReader(f):
                if row["library"] == "sie" and "index=" not in row["note"]:
                    continue  # compare_pcl's own sie rows
                rows.append(row)
    return rows


def stages(note):
    return {k: float(v) for k, v in (p.split("=") for p in note.split() if "=" in p) if k != "repeats"}


def label(row):
    """Library and method, plus the correspondence cut-off where the library has one."""
    cut = [p.split("=")[1] for p in row["note"].split() if p.startswith("maxdist=")]
    text = f"{row['library']}, {row['method']}"
    return f"{text}, max distance {cut[0]} m" if cut and row["library"] != "sie" else text


def fmt_seconds(s):
    return f"{s:.3f}" if s < 10 else f"{s:.1f}"


def main(paths):
    rows = read_rows(paths)
    sie = {(int(r["points"]), int(r["threads"])): float(r["seconds"])
           for r in rows if r["library"] == "sie" and r["method"] == "point-to-plane"}
    by_size = defaultdict(list)
    for r in rows:
        by_size[int(r["points"])].append(r)
    print("| points | library, method | threads | seconds | time / sie's | iterations "
          "| rotation error (°) | translation error (mm) | converged |")
    print("|---:|---|---:|---:|---:|---:|---:|---:|---|")
    order = {"sie": 0, "small_gicp": 1, "open3d": 2, "pcl": 3}
    for n in sorted(by_size):
        for r in sorted(by_size[n], key=lambda r: (order.get(r["library"], 9), label(r), int(r["threads"]))):
            seconds = float(r["seconds"])
            base = sie.get((n, int(r["threads"])))
            ratio = f"{seconds / base:.2f}" if base else "–"
            rot = f"{float(r['rotation_error_deg']):.3f}" if r["rotation_error_deg"] else "–"
            trans = f"{1000 * float(r['translation_error_m']):.1f}" if r["translation_error_m"] else "–"
            print(f"| {n} | {label(r)} | {r['threads']} | {fmt_seconds(seconds)} | {ratio} "
                  f"| {r['iterations'] or '–'} | {rot} | {trans} | {r['converged'] or '–'} |")
    print()
    print("sie's stages (seconds; the SIE fit is `weighting`: histogram, σ, k, P(I|r) and weights):")
    print()
    print("| points | sie run | threads | total | kd-tree | normals | matching | SIE fit | solve | final evaluation "
          "| iterations | SIE fit / iteration | iteration (ms) | floor (ms) | iteration / floor |")
    print("|---:|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|")
    for r in rows:
        if r["library"] != "sie":
            continue
        s = stages(r["note"])
        loop = s["matching"] + s["weighting"] + s["solve"]
        per_iteration = loop / max(int(r["iterations"]), 1)
        floor = s.get("floor")
        floor_cells = (f"| {1e3 * floor:.2f} | {per_iteration / floor:.1f} " if floor else "| – | – ")
        target = r["method"]
        print(f"| {r['points']} | {target} | {r['threads']} | {fmt_seconds(float(r['seconds']))} | {s['index']:.3f} "
              f"| {s['normals']:.3f} | {s['matching']:.3f} | {s['weighting']:.3f} | {s['solve']:.3f} "
              f"| {s['evaluation']:.3f} | {r['iterations']} | {100 * s['weighting'] / loop:.0f} % "
              f"| {1e3 * per_iteration:.2f} {floor_cells}|")


if __name__ == "__main__":
    if len(sys.argv) < 2:
        sys.exit(__doc__)
    main(sys.argv[1:])
