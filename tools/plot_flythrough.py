#!/usr/bin/env python3
"""Per-frame worst screen error of fly-throughs as an SVG (no dependencies).

    tools/plot_flythrough.py OUT.svg TAU LABEL=stats.csv [LABEL=stats.csv ...]

Each CSV is what `terrachunk-view --headless --flythrough ... --stats` writes;
the plot draws each run's `max_rho_px` per frame and a line at τ.
"""
import csv
import sys

COLOURS = ["#1f77b4", "#d62728", "#2ca02c", "#9467bd"]


def main():
    if len(sys.argv) < 4:
        sys.exit(__doc__)
    out, tau = sys.argv[1], float(sys.argv[2])
    runs = []
    for arg in sys.argv[3:]:
        label, path = arg.rsplit("=", 1)
        with open(path, newline="") as f:
            rows = list(csv.DictReader(f))
        runs.append((label, [float(r["max_rho_px"]) for r in rows]))
    w, h, m = 720, 300, 50
    frames = max(len(r) for _, r in runs)
    top = max(max(max(r) for _, r in runs), 2 * tau) * 1.05
    x = lambda i: m + (w - 2 * m) * i / max(frames - 1, 1)
    y = lambda v: h - m + (2 * m - h) * v / top
    svg = [f'<svg xmlns="http://www.w3.org/2000/svg" width="{w}" height="{h}" font-family="sans-serif" font-size="12">',
           f'<rect width="{w}" height="{h}" fill="white"/>',
           f'<line x1="{m}" y1="{h - m}" x2="{w - m}" y2="{h - m}" stroke="black"/>',
           f'<line x1="{m}" y1="{m}" x2="{m}" y2="{h - m}" stroke="black"/>',
           f'<line x1="{m}" y1="{y(tau):.1f}" x2="{w - m}" y2="{y(tau):.1f}" stroke="gray" stroke-dasharray="4"/>',
           f'<text x="{w - m + 4}" y="{y(tau) + 4:.1f}">τ</text>',
           f'<text x="{w / 2}" y="{h - 12}" text-anchor="middle">frame</text>',
           f'<text x="14" y="{h / 2}" transform="rotate(-90 14 {h / 2})" text-anchor="middle">worst ρ (px)</text>',
           f'<text x="{m - 6}" y="{y(0) + 4:.1f}" text-anchor="end">0</text>',
           f'<text x="{m - 6}" y="{y(top / 1.05) + 4:.1f}" text-anchor="end">{top / 1.05:.2f}</text>']
    for k, (label, rho) in enumerate(runs):
        c = COLOURS[k % len(COLOURS)]
        pts = " ".join(f"{x(i):.1f},{y(v):.1f}" for i, v in enumerate(rho))
        svg.append(f'<polyline fill="none" stroke="{c}" stroke-width="1.5" points="{pts}"/>')
        svg.append(f'<text x="{m + 10}" y="{m + 16 * k}" fill="{c}">{label}</text>')
    svg.append("</svg>")
    with open(out, "w") as f:
        f.write("\n".join(svg) + "\n")


if __name__ == "__main__":
    main()
