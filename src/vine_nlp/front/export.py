"""Tube meshes for other tools (``vine-nlp export``): STL, OBJ, PLY and glTF binary (.glb).

The tube is a closed triangle mesh (trimesh): rings of ``RING`` vertices at the
true diameter D around the model's center line, sampled at most D/8 apart along
the material and 2 deg apart in direction, on a rotation-minimizing frame, closed by flat caps at the base and the tip. Every edge is shared
by exactly two faces (``trimesh.Trimesh.is_watertight``) and the enclosed volume
is pi (D/2)^2 times the center-line length up to the polygon's area
(RING = 64: 0.16 % less).

The actuator line is a thin closed tube of its own (diameter D/10): a second
object in OBJ, a second node in glTF, and for STL and PLY (one mesh per file) a
second file ``<name>.actuator.<ext>`` beside the first.

Several actuators on one tube: one file per state, ``<name>.<state>.<ext>`` (``--state NAME``: that state alone,
in the file named), the tube in that state's shape and every actuator's line on it (``actuator-<name>``: an
object, a node, or a file ``<name>.<state>.actuator-<line>.<ext>`` beside), each line in its palette colour.

Units: glTF is in metres by definition, so coordinates are scaled from the
archive's ``units`` (cm, mm, m). STL, OBJ and PLY keep the archive's units and say
so where the format has room for it (STL header, OBJ and PLY comments).

trimesh is imported inside the functions that need it (a heavy package).
"""

from __future__ import annotations

import math
from functools import partial
from pathlib import Path

import numpy as np

from vine_nlp.errors import InputError
from vine_nlp.front import palette
from vine_nlp.front.files import check_output, output_format, within_limits
from vine_nlp.front.states import picked_states, samples, state_lines
from vine_nlp.front.view import tube_faces
from vine_nlp.io.archive import Archive, write_atomic
from vine_nlp.model import shape_lines
from vine_nlp.model.actuators import Lines
from vine_nlp.model.units import METRES_PER_UNIT
from vine_nlp.problem import Routing

FORMATS = (".stl", ".obj", ".ply", ".glb")
mesh_format = partial(output_format, formats=FORMATS, what="mesh")  # an output's format by its extension (ValueError)
RING = 64
ACTUATOR_DIAMETER = 0.1  # of D
TUBE_RGBA = [90, 140, 200, 255]


def tube_lines(routing: Routing, D: float, spacing: float | None = None):
    """Center and actuator lines sampled by :func:`samples`: two (P, 3) arrays."""
    seg, frac = samples(routing.theta, routing.lam, routing.length, D, spacing)
    center, inner, _ = shape_lines(routing.theta, routing.lam, routing.length, D, seg, frac, routing.initial_pose)
    return center, inner


def state_meshes(lines: Lines, D: float, active, state: str = "") -> list:
    """[(name, mesh, rgba)]: the tube in a state's shape, then every actuator's line (palette.LINES)."""
    _, _, shape, paths = state_lines(lines, D, active, state)
    return [("tube", tube_mesh(shape.center, D, normal=shape.inner[0] - shape.center[0]), TUBE_RGBA)] + [
        (f"actuator-{name}", tube_mesh(p, ACTUATOR_DIAMETER * D), _rgba(palette.LINES[k % len(palette.LINES)]))
        for k, (name, p) in enumerate(paths.items())]


def _rgba(color: str) -> list:
    return [int(color[i:i + 2], 16) for i in (1, 3, 5)] + [255]


def _frames(line, normal0=None):
    """Unit tangent, normal and binormal along a polyline on a rotation-minimizing frame (double reflection,
    Wang et al. 2008), started from ``normal0`` (projected off the first tangent; default: any): the rings do
    not twist about the line, so the faces between two rings do not cut into the tube."""
    T = np.gradient(line, axis=0)
    T /= np.linalg.norm(T, axis=1, keepdims=True)
    if normal0 is None or np.linalg.norm(np.cross(normal0, T[0])) < 1e-9 * np.linalg.norm(normal0):
        normal0 = np.array([1.0, 0.0, 0.0]) if abs(T[0, 0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    N = np.empty_like(T)
    N[0] = normal0 - np.dot(normal0, T[0]) * T[0]
    N[0] /= np.linalg.norm(N[0])
    for i in range(len(T) - 1):
        v1 = line[i + 1] - line[i]  # reflect the frame in the plane bisecting the chord ...
        c1 = v1 @ v1
        r, t = N[i] - (2 / c1) * (v1 @ N[i]) * v1, T[i] - (2 / c1) * (v1 @ T[i]) * v1
        v2 = T[i + 1] - t  # ... then in the plane that takes the reflected tangent onto the next one
        c2 = v2 @ v2
        N[i + 1] = r - (2 / c2) * (v2 @ r) * v2 if c2 > 1e-30 else r
    return T, N, np.cross(T, N)


def tube_mesh(line, diameter: float, normal=None, ring: int = RING):
    """A closed trimesh.Trimesh (watertight, faces wound outward) of ``diameter`` around the polyline ``line``
    (P >= 2 distinct points) with flat end caps, ``ring`` vertices per ring; ``normal``: direction of the first
    ring's first vertex (the model's N at the base), the rings following on a rotation-minimizing frame."""
    import trimesh

    line = np.asarray(line, float)
    keep = np.concatenate([[True], np.linalg.norm(np.diff(line, axis=0), axis=1) > 1e-9 * diameter])
    line = line[keep]
    if len(line) < 2:
        raise ValueError("a tube needs a center line of two distinct points or more")
    T, N, B = _frames(line, normal)
    a = 2 * math.pi * np.arange(ring) / ring
    r = 0.5 * diameter
    rings = line[:, None, :] + r * (np.cos(a)[None, :, None] * N[:, None, :] + np.sin(a)[None, :, None] * B[:, None, :])
    V = np.concatenate([rings.reshape(-1, 3), line[:1], line[-1:]])
    mesh = trimesh.Trimesh(vertices=V, faces=tube_faces(len(line), ring), process=False)
    if mesh.volume < 0:
        mesh.invert()
    return mesh


def run_meshes(archive: Archive, run: str):
    """(tube, actuator) meshes of one run, in the archive's units."""
    r = archive.runs[run]
    D = archive.diameter
    center, inner = tube_lines(r.routing, D)
    tube = tube_mesh(center, D, normal=inner[0] - center[0])
    actuator = tube_mesh(inner, ACTUATOR_DIAMETER * D)
    return tube, actuator


def beside(path, name: str) -> Path:
    """Where an STL or PLY puts its part ``name`` (one mesh per file): ``<stem>.<name><ext>`` beside ``path``."""
    path = Path(path)
    return path.with_name(f"{path.stem}.{name}{path.suffix}")


def write_mesh(archive: Archive, path, run: str | None = None, parts: list | None = None, what: str = "") -> dict:
    """Write the tube of ``run`` (default: the archive's default run) to ``path`` (.stl, .obj, .ply, .glb).

    ``parts``: [(name, mesh, rgba)], the tube first (default: the run's tube and actuator line); ``what`` is added
    to the note after the run (" state NAME"). Returns dict(run, files (written, in order), faces, watertight,
    volume (archive units^3), units (of the file's coordinates), scale (file units per archive unit)). ValueError
    for an unknown extension, an unknown run, an archive without runs or units glTF cannot scale.
    """
    import trimesh

    path = Path(path)
    ext = mesh_format(path)
    run = archive.pick_run(run)
    units = archive.units
    if ext == ".glb" and units not in METRES_PER_UNIT:
        raise ValueError(f"glTF is in metres: cannot scale units {units!r} (use {', '.join(METRES_PER_UNIT)})")
    if parts is None:
        parts = list(zip(("tube", "actuator"), run_meshes(archive, run), (TUBE_RGBA, [214, 39, 40, 255])))
    tube = parts[0][1]
    info = {"run": run, "faces": len(tube.faces), "watertight": bool(tube.is_watertight), "volume": float(tube.volume),
            "units": units, "scale": 1.0}
    note = f"vine_nlp tube of {archive.name} run {run}{what}, units {units}"
    if ext in (".stl", ".ply"):  # one mesh per file, the actuator lines beside the tube
        info["files"] = [path] + [beside(path, name) for name, _, _ in parts[1:]]
        for f, (name, mesh, _) in zip(info["files"], parts):
            blob = _with_units(mesh.export(file_type=ext[1:]), ext, note + ("" if name == "tube" else f", {name} line"))
            write_atomic(f, lambda t, b=blob: Path(t).write_bytes(b))
        return info
    scale = METRES_PER_UNIT[units] if ext == ".glb" else 1.0
    scene = trimesh.Scene()
    for name, mesh, color in parts:
        m = mesh.copy()
        m.apply_scale(scale)
        if ext == ".glb":
            m.visual.face_colors = color
        scene.add_geometry(m, node_name=name, geom_name=name)
    if ext == ".glb":
        info.update(units="m", scale=scale)
        data = scene.export(file_type="glb")
    else:
        text = scene.export(file_type="obj")
        data = f"# {note}\n{text if isinstance(text, str) else text.decode()}".encode()
    write_atomic(path, lambda t: Path(t).write_bytes(data))
    info["files"] = [path]
    return info


def _with_units(data: bytes, ext: str, note: str) -> bytes:
    """Put ``note`` (with the units) where the format has room: the STL header, a PLY comment."""
    if ext == ".stl" and not data[:5].lower().startswith(b"solid"):
        return note.encode("ascii", "replace")[:80].ljust(80, b" ") + data[80:]
    if ext == ".ply":
        head, sep, rest = data.partition(b"\n")
        fmt, sep2, rest2 = rest.partition(b"\n")
        return head + sep + fmt + sep2 + f"comment {note}\n".encode("ascii", "replace") + rest2
    return data


def cmd_export_states(args) -> int:
    """``export`` of an archive of several actuators: one file per state, or ``--state NAME`` alone in the file
    named (module docstring); every output checked before any is written."""
    out = Path(args.output)
    try:
        ext = mesh_format(out)
    except ValueError as e:
        raise InputError(out, "-o", str(e)) from None
    a, run, r, _, states = picked_states(args.archive, args.run, args.state)
    within_limits("export", a, args.archive, [run])
    paths = {s: out if args.state else beside(out, s) for s in states}
    for path in paths.values():
        check_output(path, args.force)
        for name in r.lines.names if ext in (".stl", ".ply") else ():
            check_output(beside(path, f"actuator-{name}"), args.force)
    for s, active in states.items():
        try:
            info = write_mesh(a, paths[s], run, parts=state_meshes(r.lines, a.diameter, active, s), what=f" state {s}")
        except ValueError as e:
            raise InputError(args.archive, "units", str(e)) from None
        print(f"run {run} state {s} ({', '.join(active)}): {info['faces']} faces, {'closed' if info['watertight'] else 'NOT closed'}, "
              f"volume {info['volume']:.4g} {a.units}^3, coordinates in {info['units']} -> {', '.join(str(f) for f in info['files'])}")
    return 0
