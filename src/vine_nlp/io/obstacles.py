"""Obstacles in problem files (``[[obstacles]]``) and in result archives (``/obstacles/<k>``).

formats.md "Obstacles". Every bad value raises ``InputError(file, "obstacles[k].key",
reason)`` with k counted from 0 (as the archive's ``/obstacles/<k>``). A mesh file's
*content* is a data file of its own: its errors name the mesh file, key ``mesh``.

Meshes must be closed (watertight: every edge shared by exactly two faces, with a consistent winding): inside and
outside, and so the sign of the distance, mean nothing for an open surface. Vertices are merged and zero-area faces
dropped on reading (an STL file stores every triangle's corners separately); a mesh wound inside-out (negative volume)
is turned around. At most ``MAX_MESH_FACES`` faces: the design keeps rows for the nearest triangles of every tube
sample."""

from __future__ import annotations

import difflib
import io
import math
from pathlib import Path

import h5py
import numpy as np

from vine_nlp.analysis.obstacles import GROWTH_MODES
from vine_nlp.errors import InputError
from vine_nlp.io import files, limits
from vine_nlp.io.h5read import decode_attr
from vine_nlp.io.validate import is_number
from vine_nlp.model.obstacles import OBSTACLE_TYPES, SHAPES, Box, Capsule, Mesh, Plane, Sphere, is_rotation, rotation_from_degrees

MAX_OBSTACLES = 1000
MAX_MESH_FACES = 20_000
MESH_SUFFIXES = (".stl", ".obj", ".ply")
DESIGN_KEYS = ("obstacle_margin", "growth")  # [design] keys read by parse_obstacle_design
DEFAULT_GROWTH = "while-actuated"

_KEYS = {
    "sphere": ("center", "radius"),
    "box": ("center", "size", "rotation", "rotation_deg"),
    "capsule": ("p0", "p1", "radius"),
    "plane": ("point", "normal"),
    "mesh": ("file",),
}
_REQUIRED = {shape: tuple(k for k in keys if not k.startswith("rotation")) for shape, keys in _KEYS.items()}
_COMMON = ("shape", "name")
# archive datasets per shape: name -> shape of the array (None: any number of rows)
_DATASETS = {
    "sphere": {"center": (3,), "radius": ()},
    "box": {"center": (3,), "size": (3,), "rotation": (3, 3)},
    "capsule": {"p0": (3,), "p1": (3,), "radius": ()},
    "plane": {"point": (3,), "normal": (3,)},
    "mesh": {"vertices": (None, 3), "faces": (None, 3)},
}


# ------------------------------------------------------------------ problem files


def parse_obstacles(tables, file, base_dir=None) -> list:
    """The obstacles of a problem file's ``[[obstacles]]`` array of tables, validated.

    ``tables`` is ``data["obstacles"]`` of the parsed TOML document, ``file`` the problem file (named in errors),
    ``base_dir`` the directory mesh ``file`` paths are relative to (default: the problem file's). Returns the
    shapes in file order. InputError ``(file, "obstacles[k].key", reason)``; a bad mesh file's content:
    ``(mesh file, "mesh", reason)``."""
    file = str(file)
    base = Path(file).parent if base_dir is None else Path(base_dir)
    if not (isinstance(tables, list) and all(isinstance(t, dict) for t in tables)):
        raise InputError(file, "obstacles", "must be an array of tables ([[obstacles]])")
    if len(tables) > MAX_OBSTACLES:
        raise InputError(file, "obstacles", f"has {len(tables)} obstacles; at most {MAX_OBSTACLES}")
    return [_obstacle(file, base, k, t) for k, t in enumerate(tables)]


def _obstacle(file, base, k, t):
    def err(key, reason):
        return InputError(file, f"obstacles[{k}].{key}" if key else f"obstacles[{k}]", reason)

    shape = _check_keys(err, t)
    name = t.get("name", "")
    if not isinstance(name, str):
        raise err("name", "must be a string")
    if _bad_name(name):
        raise err("name", f"must be printable text of at most {limits.MAX_NAME_CHARS} characters")
    if shape == "mesh":
        return _mesh(err, base, t["file"], name)
    return _BUILD[shape](err, t, name)


def _check_keys(err, t) -> str:
    """The table's shape, once its keys are the shape's (each unknown or missing key named)."""
    if "shape" not in t:
        raise err("shape", "missing (required)")
    shape = t["shape"]
    if not isinstance(shape, str) or shape not in SHAPES:
        listed = ", ".join(f"'{s}'" for s in SHAPES)
        close = difflib.get_close_matches(shape, SHAPES, n=1) if isinstance(shape, str) else []
        raise err("shape", f"must be one of {listed}" + (f"; did you mean '{close[0]}'?" if close else ""))
    allowed = _COMMON + _KEYS[shape]
    for key in t:
        if key not in allowed:
            close = difflib.get_close_matches(str(key), list(allowed), n=1)
            other = [s for s in SHAPES if key in _KEYS[s]]
            raise err(key, f"unknown key; did you mean '{close[0]}'?" if close else
                      f"not used by a {shape} (a key of {' and '.join(other)})" if other else "unknown key")
    for key in _REQUIRED[shape]:
        if key not in t:
            raise err(key, "missing (required)")
    return shape


def _capsule(err, t, name):
    p0, p1 = _vector(err, "p0", t["p0"]), _vector(err, "p1", t["p1"])
    if np.array_equal(p0, p1):
        raise err("p1", "must differ from p0 (for a ball use shape = \"sphere\")")
    return Capsule(p0, p1, _positive(err, "radius", t["radius"]), name)


def _plane(err, t, name):
    normal = _vector(err, "normal", t["normal"])
    if not np.any(normal != 0):
        raise err("normal", "must not be zero")
    return Plane(_vector(err, "point", t["point"]), normal, name)


def _box(err, t, name):
    center, size = _vector(err, "center", t["center"]), _vector(err, "size", t["size"])
    for i, s in enumerate(size):
        if not s > 0:
            raise err("size", f"must be > 0 (entry {i + 1})")
    if "rotation" in t and "rotation_deg" in t:
        raise err("rotation_deg", "give rotation or rotation_deg, not both")
    R = rotation_from_degrees(_vector(err, "rotation_deg", t["rotation_deg"])) if "rotation_deg" in t else np.eye(3)
    if "rotation" in t:
        R = _matrix(err, "rotation", t["rotation"])
        if not is_rotation(R):
            raise err("rotation", "must be a proper rotation matrix (orthonormal rows, determinant +1, within 0.001)")
    return Box(center, size, R, name)


_BUILD = {"sphere": lambda err, t, name: Sphere(_vector(err, "center", t["center"]), _positive(err, "radius", t["radius"]), name),
          "capsule": _capsule, "plane": _plane, "box": _box}


def _bad_name(name: str) -> bool:
    return not name.isprintable() or len(name) > limits.MAX_NAME_CHARS


def _float(err, key, v, what):
    if not is_number(v):
        raise err(key, f"must be {what}")
    if isinstance(v, float) and not math.isfinite(v):
        return v  # the callers say "must be finite"
    if abs(v) > limits.MAX_COORDINATE:
        raise err(key, f"must be of magnitude <= {limits.MAX_COORDINATE:g} (vine_nlp.io.limits.MAX_COORDINATE)")
    return float(v)


def _vector(err, key, value) -> np.ndarray:
    if not (isinstance(value, list) and len(value) == 3):
        raise err(key, "must be a list of 3 numbers")
    out = np.array([_float(err, key, v, "a list of 3 numbers") for v in value])
    for i, x in enumerate(out):
        if not math.isfinite(x):
            raise err(key, f"must be finite (entry {i + 1})")
    return out


def _positive(err, key, value) -> float:
    x = _float(err, key, value, "a number")
    if not math.isfinite(x):
        raise err(key, "must be finite")
    if not x > 0:
        raise err(key, "must be > 0")
    return x


def _matrix(err, key, value) -> np.ndarray:
    if not (isinstance(value, list) and len(value) == 3 and all(isinstance(r, list) and len(r) == 3 for r in value)):
        raise err(key, "must be a 3 x 3 matrix (a list of 3 rows of 3 numbers)")
    R = np.array([[_float(err, key, v, "a 3 x 3 matrix of numbers") for v in row] for row in value])
    if not np.all(np.isfinite(R)):
        raise err(key, "must be finite")
    return R


def _mesh(err, base, value, name) -> Mesh:
    if not (isinstance(value, str) and value.strip()):
        raise err("file", "must be a non-empty string")
    path = base / value
    if path.suffix.lower() not in MESH_SUFFIXES:
        raise err("file", f"unsupported file type '{path.suffix}' (use .stl, .obj or .ply)")
    try:
        import trimesh  # noqa: F401
    except ImportError:
        raise err("file", "mesh obstacles need trimesh and rtree (dependencies of vine_nlp: python3 -m pip install trimesh rtree)") from None
    named = err("file", "")  # the problem file and key that name the mesh, for errors opening it
    data = files.read_text(path, named.file, named.key, limits.MAX_MESH_BYTES, "MAX_MESH_BYTES", binary=True)
    vertices, faces = load_mesh_file(path, data)
    return Mesh(vertices, faces, source=value, name=name)


def load_mesh_file(path, data: bytes | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Vertices and faces of a closed triangle mesh file (.stl, .obj, .ply) read through trimesh, from its bytes
    (``data``, default: read within MAX_MESH_BYTES): trimesh opens no other file (an OBJ's ``mtllib`` is not followed).
    InputError ``(path, "mesh", reason)``: unreadable, no triangles, too many faces, not closed."""
    import trimesh
    path = Path(path)
    if data is None:
        data = files.read_text(path, None, "mesh", limits.MAX_MESH_BYTES, "MAX_MESH_BYTES", binary=True)
    try:
        mesh = trimesh.load(file_obj=io.BytesIO(data), file_type=path.suffix.lower().lstrip("."), force="mesh", process=True)
    except Exception as exc:  # noqa: BLE001  third-party parser of an untrusted file: any failure is bad input
        raise InputError(str(path), "mesh", f"cannot read the mesh ({type(exc).__name__})") from None
    if not isinstance(mesh, trimesh.Trimesh) or len(mesh.faces) == 0:
        raise InputError(str(path), "mesh", "no triangles")
    mesh.update_faces(mesh.nondegenerate_faces())
    mesh.remove_unreferenced_vertices()
    F = len(mesh.faces)
    if F > MAX_MESH_FACES:
        raise InputError(str(path), "mesh", f"has {F} faces; at most {MAX_MESH_FACES}")
    if F < 4 or not np.all(np.isfinite(mesh.vertices)):
        raise InputError(str(path), "mesh", "needs at least 4 faces and finite vertices")
    if not mesh.is_watertight:
        raise InputError(str(path), "mesh", "is not closed (watertight): inside and outside are undefined")
    if not mesh.is_winding_consistent:
        raise InputError(str(path), "mesh", "faces are not wound consistently")
    if mesh.volume < 0:
        mesh.invert()
    return np.array(mesh.vertices, float), np.array(mesh.faces, np.int64)


def parse_obstacle_design(design, file) -> tuple[float, str]:
    """(margin, growth) of the problem's ``[design]`` table (may be empty): ``obstacle_margin`` (>= 0, default 0)
    and ``growth`` (default "while-actuated"); InputError naming ``file`` and the key."""
    file = str(file)
    margin = _float(lambda key, reason: InputError(file, "design.obstacle_margin", reason), "", design.get("obstacle_margin", 0.0), "a number")
    if not math.isfinite(margin):
        raise InputError(file, "design.obstacle_margin", "must be finite")
    if margin < 0:
        raise InputError(file, "design.obstacle_margin", "must be >= 0")
    growth = design.get("growth", DEFAULT_GROWTH)
    if not isinstance(growth, str) or growth not in GROWTH_MODES:
        listed = ", ".join(f"'{g}'" for g in GROWTH_MODES)
        raise InputError(file, "design.growth", f"must be one of {listed}")
    return margin, growth


# ------------------------------------------------------------------ archives


def write_obstacles(h5group, obstacles) -> None:
    """Write obstacles into ``h5group`` (the archive's ``/obstacles`` group): subgroups ``0``, ``1``, ...

    Each subgroup has attrs ``shape`` (and ``name``, and ``source`` for meshes read from a
    file) and one dataset per parameter (formats.md "Obstacles")."""
    for k, ob in enumerate(obstacles):
        g = h5group.create_group(str(k))
        g.attrs["shape"] = ob.kind
        if ob.name:
            g.attrs["name"] = ob.name
        if isinstance(ob, Mesh) and ob.source:
            g.attrs["source"] = ob.source
        for key, value in ob.parameters().items():
            big = key == "faces" or (np.ndim(value) >= 2 and np.shape(value)[0] > 16)
            g.create_dataset(key, data=np.asarray(value, np.int64 if key == "faces" else float), **({"compression": "gzip"} if big else {}))


def _obstacle_dataset(g, key: str, want: tuple, file: str, path: str) -> np.ndarray:
    """Dataset ``key`` of obstacle group ``g``: numbers of shape ``want`` (None: any size), finite, coordinates within
    MAX_COORDINATE, a mesh of at most MAX_MESH_FACES faces (read before a byte of it is: the declared shape)."""
    if key not in g or not isinstance(g[key], h5py.Dataset):
        raise InputError(file, path, "missing")
    ds = g[key]
    if ds.dtype.kind not in "iuf":
        raise InputError(file, path, "must hold numbers")
    most = {"faces": MAX_MESH_FACES, "vertices": 3 * MAX_MESH_FACES}.get(key)
    if most is not None and len(ds.shape) == 2 and ds.shape[0] > most:
        raise InputError(file, path, f"has {ds.shape[0]} rows; at most {most} (a mesh of vine_nlp.io.obstacles.MAX_MESH_FACES faces)")
    a = ds[()]
    if not (np.ndim(a) == len(want) and all(w is None or w == s for w, s in zip(want, np.shape(a)))):
        shown = "(" + ", ".join("N" if w is None else str(w) for w in want) + (",)" if len(want) == 1 else ")")
        raise InputError(file, path, f"must have shape {shown if want else '() (a scalar)'}, got {np.shape(a)}")
    if not np.all(np.isfinite(a)):
        raise InputError(file, path, "must be finite")
    if key != "faces" and np.abs(a).max(initial=0.0) > limits.MAX_COORDINATE:
        raise InputError(file, path, f"must be of magnitude <= {limits.MAX_COORDINATE:g} (vine_nlp.io.limits.MAX_COORDINATE)")
    return a


def read_obstacles(h5group, file) -> list:
    """Obstacles from an archive's ``/obstacles`` group, validated: InputError ``(file, "<dataset or group path>",
    reason)``."""
    file = str(file)
    names = list(h5group.keys())
    base = h5group.name.rstrip("/")
    for n in names:
        if not n.isdigit() or not isinstance(h5group[n], h5py.Group):
            raise InputError(file, f"{base}/{n}", "must be a group named by its index 0, 1, ...")
    order = sorted(int(n) for n in names)
    if len(order) > MAX_OBSTACLES:
        raise InputError(file, base, f"has {len(order)} obstacles; at most {MAX_OBSTACLES}")
    if order != list(range(len(order))):
        raise InputError(file, base, f"groups must be numbered 0 to {len(order) - 1}")
    out = []
    for k in order:
        g = h5group[str(k)]
        where = f"{base}/{k}"
        shape = decode_attr(g.attrs.get("shape"))
        if shape is None:
            raise InputError(file, where, "missing attribute 'shape'")
        if shape not in OBSTACLE_TYPES:
            raise InputError(file, where, f"unknown shape '{shape}'")
        name = decode_attr(g.attrs.get("name", ""))
        if not isinstance(name, str) or _bad_name(name):
            raise InputError(file, f"{where}@name", f"must be printable text of at most {limits.MAX_NAME_CHARS} characters")
        params = {key: _obstacle_dataset(g, key, want, file, f"{where}/{key}") for key, want in _DATASETS[shape].items()}
        try:
            if shape != "mesh":  # the datasets are named as the shape's fields
                ob = OBSTACLE_TYPES[shape](**{k: float(v) if k == "radius" else v for k, v in params.items()}, name=name)
            else:
                faces = params["faces"]
                if faces.dtype.kind == "f" and not np.array_equal(faces, np.round(faces)):
                    raise ValueError("faces must be integer vertex indices")
                src = decode_attr(g.attrs.get("source"))
                if src is not None and (not isinstance(src, str) or not src.isprintable()):
                    raise ValueError("source must be printable text")
                ob = Mesh(params["vertices"], faces.astype(np.int64), source=src, name=name)
        except ValueError as exc:
            raise InputError(file, where, str(exc)) from None
        out.append(ob)
    return out


def check_start(problem, file) -> None:
    """InputError ``(file, key, reason)`` for a design that cannot start: no point of the target clears the
    obstacles by the tube's radius and ``obstacle_margin`` (the whole target inside an obstacle, or a margin wider
    than the space around it). Cheap: one distance per target point and obstacle."""
    obstacles, target = getattr(problem, "obstacles", ()), getattr(problem, "target", None)
    if not obstacles or target is None:
        return
    each = np.array([np.asarray(ob.distance(np.asarray(target, float)), float).reshape(-1) for ob in obstacles])
    gaps = each.min(axis=0) - problem.diameter / 2
    if np.all(gaps < 0):
        k = int(np.argmin(each.min(axis=1)))
        raise InputError(file, f"obstacles[{k}]", "the whole target lies inside the obstacles (no point of it leaves room for the tube): "
                         "no design can follow it")
    if np.all(gaps < problem.obstacle_margin):
        raise InputError(file, "design.obstacle_margin", f"{problem.obstacle_margin:g} is wider than the room around the target: its points are at "
                         f"most {float(gaps.max()):.4g} from the obstacles (less the tube's radius)")
