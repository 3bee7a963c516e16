"""Layer 3: model validation, fitting the model to measured shapes (paper Sec. V).

Everything here compares measured points with the geometric model of a *known*
routing; only the rigid pose (and, for an sPAM, the shared lambda) is estimated.

* ``align``: rigid transforms, pose starts, ICP and polish.
* ``model_fit``: :func:`fit_problem` / :func:`fit_lines` (``vine-nlp fit``), the pose
  (and lambda) fit of measured points to the model's center, inner or outer line.
* ``frames``: :func:`fit_frames`, lambda per frame of an actuated sequence (Fig. 9(d)).

Transforms are 4x4 homogeneous matrices. ``T`` returned by the fits maps measured
points into the model frame (``T @ measured ~ model``)."""

from vine_nlp.methods.fit.align import Polyline, apply_transform, invert_transform, pose_starts, r_squared
from vine_nlp.methods.fit.frames import FrameFit, fit_frames
from vine_nlp.methods.fit.model_fit import describe_fit, fit_lines, fit_problem, model_lines

__all__ = ["fit_problem", "fit_lines", "fit_frames", "FrameFit", "r_squared", "model_lines", "describe_fit", "pose_starts",
           "Polyline", "apply_transform", "invert_transform"]
