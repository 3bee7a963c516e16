"""Self-collision of the actuated tube (paper Sec. VI-A, VI-D).

Two checks, numpy only:

* analytic, for uniform (helical) sections of a routing: the paper's condition
  (one turn or more and 2 pi |b| < D), :func:`vine_nlp.model.helix.helix_self_collides`,
  applied to every run of equal (theta, lambda) found by :func:`uniform_sections`;
* general, for any shape: the tube of diameter D around the center line touches
  itself where two *non-neighbouring* center points are closer than D
  (:func:`min_clearance` on points, :func:`routing_clearance` on a routing, refined
  on the continuous model).

Neighbours. Points closer than ``exclude_arc`` along the center line are never counted: the cross-sections of a bent
tube overlap near the bend without any contact. Default pi D / 2, half a turn of the tightest circle a tube can make
(center radius D/2: inner line of zero radius). By Schur's comparison theorem a center line of curvature <= 2/D keeps
chord(s) >= D sin(s / D) for s <= pi D / 2, so below that arc a short chord only says "bent", while beyond it the chord
of the tightest circle shrinks again: the tube curls back into itself. Any shorter exclusion flags every tight bend, a
longer one hides contacts of tight coils.

Clearance. The clearance is the smallest distance of a *closest approach*: a local minimum of the center distance over
pairs of non-neighbouring points, away from the exclusion boundary (there the distance only says how far apart the first
non-neighbours are, about 1.5 D on a mildly bent tube). A shape without an approach (a plain arc) has clearance inf.
Contacts (distance < D, or D + margin) are reported wherever they are, boundary or not.

Analytic vs general on helices. Turns of a helix (radius R_c, pitch 2 pi b) are 2 pi |b| R_c / sqrt(R_c^2 + b^2) apart
(the pitch measured normal to the tube), not 2 pi |b|: the paper's condition is slightly optimistic for steep helices
(theta = 10 deg, lambda = 0.4: 2 pi b = 2.11 D, turns 2.00 D apart), and it needs a full turn while the ends of a
shorter coil can already touch (0.9 turn at theta = 2.5 deg, lambda = 0.4: the end is 0.9 D from the start). Both agree
on long helices of shallow pitch (tests/test_collision.py).

Growth (Sec. VI-D). A vine robot grown while actuated lays each part down in its final shape: a contact between material
points l_a < l_b first exists when the tube has grown to l_b (:func:`growth_contacts`). Actuated after full growth,
every contact of the final shape exists at full length and the tube sweeps through intermediate shapes on the way
(modelled as lambda_t = 1 - t (1 - lambda), theta fixed), which can touch where the final shape does not.

Coordinates: ``s`` is arc length along the actuated center line, ``l`` the material coordinate (unactuated tube length
from the base, the length everted by growth). Both in the problem's length units."""

from __future__ import annotations

import math

import numpy as np

from vine_nlp.analysis.obstacles import ModelLine, after_growth_routing, sample_chain
from vine_nlp.model.helix import center_rates, helix_self_collides, helix_turns

# ---------------------------------------------------------------------------------------------
# analytic: uniform sections


def uniform_sections(routing, D: float, atol: float = 1e-9) -> list[dict]:
    """Runs of consecutive segments with the same (theta, lambda) (within ``atol``), base to tip.

    Each run: dict(start, stop (segment indices, stop exclusive), theta, lam, length (unactuated), turns (around the
    helix axis), collides (the paper's condition, one turn or more and 2 pi |b| < D: model.helix.helix_self_collides))."""
    th, lam, ln = (np.asarray(v, float) for v in (routing.theta, routing.lam, routing.length))
    out, start = [], 0
    for j in range(1, th.size + 1):
        if j == th.size or abs(th[j] - th[start]) > atol or abs(lam[j] - lam[start]) > atol:
            t, la, L = float(th[start]), float(lam[start]), float(ln[start:j].sum())
            out.append({"start": start, "stop": j, "theta": t, "lam": la, "length": L, "turns": float(helix_turns(t, la, D, L)),
                        "collides": bool(helix_self_collides(t, la, D, L))})
            start = j
    return out


def helix_collisions(routing, D: float, atol: float = 1e-9) -> list[dict]:
    """The uniform sections of at least one turn that self-collide by the paper's condition."""
    return [u for u in uniform_sections(routing, D, atol) if u["turns"] >= 1.0 and u["collides"]]


# ---------------------------------------------------------------------------------------------
# general: any center line


def sample_routing(routing, D: float, spacing: float | None = None) -> dict:
    """The routing's center line sampled at most ``spacing`` apart (default D/8) along the actuated arc:
    :func:`vine_nlp.analysis.obstacles.sample_chain`'s dict(points, s, l, seg, frac)."""
    spacing = D / 8 if spacing is None else float(spacing)
    _, _, lc = center_rates(routing.theta, routing.lam, D)
    return sample_chain(routing, D, np.maximum(1, np.ceil(routing.length * lc / spacing)).astype(int))


def _segment_distance(p0, p1, q0, q1):
    """Closest points of segments p0-p1 and q0-q1: (distance, t on p, u on q) (Ericson, RTCD 5.1.9)."""
    d1, d2, r = p1 - p0, q1 - q0, p0 - q0
    a, e, f = d1 @ d1, d2 @ d2, d2 @ r
    c, b = d1 @ r, d1 @ d2
    den = a * e - b * b
    t = np.clip((b * f - c * e) / den, 0.0, 1.0) if den > 1e-14 * a * e and a > 0 else 0.0
    u = (b * t + f) / e if e > 0 else 0.0
    if u < 0.0:
        u, t = 0.0, (np.clip(-c / a, 0.0, 1.0) if a > 0 else 0.0)
    elif u > 1.0:
        u, t = 1.0, (np.clip((b - c) / a, 0.0, 1.0) if a > 0 else 0.0)
    return float(np.linalg.norm(p0 + t * d1 - q0 - u * d2)), float(t), float(u)


def _sampled(points, s):
    """No refinement: the sampled pair itself."""
    return lambda i, j: (float(np.linalg.norm(points[i] - points[j])), float(s[i]), float(s[j]), points[i], points[j])


def _polyline_refine(points, s):
    """Refinement on the polyline itself: exact segment-to-segment distance around (i, j)."""
    P = len(points)

    def refine(i, j):
        best = (float(np.linalg.norm(points[i] - points[j])), float(s[i]), float(s[j]), points[i], points[j])
        for a in (i - 1, i):
            for b in (j - 1, j):
                if 0 <= a < P - 1 and 0 <= b < P - 1:
                    d, t, u = _segment_distance(points[a], points[a + 1], points[b], points[b + 1])
                    if d < best[0]:
                        pa = points[a] + t * (points[a + 1] - points[a])
                        pb = points[b] + u * (points[b + 1] - points[b])
                        best = (d, s[a] + t * (s[a + 1] - s[a]), s[b] + u * (s[b + 1] - s[b]), pa, pb)
        return best

    return refine


def _regions(pairs, s, h):
    """Connected groups of pairs in the (s_i, s_j) plane (pairs closer than ~2 sample spacings)."""
    K = len(pairs)
    if K == 0:
        return []
    st = np.column_stack([s[pairs[:, 0]], s[pairs[:, 1]]])
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components
    from scipy.spatial import cKDTree
    links = cKDTree(st).query_pairs(r=2.01 * h, p=np.inf, output_type="ndarray")
    g = coo_matrix((np.ones(len(links)), (links[:, 0], links[:, 1])), shape=(K, K)) if len(links) else coo_matrix((K, K))
    _, label = connected_components(g, directed=False)
    return [np.flatnonzero(label == k) for k in range(label.max() + 1)]


def _interior_minima(pairs, dist, points, s, exclude_arc, h):
    """Indices of the pairs that are discrete local minima of the distance, away from the
    exclusion boundary: closest approaches of two parts, not the first non-neighbour of a point."""
    if len(pairs) == 0:
        return np.zeros(0, int)
    P = len(points)
    i, j = pairs[:, 0], pairs[:, 1]
    ok = (s[j] - s[i]) - exclude_arc > 1.01 * h
    for di, dj in ((-1, 0), (1, 0), (0, -1), (0, 1)):
        a, b = i + di, j + dj
        valid = (a >= 0) & (a < P) & (b >= 0) & (b < P)
        dn = np.full(len(pairs), np.inf)
        dn[valid] = np.linalg.norm(points[a[valid]] - points[b[valid]], axis=1)
        ok &= dist <= dn
    return np.flatnonzero(ok)


def _clearance(points, s, D, exclude_arc, margin, refine, closest=True):
    points = np.asarray(points, float)
    h = float(np.max(np.diff(s))) if len(s) > 1 else 0.0
    threshold = D + margin
    from scipy.spatial import cKDTree
    tree = cKDTree(points)

    def candidates(r):
        pr = tree.query_pairs(r=r, output_type="ndarray")
        if len(pr) == 0:
            return pr.reshape(0, 2), np.zeros(0)
        pr = np.sort(pr, axis=1)
        pr = pr[np.abs(s[pr[:, 1]] - s[pr[:, 0]]) > exclude_arc]
        return pr, np.linalg.norm(points[pr[:, 0]] - points[pr[:, 1]], axis=1)

    # candidates include pairs up to one spacing beyond the threshold: the continuous minimum
    # lies within h of the sampled one, so no contact is missed; refinement then decides.
    cand, dist = candidates(threshold + h)
    regions = []
    for idx in _regions(cand, s, h):
        k = idx[np.argmin(dist[idx])]
        i, j = (int(v) for v in cand[k])
        d, si, sj, pi, pj = refine(i, j)
        if d >= threshold:
            continue
        inside = idx[dist[idx] < threshold]
        pr = cand[inside] if len(inside) else cand[[k]]
        regions.append({"clearance": float(d), "i": i, "j": j, "s_i": float(si), "s_j": float(sj),
                        "point_i": np.asarray(pi, float), "point_j": np.asarray(pj, float),
                        "s_i_range": (float(s[pr[:, 0]].min()), float(s[pr[:, 0]].max())),
                        "s_j_range": (float(s[pr[:, 1]].min()), float(s[pr[:, 1]].max())), "pairs": pr})
    # growth order: the region whose later part comes first
    regions.sort(key=lambda r: (r["s_j_range"][0], r["s_i_range"][0]))
    if regions:
        best = min(regions, key=lambda r: r["clearance"])
        d, i, j, si, sj, pi, pj = (best[k] for k in ("clearance", "i", "j", "s_i", "s_j", "point_i", "point_j"))
    elif not closest:
        d, i, j, si, sj, pi, pj = math.nan, -1, -1, math.nan, math.nan, None, None
    else:
        # no contact: the closest approach, searched with a growing radius
        extent = float(np.linalg.norm(np.ptp(points, axis=0))) if len(points) else 0.0
        r, c, dd = max(threshold + h, 1e-12), cand, dist
        best = None
        while True:
            mins = _interior_minima(c, dd, points, s, exclude_arc, h)
            if len(mins):
                order = mins[np.argsort(dd[mins])[:5]]
                best = min((refine(int(c[k, 0]), int(c[k, 1])) + (int(c[k, 0]), int(c[k, 1])) for k in order), key=lambda v: v[0])
                break
            if r > 2 * extent + 2 * threshold:
                break
            r *= 2
            c, dd = candidates(r)
        if best is None:
            d, i, j, si, sj, pi, pj = math.inf, -1, -1, math.nan, math.nan, None, None
        else:
            d, si, sj, pi, pj, i, j = best
    pairs = np.concatenate([r["pairs"] for r in regions]) if regions else np.zeros((0, 2), int)
    return {"clearance": float(d), "gap": float(d - D), "contact": bool(regions),
            "i": i, "j": j, "s_i": float(si), "s_j": float(sj), "point_i": pi, "point_j": pj, "pairs": pairs,
            "distances": np.linalg.norm(points[pairs[:, 0]] - points[pairs[:, 1]], axis=1) if len(pairs) else np.zeros(0),
            "regions": regions, "points": points, "s": np.asarray(s, float),
            "exclude_arc": float(exclude_arc), "threshold": float(threshold), "spacing": h}


def _densify(points, s, max_spacing):
    """Linear resampling so that consecutive points are at most ``max_spacing`` apart."""
    steps = np.diff(s)
    k = np.maximum(1, np.ceil(steps / max_spacing).astype(int))
    if np.all(k == 1):
        return points, s
    t = np.concatenate([j + np.arange(kk) / kk for j, kk in enumerate(k)] + [[len(s) - 1]])
    j = np.minimum(np.floor(t).astype(int), len(s) - 2)
    f = (t - j)[:, None]
    return points[j] * (1 - f) + points[j + 1] * f, s[j] * (1 - f[:, 0]) + s[j + 1] * f[:, 0]


def min_clearance(center, D: float, s=None, exclude_arc: float | None = None, margin: float = 0.0, refine: bool = True) -> dict:
    """Smallest distance between non-neighbouring parts of a center line, and its contacts.

    center: (P, 3) points base to tip; s: their arc length (default: cumulative chord). Parts closer than
    ``exclude_arc`` along the line (default pi D / 2, module docstring) are neighbours and never compared. The line is
    resampled linearly to spacing <= D/4 if coarser; pairs come from a k-d tree (query_pairs), and each contact region's
    minimum is refined by exact segment-to-segment distance on the polyline (``refine``).

    Returns dict(clearance (smallest center distance of a closest approach, module docstring; inf if there is none), gap
    = clearance - D, contact (clearance < D + margin), i, j (indices into ``points`` of the closest sampled pair), s_i
    <= s_j, point_i, point_j (refined), pairs (K, 2) all sampled pairs closer than D + margin, distances (K,), regions
    (list of dicts: clearance, i, j, s_i, s_j, point_i, point_j, s_i_range, s_j_range, pairs, ordered by where the later
    part starts), points, s (the line checked), exclude_arc, threshold, spacing)."""
    pts = np.asarray(center, float)
    s = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(pts, axis=0), axis=1))]) if s is None else np.asarray(s, float)
    exclude_arc = 0.5 * math.pi * D if exclude_arc is None else float(exclude_arc)
    pts, s = _densify(pts, s, D / 4)
    return _clearance(pts, s, D, exclude_arc, margin, _polyline_refine(pts, s) if refine else _sampled(pts, s))


def routing_clearance(routing, D: float, spacing: float | None = None, exclude_arc: float | None = None, margin: float = 0.0, refine: bool = True,
                      closest: bool = True) -> dict:
    """:func:`min_clearance` of a routing's center line, sampled by the model (spacing <= D/8 by
    default) and refined on the continuous model (each region's minimum over material
    coordinates, L-BFGS-B): the clearance is exact to ~1e-9 D, not to the sampling.

    Adds to every region and to the result the material coordinates l_i, l_j (and l_i_range, l_j_range for regions), and
    ``line`` (the sample_routing dict). ``closest`` False: contacts only (clearance nan when there is none; faster)."""
    smp = sample_routing(routing, D, spacing)
    pts, s, l = smp["points"], smp["s"], smp["l"]
    exclude_arc = 0.5 * math.pi * D if exclude_arc is None else float(exclude_arc)
    model = ModelLine(routing, D)
    hl = float(np.max(np.diff(l))) if len(l) > 1 else 0.0

    sampled = _sampled(pts, s)

    def ref(i, j):
        d0 = float(np.linalg.norm(pts[i] - pts[j]))
        if not refine:
            return sampled(i, j)

        def f(z):
            q = model.points(z)
            return float(np.sum((q[0] - q[1]) ** 2)) / D**2

        box = [(max(0.0, l[i] - 2 * hl), min(l[-1], l[i] + 2 * hl)), (max(0.0, l[j] - 2 * hl), min(l[-1], l[j] + 2 * hl))]
        from scipy.optimize import minimize  # SciPy loads where it is used: commands start faster
        opt = minimize(f, np.array([l[i], l[j]]), method="L-BFGS-B", bounds=box, options={"ftol": 1e-15, "gtol": 1e-12, "maxiter": 200})
        za, zb = opt.x
        sa, sb = model.arc([za, zb])
        if not (opt.fun * D**2 < d0**2 and abs(sb - sa) > exclude_arc):
            return sampled(i, j)
        q = model.points(opt.x)
        return float(np.linalg.norm(q[0] - q[1])), float(sa), float(sb), q[0], q[1]

    out = _clearance(pts, s, D, exclude_arc, margin, ref, closest)

    def to_l(v):
        return float(np.interp(v, s, l))

    for r in out["regions"]:
        r |= {f"l_{e}": to_l(r[f"s_{e}"]) for e in "ij"} | {f"l_{e}_range": tuple(map(to_l, r[f"s_{e}_range"])) for e in "ij"}
    out |= {f"l_{e}": to_l(out[f"s_{e}"]) if math.isfinite(out[f"s_{e}"]) else math.nan for e in "ij"} | {"line": smp}
    return out


# ---------------------------------------------------------------------------------------------
# growth order (Sec. VI-D)


def _overlap(a, b, tol):
    return a[0] <= b[1] + tol and b[0] <= a[1] + tol


def _same_place(r, q, tol):
    return _overlap(r["l_i_range"], q["l_i_range"], tol) and _overlap(r["l_j_range"], q["l_j_range"], tol)


def growth_contacts(routing, D: float, margin: float = 0.0, spacing: float | None = None, exclude_arc: float | None = None,
                    actuation_steps: int = 20) -> list[dict]:
    """When each contact appears: grown while actuated vs actuated after full growth.

    Grown while actuated (the grown part already has its final shape), the contact between material points l_early <
    l_late exists from growth length l_late on: a region's ``growth_length`` is the smallest l of its later part
    (material length everted, i.e. unactuated tube length; ``growth_arc`` the same place as actuated arc length;
    resolution: the sampling spacing). Actuated after full growth (``all_at_once_growth_length`` = total length), the
    tube passes through lambda_t = 1 - t (1 - lambda), t: 0 -> 1 (``actuation_steps`` steps, 0 to skip):
    ``actuation_fraction`` is the first t at which the region is in contact. Contacts met only on the way (absent from
    the final shape) are listed with ``transient`` True and growth_length None: growing never meets them.

    Returns a list of dicts (final-shape regions in growth order, then transient ones): region, transient, clearance
    (final shape; for transient ones the smallest seen on the way), l_early, l_late, s_early, s_late, growth_length,
    growth_arc, growth_fraction, all_at_once_growth_length, actuation_fraction."""
    total = float(np.sum(routing.length))
    final = routing_clearance(routing, D, spacing, exclude_arc, margin, closest=False)
    tol = 2.5 * (D / 8 if spacing is None else spacing)
    out = []
    for k, r in enumerate(final["regions"]):
        s_first = float(final["s"][r["pairs"][:, 1]].min())
        l_first = float(np.interp(s_first, final["s"], final["line"]["l"]))
        out.append(_contact(k, r, r["clearance"], total, (l_first, s_first, l_first / total), None))
    transient = []  # [(t_first, min clearance, merged region)]
    if actuation_steps > 0:
        for t in np.linspace(0.0, 1.0, actuation_steps + 1)[1:]:
            rt = routing if t == 1.0 else after_growth_routing(routing, t)
            res = final if t == 1.0 else routing_clearance(rt, D, spacing, exclude_arc, margin, closest=False)
            for q in res["regions"]:
                hit = False
                for o, r in zip(out, final["regions"]):
                    if _same_place(r, q, tol):
                        hit = True
                        if o["actuation_fraction"] is None:
                            o["actuation_fraction"] = float(t)
                if hit:
                    continue
                for tr in transient:
                    if _same_place(tr[2], q, tol):
                        tr[1] = min(tr[1], q["clearance"])
                        tr[2] = {k: (min(tr[2][k][0], q[k][0]), max(tr[2][k][1], q[k][1])) if k.endswith("range") else tr[2][k] for k in tr[2]}
                        break
                else:
                    keep = {k: q[k] for k in ("l_i", "l_j", "s_i", "s_j", "l_i_range", "l_j_range")}
                    transient.append([float(t), q["clearance"], keep])
    out += [_contact(len(final["regions"]) + k, q, float(d), total, None, t) for k, (t, d, q) in enumerate(transient)]
    return out


def _contact(k, r, clearance, total, growth, t) -> dict:
    """One entry of :func:`growth_contacts`: region ``r``'s places; ``growth`` (length, arc, fraction) or None (transient)."""
    return {"region": k, "transient": growth is None, "clearance": clearance, "l_early": r["l_i"], "l_late": r["l_j"],
            "s_early": r["s_i"], "s_late": r["s_j"], **dict(zip(("growth_length", "growth_arc", "growth_fraction"), growth or (None,) * 3)),
            "all_at_once_growth_length": total, "actuation_fraction": t}


def collision_metrics(result, D: float | None = None, margin: float = 0.0) -> dict:
    """Floats for archive attributes: min_clearance (smallest center distance between non-neighbouring parts, inf when
    none), contacts (number of contact regions of the final shape), first_contact_growth_length (material length grown
    when the first contact appears if grown while actuated; nan when there is none)."""
    D = float(result.diameter if D is None else D)
    res = routing_clearance(result.routing, D, margin=margin)
    growth = [c["growth_length"] for c in growth_contacts(result.routing, D, margin, actuation_steps=0)]
    return {"min_clearance": float(res["clearance"]), "contacts": float(len(res["regions"])),
            "first_contact_growth_length": float(min(growth)) if growth else math.nan}
