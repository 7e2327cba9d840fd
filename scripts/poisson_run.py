#!/usr/bin/env python3
"""Run the validators kit's screened-Poisson peer (Open3D or PyMeshLab) on a cloud, and nothing else.

The kit's `poisson_peer.py` also measures its result against the cloud, which costs time and memory that are
not the reconstruction's. This driver calls the kit's own functions (`load_cloud`, `estimate_normals`,
`run_open3d`, `run_pymeshlab`, the same settings and defaults) and writes the mesh, so that the benchmark
(`cargo bench --bench reconstruct`) can time and measure every tool the same way.

Usage: poisson_run.py KIT_DIR CLOUD OUT.ply --backend open3d|pymeshlab --depth D [--force-estimate-normals]
Prints JSON: seconds (normals, reconstruction, total), the process's peak RSS (MiB), vertices, faces.
"""
import argparse
import json
import resource
import sys
import time


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("kit")
    ap.add_argument("cloud")
    ap.add_argument("out")
    ap.add_argument("--backend", choices=["open3d", "pymeshlab"], default="open3d")
    ap.add_argument("--depth", type=int, default=9)
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--force-estimate-normals", action="store_true")
    args = ap.parse_args()
    sys.path.insert(0, args.kit)
    import poisson_peer as pp  # the kit's peer: its functions and defaults

    defaults = dict(scale=1.1, linear_fit=False, samples_per_node=1.5, point_weight=4.0, trim_quantile=0.0)
    settings = argparse.Namespace(depth=args.depth, threads=args.threads, **defaults)
    t0 = time.perf_counter()
    P, N = pp.load_cloud(args.cloud)
    t_norm = 0.0
    if N is None or args.force_estimate_normals:
        t1 = time.perf_counter()
        N = pp.estimate_normals(P, 30, 15)
        t_norm = time.perf_counter() - t1
    fn = pp.run_open3d if args.backend == "open3d" else pp.run_pymeshlab
    V, F, t_rec = fn(P, N, settings)
    import open3d as o3d

    mesh = o3d.geometry.TriangleMesh(o3d.utility.Vector3dVector(V), o3d.utility.Vector3iVector(F.astype("int32")))
    o3d.io.write_triangle_mesh(args.out, mesh)
    print(json.dumps({
        "seconds": {"normals": t_norm, "reconstruction": t_rec, "total": time.perf_counter() - t0},
        "peak_mib": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0,
        "vertices": int(len(V)),
        "faces": int(len(F)),
    }))


if __name__ == "__main__":
    main()
