#!/usr/bin/env python3
"""The synthetic cloud of the reconstruction scale check (BENCHMARKS.md, issue 32): N points (default ten
million) area-uniform on a torus (R = 1, r = 0.35) with exact normals and Gaussian noise 0.0005, seeded, as
binary little-endian PLY (x y z nx ny nz float).

Usage: .venv-validators/bin/python scripts/make-torus-cloud.py OUT.ply [N]
then:  scanstation --memory-budget 1G reconstruct OUT.ply -o out.ply   (under /usr/bin/time -f '%e s %M KB')
"""
import sys

import numpy as np


def main():
    out = sys.argv[1]
    n = int(sys.argv[2]) if len(sys.argv) > 2 else 10_000_000
    rng = np.random.default_rng(1)
    big_r, r = 1.0, 0.35
    u = rng.random(n) * 2 * np.pi
    # Area-uniform: the area element grows with R + r cos v (rejection).
    v = rng.random(n * 2) * 2 * np.pi
    w = rng.random(n * 2) * (big_r + r)
    v = v[w < big_r + r * np.cos(v)][:n]
    cu, su, cv, sv = np.cos(u), np.sin(u), np.cos(v), np.sin(v)
    p = np.stack([(big_r + r * cv) * cu, (big_r + r * cv) * su, r * sv], 1)
    nrm = np.stack([cv * cu, cv * su, sv], 1)
    p += rng.normal(0, 0.0005, p.shape)
    d = np.zeros(n, dtype=[(c, "<f4") for c in ["x", "y", "z", "nx", "ny", "nz"]])
    for k, c in enumerate("xyz"):
        d[c] = p[:, k]
        d["n" + c] = nrm[:, k]
    props = "".join(f"property float {c}\n" for c in ["x", "y", "z", "nx", "ny", "nz"])
    with open(out, "wb") as f:
        f.write(f"ply\nformat binary_little_endian 1.0\nelement vertex {n}\n{props}end_header\n".encode())
        f.write(d.tobytes())


if __name__ == "__main__":
    main()
