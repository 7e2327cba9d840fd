#!/usr/bin/env python3
"""Tetrahedralise a STEP solid with gmsh (its own OpenCASCADE reader): prints JSON with the number of
volumes and tetrahedra. Used by the conformance suite as "gmsh can mesh it" (issue 5).

Usage: gmsh_tetrahedralise.py SOLID.step [CELLS_PER_DIAGONAL (default 40)]
"""
import json
import sys
import time

import gmsh


def main() -> int:
    t0 = time.time()
    per_diag = float(sys.argv[2]) if len(sys.argv) > 2 else 40.0
    gmsh.initialize()
    gmsh.option.setNumber("General.Terminal", 0)
    gmsh.model.add("solid")
    gmsh.model.occ.importShapes(sys.argv[1])
    gmsh.model.occ.synchronize()
    volumes = gmsh.model.getEntities(3)
    xmin, ymin, zmin, xmax, ymax, zmax = gmsh.model.getBoundingBox(-1, -1)
    diag = ((xmax - xmin) ** 2 + (ymax - ymin) ** 2 + (zmax - zmin) ** 2) ** 0.5
    gmsh.option.setNumber("Mesh.MeshSizeMin", diag / per_diag)
    gmsh.option.setNumber("Mesh.MeshSizeMax", diag / per_diag)
    gmsh.option.setNumber("Mesh.MeshSizeFromCurvature", 0)
    gmsh.option.setNumber("Mesh.MeshSizeExtendFromBoundary", 0)
    # MeshAdapt: the most robust 2D algorithm on B-spline faces with uneven parametrisation.
    gmsh.option.setNumber("Mesh.Algorithm", float(sys.argv[3]) if len(sys.argv) > 3 else 1)
    gmsh.option.setNumber("Mesh.Algorithm3D", float(sys.argv[4]) if len(sys.argv) > 4 else 1)
    try:
        gmsh.model.mesh.generate(3)
    except Exception as e:  # report, do not crash: the caller asserts on the count
        print(json.dumps({"ok": False, "error": str(e), "volumes": len(volumes), "tetrahedra": 0}))
        return 1
    _, tags, _ = gmsh.model.mesh.getElements(3)
    tets = sum(len(t) for t in tags)
    print(json.dumps({"ok": True, "volumes": len(volumes), "tetrahedra": int(tets), "seconds": time.time() - t0}))
    gmsh.finalize()
    return 0


if __name__ == "__main__":
    sys.exit(main())
