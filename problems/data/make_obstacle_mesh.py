"""Make the mesh obstacle of problems/obstacle-mesh.toml: a bent block (problems/data/bent-block.stl).

A 30 x 4 x 8 cm block (subdivided to edges of at most 4 cm: 360 triangles) bent around the
z axis on a 20 cm radius (1.5 rad of arc), so it has a concave side: a closed, non-convex
triangle mesh, in cm. Run from anywhere: python3 problems/data/make_obstacle_mesh.py
"""

from pathlib import Path

import numpy as np
import trimesh

BEND_RADIUS = 20.0  # cm, radius of the block's mid-surface after bending
EXTENTS = (30.0, 4.0, 8.0)  # cm, before bending: length (bent), thickness, height
MAX_EDGE = 4.0  # cm
OFFSET = np.array([30.0, 12.0, 0.0])  # where the bend's apex goes in the problem's frame
OUT = Path(__file__).resolve().parent / "bent-block.stl"


def bent_block() -> trimesh.Trimesh:
    box = trimesh.creation.box(extents=EXTENTS)
    v, f = trimesh.remesh.subdivide_to_size(box.vertices, box.faces, max_edge=MAX_EDGE)
    x, y, z = v[:, 0], v[:, 1], v[:, 2]
    a = x / BEND_RADIUS  # arc length -> angle around the bend center (0, BEND_RADIUS)
    rho = BEND_RADIUS - y
    bent = np.column_stack([rho * np.sin(a), BEND_RADIUS - rho * np.cos(a), z]) + OFFSET
    mesh = trimesh.Trimesh(bent, f, process=True)
    if mesh.volume < 0:
        mesh.invert()
    assert mesh.is_watertight and mesh.is_winding_consistent
    return mesh


if __name__ == "__main__":
    m = bent_block()
    m.export(OUT)
    print(f"{OUT}: {len(m.faces)} faces, {len(m.vertices)} vertices, volume {m.volume:.1f} cm^3")
