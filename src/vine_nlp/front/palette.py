"""One colour per thing in every figure, page and movie (``plot``, ``view``, ``animate``, ``template``), and the
legend's word for it.

The *opposite line* is the line on the tube wall diametrically opposite the actuator line (the model's outer
line, D/2 from the center line away from the actuator): with the actuator line it shows how the routing twists
around the tube. Runs (nlp, greedy, ...) take RUNS in the 2-D panels and the view's center lines; none of
them is a colour of a thing above."""

ACTUATOR = "#1f5fbf"  # blue: the actuator line; on a template, its path where it stays (stoppers, an sPAM's pouches)
OPPOSITE = "#2ca02c"  # green: the opposite line
TARGET = "#000000"  # black, dashed: the target
TUBE = "#a0a0a0"  # grey: the tube wall at its true diameter
OBSTACLE = "#8c6d46"  # brown: obstacles
CONTACT = "#e7298a"  # magenta: self-contacts (animate)
REMOVED = "#d62728"  # red, templates only: removed or pinched
CHANGE = "#ff7f0e"  # orange, templates only: a segment that changes against the robot built last
RUNS = ("#6a3d9a", "#e6ab02", "#e377c2", "#17becf", "#7f7f7f", "#b15928")  # purple, gold, pink first: far from every thing's colour
# several actuators on one tube: actuator k's line, stoppers and pouches take LINES[k] (the first: ACTUATOR)
LINES = (ACTUATOR, "#9467bd", "#17becf", "#bcbd22", "#8c564b", "#e377c2")  # blue, violet, cyan, olive, brown, pink
ERROR_CMAP = "plasma"  # the center line coloured by its distance to the target (with a colour bar)

LABELS = {"actuator": "actuator line", "opposite": "opposite line (twist)", "target": "target", "tube": "tube (true D)",
          "obstacle": "obstacle", "contact": "self-contact", "center": "center line (colour: error)"}
