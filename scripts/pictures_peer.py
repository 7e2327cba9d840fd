#!/usr/bin/env python3
"""The pictures benchmark's peer: what a Python developer reaches for to draw a coloured mesh headless —
matplotlib (Agg) with a Poly3DCollection per view, the faces coloured by the error map's vertex colours,
four views (front, side, top, isometric) on one 1024 x 768 figure, saved as PNG.

    pictures_peer.py ERROR_MAP.ply OUT.png   ->  prints {"seconds": ..., "peak_rss_mib": ..., "triangles": ...}
"""
import json
import resource
import sys
import time

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
import trimesh  # noqa: E402
from mpl_toolkits.mplot3d.art3d import Poly3DCollection  # noqa: E402


def main():
    src, out = sys.argv[1], sys.argv[2]
    mesh = trimesh.load(src, process=False)
    t0 = time.perf_counter()
    tris = mesh.vertices[mesh.faces]
    colours = mesh.visual.vertex_colors[mesh.faces].mean(axis=1)[:, :3] / 255.0
    fig = plt.figure(figsize=(10.24, 7.68), dpi=100)
    lo, hi = mesh.bounds
    views = [("front", 90, -90), ("side", 0, 0), ("top", 90, -90), ("iso", 30, -45)]
    for k, (name, elev, azim) in enumerate(views):
        ax = fig.add_subplot(2, 2, k + 1, projection="3d")
        ax.add_collection3d(Poly3DCollection(tris, facecolors=colours, edgecolors="none"))
        ax.set_xlim(lo[0], hi[0]); ax.set_ylim(lo[1], hi[1]); ax.set_zlim(lo[2], hi[2])
        ax.view_init(elev=elev, azim=azim)
        ax.set_axis_off()
        ax.set_title(name)
    fig.savefig(out)
    seconds = time.perf_counter() - t0
    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0
    print(json.dumps({"seconds": seconds, "peak_rss_mib": peak, "triangles": int(len(mesh.faces))}))


if __name__ == "__main__":
    main()
