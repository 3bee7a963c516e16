"""Problem files and archives of tubes with several actuators (spec "Several actuators on one tube").

Problem: ``[[actuators]]`` (name, kind, lambda_min, theta_max_deg, width; forward problems: each line's routing,
``theta``/``theta_deg``/``phi``, ``lambda``, ``phi0``/``phi0_deg``) and ``[[states]]`` (name, active, design
problems: ``[states.target]``). A forward problem has ``[routing]`` with the shared ``length``, ``segment_length``
and ``initial_pose``; a design problem has none (a fixed base's pose: ``[routing] initial_pose`` with
``[design] base = "fixed"``, as for one actuator).

Archive: the contract's standard part (every reader works: ``/target/points`` and the run's design and shape are
the first state's target and shape, design/theta and lambda actuator 0's), plus
``/targets/<state>/points``, ``/runs/<run>/actuators/<name>/design/{theta, lambda, phi}``,
``/runs/<run>/states/<state>/shape/{center, inner, outer}`` and ``/runs/<run>/states/<state>/metrics``; the run's
attributes ``actuators`` and ``states`` (JSON: the names in order; each state's active actuators).
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np

from vine_nlp.io import limits, sections
from vine_nlp.io.archive import Archive, _Checker, load_archive, write_archive
from vine_nlp.io.h5read import ArchiveError, open_archive
from vine_nlp.io.validate import SourceFile, check, nonempty_text, real_number, sub_table, unknown_key
from vine_nlp.methods.actuators import ActuatorsProblem, ActuatorsResult, Line, check_states
from vine_nlp.model.actuators import Lines, TwoLines
from vine_nlp.model.shape import Shape

_LINE_KEYS = ("name", "kind", "lambda_min", "theta_max_deg", "width")
_LINE_ROUTING = ("theta", "theta_deg", "phi", "lambda", "phi0", "phi0_deg")
_STATE_KEYS = ("name", "active", "target", "units")


def _list(f, data, key):
    items = data.get(key)
    check(f, key, isinstance(items, list) and len(items) > 0 and all(isinstance(t, dict) for t in items),
          f"must be an array of tables ([[{key}]]), at least one")
    check(f, key, len(items) <= limits.MAX_LEVELS, f"has {len(items)} entries; at most {limits.MAX_LEVELS}")
    return items


def _names(f, items, key):
    names = []
    for k, item in enumerate(items):
        name = nonempty_text(f, f"{key}.{k}.name", item.get("name", ""), limits.MAX_NAME_CHARS)
        check(f, f"{key}.{k}.name", name.replace("-", "").replace("_", "").replace(".", "").isalnum(),
              "must be plain: letters, digits, '-', '_' or '.'")
        check(f, f"{key}.{k}.name", name not in names, f"'{name}' is used twice")
        names.append(name)
    return names


def parse_actuators(f: SourceFile, data: dict, name: str, units: str, diameter: float):
    """(kind, ActuatorsProblem): kind "actuators" (design) or "actuators-forward" ([routing] present); each item's
    [actuator], [target] and [routing] read by ``io.sections``' readers."""
    forward = "routing" in data and any(k in data["routing"] for k in ("length", "segment_length")) if isinstance(data.get("routing"), dict) else False
    items, states = _list(f, data, "actuators"), _list(f, data, "states")
    names = _names(f, items, "actuators")
    lines = []
    for k, item in enumerate(items):
        for key in item:
            if key not in _LINE_KEYS and not (forward and key in _LINE_ROUTING):
                raise f.error(f"actuators.{k}.{key}", "not used in a design problem (routings belong to forward problems)"
                              if key in _LINE_ROUTING else unknown_key(key, _LINE_KEYS + (_LINE_ROUTING if forward else ())))
        act = sections.read_actuator(sections.Item(f, f"actuators.{k}", "actuator"), {key: v for key, v in item.items() if key in _LINE_KEYS[1:4]})
        width = real_number(f, f"actuators.{k}.width", item.get("width", diameter / 8))
        check(f, f"actuators.{k}.width", width >= 0, "must be >= 0")
        check(f, f"actuators.{k}.width", width <= math.pi * diameter,
              f"{width:g} is wider than the tube's circumference pi D = {math.pi * diameter:.6g}")
        lines.append(Line(names[k], act, width))
    snames = _names(f, states, "states")
    active, targets = {}, {}
    design = sub_table(f, data, "design", None) if not forward else {}
    for k, item in enumerate(states):
        for key in item:
            if key not in _STATE_KEYS:
                raise f.error(f"states.{k}.{key}", unknown_key(key, _STATE_KEYS))
        got = item.get("active")
        check(f, f"states.{k}.active", isinstance(got, list) and len(got) > 0 and all(isinstance(a, str) for a in got),
              "must be a list of actuator names, at least one")
        for a in got:
            check(f, f"states.{k}.active", a in names, f"unknown actuator '{a}' (actuators: {', '.join(names)})")
        check(f, f"states.{k}.active", len(set(got)) == len(got), "names an actuator twice")
        if "units" in item:
            check(f, f"states.{k}.units", item["units"] == units,
                  f"'{item['units']}' differs from the problem's units '{units}' (one tube, one unit)")
        active[snames[k]] = tuple(got)
        if forward:
            check(f, f"states.{k}.target", "target" not in item, "not used in a forward problem")
        else:
            check(f, f"states.{k}.target", isinstance(item.get("target"), dict), "missing: every state of a design problem needs a target")
            targets[snames[k]] = sections.read_target(sections.Item(f, f"states.{k}.target", "target"), {"target": item["target"]}, diameter)
    if forward:
        check(f, "design", "design" not in data, "not used in a forward problem")
        return "actuators-forward", _forward(f, data, items, name, units, diameter, lines, active)
    return "actuators", _design(f, data, design, name, units, diameter, lines, active, targets)


def _forward(f, data, items, name, units, diameter, lines, active):
    shared = sub_table(f, data, "routing", ("length", "segment_length", "initial_pose"))
    theta, lam, phi0 = [], [], []
    for k, item in enumerate(items):
        table = {**shared, **{key: v for key, v in item.items() if key in _LINE_ROUTING[:4]}}
        r = sections.read_routing(sections.Item(f, f"actuators.{k}", "routing", _LINE_ROUTING), table, diameter)
        theta.append(r.theta)
        lam.append(r.lam)
        start = 0.0
        if "phi" in item:
            start = float(sections.per_point(f, f"actuators.{k}.phi", item["phi"], np.zeros(1), "one per segment end")[0]) \
                if not isinstance(item["phi"], list) else real_number(f, f"actuators.{k}.phi", item["phi"][0])
        for key, scale in (("phi0", 1.0), ("phi0_deg", math.pi / 180)):
            if key in item:
                check(f, f"actuators.{k}.{key}", "phi" not in item, "conflicts with phi (whose value at s = 0 is phi0)")
                start = real_number(f, f"actuators.{k}.{key}", item[key]) * scale
        check(f, f"actuators.{k}.phi0", k > 0 or start == 0, "the first actuator starts at phi = 0 (the base frame's y axis)")
        phi0.append(start)
    ls = Lines(tuple(a.name for a in lines), theta, lam, phi0, r.length, r.initial_pose)
    problem = ActuatorsProblem(name, diameter, tuple(lines), active, lines=ls, units=units)
    try:
        check_states(problem, ls)
    except TwoLines as e:
        raise f.error(f"states.{list(active).index(e.state)}.active", str(e)) from None
    return problem


def _design(f, data, design, name, units, diameter, lines, active, targets):
    for key in design:
        if key not in sections._OTHER_DESIGN_KEYS + sections._BUILD_KEYS:
            raise f.error(f"design.{key}", unknown_key(key, sections._OTHER_DESIGN_KEYS + sections._BUILD_KEYS))
    options = sections.design_options(f, data, design, lines[0].actuator)
    first = next(iter(targets))
    for k, (pts, _) in enumerate(targets.values()):
        need = options.points_per_segment + 1
        check(f, f"states.{k}.target", pts.shape[0] >= need,
              f"needs at least points_per_segment + 1 = {need} points, got {pts.shape[0]}")
        check(f, f"states.{k}.target", pts.shape[0] == targets[first][0].shape[0],
              f"has {pts.shape[0]} points; every state needs as many as states.0 ({targets[first][0].shape[0]})")
    return ActuatorsProblem(name, diameter, tuple(lines), active, targets={s: t[0] for s, t in targets.items()},
                            options=options, units=units)


# ---------------------------------------------------------------- archives


def write_actuators_archive(path, problem_file, runs: dict, extra: dict | None = None, extend=None) -> None:
    """Write the archive atomically: the standard part and the extension (module docstring) of every run of ``runs``
    (name -> ActuatorsResult), ``extra`` datasets and ``extend(h5)`` (a correction's: io.correction)."""
    problem, D = problem_file.problem, problem_file.problem.diameter
    targets = problem.targets or {}
    archive = Archive(name=problem_file.name, kind=problem_file.kind, source=problem_file.source, diameter=D, units=problem_file.units,
                      target=next(iter(targets.values()), None), runs=dict(runs),
                      extra={f"targets/{s}/points": t for s, t in targets.items()} | (extra or {}))

    def more(h5):
        for run, result in runs.items():
            g, lines = h5[f"runs/{run}"], result.lines
            g.attrs["actuators"] = json.dumps(list(lines.names))
            g.attrs["states"] = json.dumps({s: list(a) for s, a in problem.states.items()})
            phi = lines.phi(D)
            for k, nm in enumerate(lines.names):
                d = g.create_group(f"actuators/{nm}/design")
                for key, v in (("theta", lines.theta[k]), ("lambda", lines.lam[k]), ("phi", phi[k])):
                    d.create_dataset(key, data=v)
            for s, shape in result.shapes.items():
                sg = g.create_group(f"states/{s}")
                for line in ("center", "inner", "outer"):
                    sg.create_dataset(f"shape/{line}", data=getattr(shape, line))
                if s in result.state_metrics:
                    sg.create_group("metrics").attrs.update({k: float(v) for k, v in result.state_metrics[s].items()})
        if extend is not None:
            extend(h5)

    write_archive(path, archive, extend=more)


def read_actuators_archive(path, run: str | None = None):
    """(Archive, ActuatorsResult of ``run`` (default: the archive's default run), {state: target}), every part
    of the extension checked (ArchiveError naming the dataset otherwise)."""
    a = load_archive(path)
    run = a.pick_run(run)
    base, c = a.runs[run], _Checker(path)
    with open_archive(path) as h5:
        g = h5[f"runs/{run}"]
        try:
            names = json.loads(c.text(g, "actuators"))
            states = {s: tuple(v) for s, v in json.loads(c.text(g, "states")).items()}
        except (ValueError, AttributeError, TypeError):
            raise ArchiveError(path, f"/runs/{run}@actuators", "must be JSON: the actuator names and the states") from None
        M = base.routing.segments
        rows = [[c.array(c.group(c.group(g["actuators"], nm), "design"), key, (M + (key == "phi"),), limits.MAX_SEGMENTS + 1)
                 for key in ("theta", "lambda", "phi")] for nm in names]
        targets = {s: a.extra[f"targets/{s}/points"] for s in states if f"targets/{s}/points" in a.extra}
        shapes, sm = {}, {}
        for s in states:
            sg = c.group(c.group(g, "states"), s)
            shapes[s] = c.shape_lines(sg, s, targets[s].shape[0] if s in targets else None)
            sm[s] = c.metrics(sg)
    for nm, (t, v, _) in zip(names, rows):  # every line's values by the problem files' rules (the first one's: design/)
        if broken := limits.routing_rule(t, v, base.routing.length, a.diameter):
            raise ArchiveError(path, f"/runs/{run}/actuators/{nm}/design/{broken[0]}", broken[1])
    th, lam, phi = (np.array([r[i] for r in rows]) for i in range(3))
    lines = Lines(tuple(names), th, lam, phi[:, 0], base.routing.length, base.routing.initial_pose)
    if not np.allclose(lines.phi(a.diameter), phi, atol=1e-9 * (1 + np.abs(phi).max())):
        raise ArchiveError(path, f"/runs/{run}/actuators", "phi does not follow from theta and the lengths")
    problem = ActuatorsProblem(a.name, a.diameter, tuple(Line(n) for n in names), states)
    try:
        check_states(problem, lines)
    except TwoLines as e:
        raise ArchiveError(path, f"/runs/{run}/actuators", str(e)) from None
    r = ActuatorsResult(method=base.method, routing=base.routing, shape=base.shape, status=base.status, solve_time_s=base.solve_time_s,
                        iterations=base.iterations, metrics=base.metrics, stats=base.stats | {"states": {s: list(v) for s, v in states.items()}}, diameter=a.diameter,
                        shortfall=base.shortfall, lines=lines, shapes={s: Shape(*(v.center, v.inner, v.outer)) for s, v in shapes.items()},
                        state_metrics={s: m for s, m in sm.items() if m})
    return a, r, targets


def stored_forward(path, run: str):
    """``forward ARCHIVE.h5 --run RUN`` of an archive of several actuators: its lines and states as a forward
    problem, and a source text that says where the routing is."""
    a, r, _ = read_actuators_archive(path, run)
    states = {s: tuple(v) for s, v in r.stats["states"].items()}
    problem = ActuatorsProblem(f"{a.name}-{run}", a.diameter, tuple(Line(n) for n in r.lines.names), states, lines=r.lines, units=a.units)
    source = f"# written by vine_nlp: forward {Path(path).name} --run {run}\n# the routing: the archive's /runs/{run}/actuators\n"
    return problem, source
