"""The piecewise-helix chain (paper eq. iterativeTransform) and the actuator angle phi(s).

T^{j+1}_w = T^j_w T^{j+1}_j, with non-uniform segment lengths and any initial pose
T^0_w, in numpy (the NLP chains the segments by multiple shooting instead: methods.transcription)."""

from __future__ import annotations

import numpy as np

from vine_nlp.model.segment import segment_transform


def chain_frames(theta, lam, length, D, initial_pose=None):
    """Frames T^j_w at all segment ends, j = 0..M (numpy): (M+1, 4, 4)."""
    theta, lam, length = np.broadcast_arrays(*(np.atleast_1d(np.asarray(v, float)) for v in (theta, lam, length)))
    steps = segment_transform(theta, lam, length, D)
    frames = np.empty((theta.size + 1, 4, 4))
    frames[0] = np.eye(4) if initial_pose is None else np.asarray(initial_pose, float)
    for j in range(theta.size):
        frames[j + 1] = frames[j] @ steps[j]
    return frames


def chain_points(theta, lam, length, D, segment, fraction, initial_pose=None, frames=None):
    """Center-line points at ``fraction`` (0..1) of segment ``segment`` (numpy, vectorized).

    Returns (P, 3) points and (P, 3, 3) rotations of the center frames there."""
    theta, lam, length = np.broadcast_arrays(*(np.atleast_1d(np.asarray(v, float)) for v in (theta, lam, length)))
    if frames is None:
        frames = chain_frames(theta, lam, length, D, initial_pose)
    segment, fraction = np.asarray(segment, int), np.asarray(fraction, float)
    local = segment_transform(theta[segment], lam[segment], fraction * length[segment], D)
    world = frames[segment] @ local
    return world[:, :3, 3], world[:, :3, :3]


def shape_lines(theta, lam, length, D, segment, fraction, initial_pose=None):
    """Center, inner (actuator) and outer lines at the given points: three (P, 3) arrays.

    Inner = center + (D/2) N, outer = center - (D/2) N (paper T^c_i, T^c_o translations)."""
    center, rot = chain_points(theta, lam, length, D, segment, fraction, initial_pose)
    normal = rot[:, :, 1]
    return center, center + 0.5 * D * normal, center - 0.5 * D * normal


def segment_end_samples(length, per_segment):
    """(segment, fraction) pairs covering every segment end, base to tip, with
    ``per_segment[j]`` equal pieces in segment j."""
    per_segment = np.broadcast_to(np.asarray(per_segment, int), np.shape(length))
    seg = np.concatenate([np.full(k, j) for j, k in enumerate(per_segment)] + [[len(per_segment) - 1]])
    frac = np.concatenate([np.arange(k) / k for k in per_segment] + [[1.0]])
    return seg.astype(int), frac


def phi_from_theta(theta, length, D):
    """Actuator angle around the tube at the segment ends, phi[0] = 0 (paper eq. phi(s_j)).

    phi(s_{j+1}) = phi(s_j) + (2/D) tan(theta_j) dl_j."""
    steps = 2.0 / D * np.tan(np.asarray(theta, float)) * np.asarray(length, float)
    return np.concatenate([[0.0], np.cumsum(steps)])

