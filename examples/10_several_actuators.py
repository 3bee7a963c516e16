"""Tutorial 10: several actuators on one tube, one shape for each state.

``problems/actuators-base-tip.toml`` has two tendons on one tube: A near the base, B near the tip, on the other side
of the tube. Pulled alone, each bends its own end; pulled together they make an S. The three targets were made by
the model from a known routing, so every state can be met exactly: the design should find A contracting only near
the base, B only near the tip, and never both on one segment.

Run:  python3 examples/10_several_actuators.py [--out DIR]
Makes: actuators.h5, actuators.png, summary.json.
"""

import numpy as np
from _common import PROBLEMS, arguments, vine_nlp, write_summary

from vine_nlp.io.actuators import read_actuators_archive
from vine_nlp.model.routing import actuated

args = arguments("10_several_actuators", __doc__.splitlines()[0])
out = args.out
archive = out / "actuators.h5"

vine_nlp("design", PROBLEMS / "actuators-base-tip.toml", "-o", archive, "--plot", out / "actuators.png", "--force")

_, run, _ = read_actuators_archive(archive)
on = actuated(run.lines.lam)  # (K, M): where each line has an actuator
pieces = {name: [int(j) for j in np.flatnonzero(on[k])] for k, name in enumerate(run.lines.names)}
print(f"A contracts segments {pieces['A'][0]}-{pieces['A'][-1]}, B segments {pieces['B'][0]}-{pieces['B'][-1]}; "
      f"segments with both: {int(np.sum(on[0] & on[1]))}")
write_summary(
    out,
    {
        "status": run.status,
        "worst_state_rmse_mm": 10.0 * max(m["rmse"] for m in run.state_metrics.values()),
        "segments_with_both": int(np.sum(on[0] & on[1])),
        "A_first": pieces["A"][0], "A_last": pieces["A"][-1], "B_first": pieces["B"][0], "B_last": pieces["B"][-1],
        "files": ["actuators.h5", "actuators.png"],
    },
)
