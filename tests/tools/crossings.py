#!/usr/bin/env python3
"""Count the crossing triangle pairs of a surface mesh, independently of scanstation's own counter.

Usage: crossings.py MESH [--weld REL] [--tolerance ABS]   (PLY/OBJ/STL/OFF; polygons fanned by trimesh)

A pair crosses when an edge of one triangle pierces the other's interior: the edge's ends lie strictly on
opposite sides of the other's plane and the edge passes strictly inside its three sides. Strictly means by
more than a relative tolerance (1e-10 of the bounding-box diagonal, cubed for volumes), so triangles that only
touch, or share an edge or a vertex, never count. Vertices closer than REL x the diagonal (default 1e-9) are
welded first, so that a tessellation written face by face (OpenCASCADE's BRepMesh, `step_check.py
--tess-out`) shares its edge nodes; pairs that share a welded vertex are skipped (as Open3D's
`get_self_intersecting_triangles` does). Coplanar overlaps are not counted.

With `--tolerance` (a tessellation's chordal deflection: `step_check.py` reports it), a crossing pair is
counted only when neither triangle can be moved clear of the other's plane by that much or less (its
penetration depth exceeds it): the exact surfaces lie within the deflection of their triangles, so a
shallower crossing of two triangles says nothing about the surfaces. Those pairs are reported as
"shallow_pairs" with their largest depth.

Broad phase: every triangle's bounding box is put into the cells of a uniform grid (cell = twice the median
box extent), pairs that share a cell and whose boxes overlap are tested, vectorised with numpy. Everything is
float64; no part of it is scanstation's.

Prints JSON: {"triangles", "vertices", "welded", "candidates", "crossing_pairs", "at": [up to 10 points],
"deepest" (the largest penetration depth of a counted pair), "shallow_pairs", "shallow_depth_max", "tolerance",
"time_s"}.
"""
from __future__ import annotations

import argparse
import json
import sys
import time

import numpy as np
import trimesh


def load(path):
    m = trimesh.load(path, force="mesh", process=False)
    return np.asarray(m.vertices, float), np.asarray(m.faces, np.int64)


def weld(V, F, rel):
    diag = float(np.linalg.norm(V.max(0) - V.min(0))) or 1.0
    q = np.round(V / (rel * diag)).astype(np.int64)
    _, first, inv = np.unique(q, axis=0, return_index=True, return_inverse=True)
    inv = inv.reshape(-1)
    return V[first], inv[F], diag


def candidate_pairs(V, F):
    lo = V[F].min(1)
    hi = V[F].max(1)
    ext = np.median((hi - lo).max(1))
    cell = max(2.0 * ext, 1e-300)
    a = np.floor(lo / cell).astype(np.int64)
    b = np.floor(hi / cell).astype(np.int64)
    span = b - a + 1
    keys, tris = [], []
    for dx in range(int(span[:, 0].max())):
        for dy in range(int(span[:, 1].max())):
            for dz in range(int(span[:, 2].max())):
                d = np.array([dx, dy, dz])
                ok = np.all(d < span, axis=1)
                c = a[ok] + d
                keys.append(c[:, 0] * 73856093 ^ c[:, 1] * 19349663 ^ c[:, 2] * 83492791)
                tris.append(np.nonzero(ok)[0])
    keys = np.concatenate(keys)
    tris = np.concatenate(tris)
    order = np.lexsort((tris, keys))
    keys, tris = keys[order], tris[order]
    starts = np.nonzero(np.r_[True, keys[1:] != keys[:-1]])[0]
    ends = np.r_[starts[1:], len(keys)]
    pairs = []
    for s, e in zip(starts, ends):
        n = e - s
        if n < 2:
            continue
        t = tris[s:e]
        i, j = np.triu_indices(n, 1)
        pairs.append(np.stack([t[i], t[j]], 1))
    if not pairs:
        return np.zeros((0, 2), np.int64)
    P = np.unique(np.concatenate(pairs), axis=0)
    overlap = np.all((lo[P[:, 0]] <= hi[P[:, 1]]) & (lo[P[:, 1]] <= hi[P[:, 0]]), axis=1)
    P = P[overlap]
    shared = np.zeros(len(P), bool)
    for x in range(3):
        for y in range(3):
            shared |= F[P[:, 0], x] == F[P[:, 1], y]
    return P[~shared]


def orient(a, b, c, d):
    return np.einsum("ij,ij->i", np.cross(b - a, c - a), d - a)


def pierces(p, q, a, b, c, eps_vol):
    """Segment pq strictly crosses triangle abc's interior (rows)."""
    sp = orient(a, b, c, p)
    sq = orient(a, b, c, q)
    across = ((sp > eps_vol) & (sq < -eps_vol)) | ((sp < -eps_vol) & (sq > eps_vol))
    s1 = orient(p, q, a, b)
    s2 = orient(p, q, b, c)
    s3 = orient(p, q, c, a)
    inside = ((s1 > eps_vol) & (s2 > eps_vol) & (s3 > eps_vol)) | (
        (s1 < -eps_vol) & (s2 < -eps_vol) & (s3 < -eps_vol))
    return across & inside


def crossing(V, F, P, diag):
    eps_vol = (1e-10 * diag) ** 3
    hit = np.zeros(len(P), bool)
    for chunk in range(0, len(P), 200_000):
        Q = P[chunk:chunk + 200_000]
        h = np.zeros(len(Q), bool)
        for s, t in ((0, 1), (1, 0)):
            A = V[F[Q[:, s]]]
            B = V[F[Q[:, t]]]
            for e in range(3):
                h |= pierces(A[:, e], A[:, (e + 1) % 3], B[:, 0], B[:, 1], B[:, 2], eps_vol)
        hit[chunk:chunk + 200_000] = h
    return P[hit]


def depth(A, B):
    """How far triangle A reaches past B's plane on its lesser side (rows): the move that clears it."""
    n = np.cross(B[:, 1] - B[:, 0], B[:, 2] - B[:, 0])
    n /= np.linalg.norm(n, axis=1, keepdims=True)
    d = np.einsum("ikj,ij->ik", A - B[:, :1], n)
    return np.minimum(d.max(1), -d.min(1))


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("mesh")
    ap.add_argument("--weld", type=float, default=1e-9)
    ap.add_argument("--tolerance", type=float, default=0.0)
    args = ap.parse_args()
    t0 = time.time()
    V0, F0 = load(args.mesh)
    V, F, diag = weld(V0, F0, args.weld)
    area2 = np.linalg.norm(np.cross(V[F[:, 1]] - V[F[:, 0]], V[F[:, 2]] - V[F[:, 0]]), axis=1)
    F = F[area2 > 0]
    P = candidate_pairs(V, F)
    X = crossing(V, F, P, diag)
    A, B = V[F[X[:, 0]]], V[F[X[:, 1]]]
    dep = np.minimum(depth(A, B), depth(B, A)) if len(X) else np.zeros(0)
    deep = dep > args.tolerance
    at = [V[F[i]].mean(0).round(6).tolist() for i in X[deep][:10, 0]]
    print(json.dumps({
        "triangles": int(len(F)), "vertices": int(len(V0)), "welded": int(len(V)),
        "candidates": int(len(P)), "crossing_pairs": int(deep.sum()), "at": at,
        "deepest": float(dep[deep].max()) if deep.any() else 0.0,
        "shallow_pairs": int((~deep).sum()),
        "shallow_depth_max": float(dep[~deep].max()) if (~deep).any() else 0.0,
        "tolerance": args.tolerance, "time_s": round(time.time() - t0, 3),
    }))


if __name__ == "__main__":
    try:
        main()
    except Exception as e:  # noqa: BLE001
        print(json.dumps({"error": f"{type(e).__name__}: {e}"}))
        sys.exit(2)
